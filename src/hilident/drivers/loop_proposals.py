"""The drive's cascade as its EDS names it: the ``[loop]`` table ``hilident drivers new`` proposes.

Vendors keep their loops' gains in objects named after the loop and the term:
"Speed Regulator P-Gain" and "Position Regulator D-Gain" (maxon 0x60F9,
0x60FB), "Velocity loop, integral gain (closed loop)" (Nanotec 0x3210), a
record "Velocity Control Parameter Set" with "Integral Term I" (Faulhaber
0x2331). :func:`loop_objects` reads each object's loop (current, velocity,
position) and term (P, I, integral time, D, velocity or acceleration
feed-forward) from its name and its record's name; :func:`propose_loop` turns
them into the keys of ``[loop]`` (:mod:`hilident.protocol.loop_parameters`).

An EDS names an object, never its unit: every key proposed is a placeholder
whose ``scale`` (SI units per stored unit) must come from the manual, and the
parts an EDS does not hold (the current loop's bandwidth, the delay, the
velocity estimate's filter) are the manual's figures. What hilident's cascade
does not describe (the current loop's gains, a second object of one term) is
said in notes, never silently dropped.

All pure: an object dictionary in, a proposal out.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from hilident.protocol import eds as E
from hilident.protocol.canopen_objects import BOOLEAN, NUMERIC_TYPES

__all__ = ["LoopObject", "LoopProposal", "loop_objects", "propose_loop"]

#: The terms an object's name may name, most specific first: term -> pattern.
_TERMS = (
    ("velocity_ff", r"(velocity|speed)\s*feed\s*-?\s*forward"),
    ("accel_ff", r"acceleration\s*feed\s*-?\s*forward"),
    ("ti", r"integra(l|tion)\s+time|reset\s+time"),
    ("p", r"\bp-gain\b|proportional"),
    ("i", r"\bi-gain\b|integral"),
    ("d", r"\bd-gain\b|derivative"),
)
#: The loops, the current loop first (a "torque current loop" is no velocity loop): loop -> pattern.
_LOOPS = (
    ("current", r"current|flux"),
    ("velocity", r"velocity|speed"),
    ("position", r"position"),
)
#: Names of objects that look like a gain but are none of the running cascade's.
_NOT_A_LOOP_GAIN = r"analog|autotun|auto-tun|scheduling|open loop|identification|\bao\d|\bai\d"
#: CiA 301 types a gain can be held in: the numbers, a BOOLEAN aside.
_GAIN_TYPES = NUMERIC_TYPES - {BOOLEAN}


@dataclass(frozen=True)
class LoopObject:
    """One object of the drive's loops, as its name says.

    Attributes
    ----------
    info : ObjectInfo
        The EDS entry.
    text : str
        Its record's name and its own, as read.
    loop : str
        ``"current"``, ``"velocity"``, ``"position"`` or ``""`` (not named).
    term : str
        ``"p"``, ``"i"``, ``"ti"``, ``"d"``, ``"velocity_ff"`` or ``"accel_ff"``.
    """

    info: E.ObjectInfo
    text: str
    loop: str
    term: str

    def describe(self) -> str:
        """``0x60F9:1 "Speed Regulator P-Gain" (INTEGER16, default 1000)``."""
        default = "" if self.info.default is None else f", default {self.info.default}"
        return f'{self.info.address} "{self.info.name}" ({E.type_name(self.info.data_type)}{default})'


@dataclass(frozen=True)
class LoopProposal:
    """The ``[loop]`` keys proposed, and what the drive has that the cascade does not describe.

    Attributes
    ----------
    keys : tuple of (str, str, str)
        ``(key, TOML value, why)``: every one a placeholder, ``why`` saying where it came from and what to check.
    notes : tuple of str
        The drive's loop objects left out, and why.
    """

    keys: tuple[tuple[str, str, str], ...]
    notes: tuple[str, ...]


def loop_objects(od) -> list[LoopObject]:
    """The objects of ``od`` whose names say they are a gain or a feed-forward term of one of the drive's loops:
    numeric, readable and writable, outside the communication area (0x1000-0x1FFF)."""
    found = []
    for index in sorted(od.indices):
        if index < 0x2000:
            continue
        record = od.indices[index]
        for sub in (0,) if not hasattr(record, "subindices") else sorted(record.subindices):
            info = E.object_info(od, index, sub)
            if info is None or info.data_type not in _GAIN_TYPES or not (E.writable(info.access)):
                continue
            found += _classified(info, "" if sub == 0 else record.name)
    return found


def _classified(info: E.ObjectInfo, record_name: str) -> list[LoopObject]:
    own, record = _words(info.name), _words(record_name)
    if re.search(_NOT_A_LOOP_GAIN, f"{record} {own}"):
        return []
    term = next((t for t, pattern in _TERMS if re.search(pattern, own)), None)
    if term is None:
        return []
    # a feed-forward term's loop is the one it is "in" ("... in Speed Regulator"), not the quantity it feeds
    rest = re.sub(dict(_TERMS)[term], " ", own) if term.endswith("_ff") else own
    loop = _loop_of(rest) or _loop_of(record)
    if not loop and not term.endswith("_ff"):
        return []
    return [LoopObject(info, f"{record_name} / {info.name}" if record_name else info.name, loop, term)]


def _words(name: str) -> str:
    return " " + re.sub(r"\s+", " ", str(name).lower().replace("_", " ")) + " "


def _loop_of(text: str) -> str:
    return next((loop for loop, pattern in _LOOPS if re.search(pattern, text)), "")


def propose_loop(od) -> LoopProposal | None:
    """The ``[loop]`` table for the drive ``od`` describes; None when its EDS names no velocity P and I gains.

    The velocity loop's P and I (or integral time) are required; the position loop's P, I and D, the
    feed-forward terms and the notes follow what the EDS has. Every key is a placeholder (the EDS gives no unit).
    """
    objects = loop_objects(od)

    def first(loop: str, *terms: str) -> LoopObject | None:
        return next((o for o in objects if o.loop == loop and o.term in terms), None)

    kv, integral = first("velocity", "p"), first("velocity", "i", "ti")
    if kv is None or integral is None:
        return None
    kp = first("position", "p")
    keys = [
        _object_key("kv_nm_per_mps", kv, "N*m/(m/s)"),
        _object_key(
            "ki_nm_per_m" if integral.term == "i" else "ti_s",
            integral,
            "N*m per m (kv / ti)" if integral.term == "i" else "s",
        ),
        _object_key("kp_pos_per_s", kp, "(m/s) per m")
        if kp is not None
        else ("kp_pos_per_s", "0.0", "no position gain object recognised: the manual's gain, (m/s) per m"),
        ("velocity_filter_hz", "inf", "no velocity estimate filter object recognised: the manual's cut-off, Hz"),
        ("current_loop_hz", "1000.0", "the current loop's bandwidth from the manual, Hz (the EDS holds its gains)"),
        ("delay_ticks", "1", "the computation and transport delay from the manual, loop ticks"),
    ]
    notes = []
    if first("position", "d") is not None:
        notes.append(
            "The position controller has a D term: hilident's cascade puts the position controller around the "
            "velocity loop; a drive whose position PID drives the current itself is another structure. Check the "
            "manual's block diagram before trusting position-mode margins."
        )
    ki_pos, kd_pos = first("position", "i"), first("position", "d")
    if ki_pos is not None:
        keys.append(_object_key("ki_pos_per_s2", ki_pos, "(m/s) per (m*s)"))
    if kd_pos is not None:
        keys.append(_object_key("kd_pos", kd_pos, "(m/s) per (m/s)"))
    feedforward = _feedforward_objects(objects)
    keys += [_object_key(key, o, unit) for key, (o, unit) in feedforward.items()]
    chosen = (kv, integral, kp, ki_pos, kd_pos, *(o for o, _ in feedforward.values()))
    used = {o.info.address for o in chosen if o is not None}
    notes += [_left_out(o) for o in objects if o.info.address not in used]
    return LoopProposal(tuple(keys), tuple(notes))


def _object_key(key: str, o: LoopObject, unit: str) -> tuple[str, str, str]:
    """``key = { object, scale }``: 1 unless the name gives it ("per mille"); the why says what to confirm."""
    scale = "0.001" if "per mille" in o.text.lower() else "1.0"
    why = f"{o.describe()}: scale = {unit} per stored unit, from the manual"
    return key, f'{{ object = "{o.info.address}", scale = {scale} }}', why


def _feedforward_objects(objects: list[LoopObject]) -> dict[str, tuple[LoopObject, str]]:
    """The feed-forward terms, key -> (object, unit): a velocity term in the position loop (or in none) is the
    velocity feed-forward, one in the velocity loop the viscous term; an acceleration term is the inertia's."""
    found: dict[str, tuple[LoopObject, str]] = {}
    for o in objects:
        if o.term == "velocity_ff" and o.loop == "velocity":
            found.setdefault("viscous_feedforward_nm_per_mps", (o, "N*m/(m/s)"))
        elif o.term == "velocity_ff":
            found.setdefault("velocity_feedforward", (o, "1"))
        elif o.term == "accel_ff":
            found.setdefault("accel_feedforward_nm_per_mps2", (o, "N*m/(m/s^2)"))
    return found


def _left_out(o: LoopObject) -> str:
    """Why an object of the drive's loops has no key: the cascade's position loop is P, its current loop a lag."""
    if o.loop == "position" and o.term == "ti":
        return (
            f"{o.describe()}: the position controller's integral time; give it as ki_pos_per_s2 = kp / time "
            "(a value), or hold it at its off value on the drive"
        )
    if o.loop == "current":
        return f"{o.describe()}: a current loop gain; the cascade takes the current loop as its bandwidth"
    if o.term.endswith("_ff"):
        return f"{o.describe()}: a second feed-forward object of one term; the first one found is proposed"
    return f"{o.describe()}: a second {o.loop} {o.term.upper()} gain; the first one found is proposed"
