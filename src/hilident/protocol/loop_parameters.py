"""Where a drive keeps its control loop's parameters: the ``[loop]`` table of a ``driver.toml``.

A drive's cascade (:class:`hilident.control.Cascade`) has six parameters. The
driver folder says, for each, where the drive keeps it or what it is:

.. code-block:: toml

    [loop]
    kv_nm_per_mps = { object = "0x2400:1" }              # a CANopen object, in SI units
    ti_s = { object = "0x2400:2", scale = 0.001 }        # stored in ms: 0.001 s per unit
    kp_pos_per_s = { object = "0x2400:3" }
    velocity_filter_hz = { object = "0x2400:4" }
    current_loop_hz = { value = 1000.0 }                 # fixed by the firmware (the manual's figure)
    delay_ticks = { value = 1 }

A drive whose position controller is a PI, PD or PID lists its other terms
(:data:`POSITION_TERMS`, e.g. ``ki_pos_per_s2 = { object = "0x3210:2" }``).
A drive with feed-forward terms lists those it has (:data:`FEEDFORWARD`,
e.g. ``accel_feedforward_nm_per_mps2 = { object = "0x2400:6" }``); a term left
out is one the drive lacks.

A drive that keeps the velocity loop's integral as a gain (most vendors do:
maxon's, Nanotec's, Faulhaber's "I-gain") gives ``ki_nm_per_m`` instead of
``ti_s`` (:data:`ALTERNATIVES`): ``ki = kv / ti``, 0 for a P controller. The
host converts (:meth:`LoopDescription.to_cascade`, :meth:`LoopDescription.to_device`),
so the cascade, the tuner and ``summary.json`` always speak ``ti_s``; writing
``kv`` alone to such a drive writes ``ki`` with it, so the integral time stays.

``value`` may be ``inf`` where the parameter's part is absent (``ti_s = inf``:
a P controller; ``velocity_filter_hz = inf``: the raw difference;
``current_loop_hz = inf``: an ideal current loop). The host reads the objects
and never writes a parameter kept as a value.

Where a parameter lives depends on the transport: a CANopen drive keeps it in
an object (``object = "0xIIII:S"``, with ``scale``), a Modbus drive in a
register of its map (``register = "name"``, the register's own type and scale
apply), the serial board in its LOOP message (``message = "LOOP"``, the
protocol fixes the field and the unit). Each transport accepts only its own
kind (:func:`parse_loop`'s ``kinds``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from hilident.errors import ConfigError
from hilident.protocol.canopen_types import ObjectAddress, parse_address

__all__ = [
    "ALTERNATIVES",
    "FEEDFORWARD",
    "GAINS",
    "PARAMETERS",
    "POSITION_TERMS",
    "TUNABLE",
    "WRITABLE",
    "LoopDescription",
    "LoopParameter",
    "parse_loop",
]

#: The cascade's parameters, with their units.
PARAMETERS = {
    "kv_nm_per_mps": "velocity loop proportional gain, N*m per (m/s)",
    "ti_s": "velocity loop integral time, s (inf: a P controller)",
    "kp_pos_per_s": "position loop gain, (m/s) per m",
    "velocity_filter_hz": "cut-off of the velocity estimate's low-pass, Hz (inf: none)",
    "current_loop_hz": "bandwidth of the current loop, Hz (inf: ideal)",
    "delay_ticks": "computation and transport delay, loop ticks",
}
#: The feed-forward terms a drive may have; one left out of ``[loop]`` is a term the drive lacks. Each acts on
#: the set-point (its velocity and acceleration by differences over the set-point period), in velocity mode and
#: in position mode, except ``velocity_feedforward`` (position mode only).
FEEDFORWARD = {
    "velocity_feedforward": "position mode: share of the set-point's velocity added to the velocity set-point, 1",
    "accel_feedforward_nm_per_mps2": "torque per m/s^2 of the set-point's acceleration (inertia), N*m/(m/s^2)",
    "viscous_feedforward_nm_per_mps": "torque per m/s of the set-point's velocity (viscous friction), N*m/(m/s)",
    "friction_feedforward_nm": "torque with the sign of the set-point's velocity (Coulomb friction), N*m",
}
#: The position controller's terms beyond P that a drive may have (a PI, PD or PID position loop); one left out of
#: ``[loop]`` is a term the drive lacks (0). The tuner keeps them as the drive has them.
POSITION_TERMS = {
    "ki_pos_per_s2": "position loop integral gain: (m/s) of velocity set-point per m*s of position error, 1/s^2",
    "kd_pos": "position loop derivative gain: (m/s) of velocity set-point per (m/s) of position error's rate, 1",
}
#: The cascade's parameters a tuner may change; the others are the drive's hardware and firmware.
GAINS = ("kv_nm_per_mps", "ti_s", "kp_pos_per_s", "velocity_filter_hz")
#: Everything a host may change: the gains, the position controller's other terms and the feed-forward terms.
TUNABLE = (*GAINS, *POSITION_TERMS, *FEEDFORWARD)
#: Other forms a drive may keep a cascade parameter in: name -> (the parameter it stands for, its meaning).
#: ``[loop]`` gives one of the two.
ALTERNATIVES = {
    "ki_nm_per_m": ("ti_s", "velocity loop integral gain, N*m per m of integrated velocity error: kv / ti (0: P)"),
}
#: What a drive may let a host write: the tunable parameters, in either of their forms.
WRITABLE = (*TUNABLE, *ALTERNATIVES)
#: The integral gain's name (:data:`ALTERNATIVES`).
INTEGRAL_GAIN = "ki_nm_per_m"


@dataclass(frozen=True)
class LoopParameter:
    """One cascade parameter: the object that holds it, or its fixed value.

    Attributes
    ----------
    name : str
        One of :data:`PARAMETERS`, :data:`ALTERNATIVES`, :data:`POSITION_TERMS` or :data:`FEEDFORWARD`.
    address : ObjectAddress or None
        The CANopen object that holds it (None: not in an object).
    value : float or None
        The fixed value in SI units (None: held by the drive).
    scale : float
        SI units per stored unit of the object.
    register : str or None
        The Modbus register (a name of ``[modbus.registers]``) that holds it.
    message : str or None
        The serial message that carries it (``"LOOP"``).
    """

    name: str
    address: ObjectAddress | None = None
    value: float | None = None
    scale: float = 1.0
    register: str | None = None
    message: str | None = None

    @property
    def held(self) -> bool:
        """Whether the drive holds it (object, register or message), rather than the description fixing it."""
        return self.value is None

    def physical(self, stored) -> float:
        """The SI value of what the object holds."""
        return float(stored) * self.scale

    def stored(self, physical: float) -> float:
        """What the object holds for the SI value ``physical`` (before rounding to the object's type)."""
        return physical / self.scale


@dataclass(frozen=True)
class LoopDescription:
    """The ``[loop]`` table: every parameter of :data:`PARAMETERS`, and the feed-forward terms of
    :data:`FEEDFORWARD` the drive has, where each lives.

    Attributes
    ----------
    parameters : dict
        Name -> :class:`LoopParameter`.
    """

    parameters: dict[str, LoopParameter]

    @property
    def held(self) -> dict[str, LoopParameter]:
        """The parameters the drive holds (not fixed values): name -> parameter."""
        return {n: p for n, p in self.parameters.items() if p.held}

    def fixed(self) -> dict[str, float]:
        """The parameters the description fixes: name -> SI value."""
        return {n: float(p.value) for n, p in self.parameters.items() if p.value is not None}

    @property
    def objects(self) -> dict[str, ObjectAddress]:
        """The parameters held in objects: name -> address."""
        return {n: p.address for n, p in self.parameters.items() if p.address is not None}

    def owner(self, addr: ObjectAddress) -> str | None:
        """The parameter the object ``addr`` holds; None when it holds none."""
        return next((n for n, a in self.objects.items() if a == addr), None)

    @property
    def integral_as_gain(self) -> bool:
        """Whether the drive keeps the velocity integral as a gain (``ki_nm_per_m``) rather than a time."""
        return INTEGRAL_GAIN in self.parameters

    def to_cascade(self, values: Mapping[str, float], present: Callable[[], Mapping[str, float]] | None = None):
        """Values in the drive's form (names of ``parameters``, SI units) as the cascade's (:data:`PARAMETERS`).

        Parameters
        ----------
        values : mapping
            Some or all of the drive's parameters, SI units.
        present : callable, optional
            The drive's present parameters in the cascade's form; asked only when ``values`` has one of ``kv`` and
            ``ki`` without the other (a drive keeps the other: ``ki`` stays when ``kv`` is written, and the
            integral time moves with it).

        Returns
        -------
        dict
            ``values`` with ``ki_nm_per_m`` replaced by ``ti_s = kv / ki`` (``inf`` for ``ki = 0``).
        """
        out = dict(values)
        if not self.integral_as_gain or not ({"kv_nm_per_mps", INTEGRAL_GAIN} & set(out)):
            return out
        base = _present(present) if not {"kv_nm_per_mps", INTEGRAL_GAIN} <= set(out) else {}
        kv = float(out.get("kv_nm_per_mps", base.get("kv_nm_per_mps", 0.0)))
        ki = float(out.pop(INTEGRAL_GAIN)) if INTEGRAL_GAIN in out else _gain(base)
        out["ti_s"] = kv / ki if ki != 0 else math.inf  # a negative gain gives a negative time, which is refused
        return out

    def to_device(self, values: Mapping[str, float], present: Callable[[], Mapping[str, float]] | None = None):
        """Cascade values (:data:`PARAMETERS` and :data:`FEEDFORWARD`, SI units) in the drive's form.

        Parameters
        ----------
        values : mapping
            Some or all of the cascade's parameters, SI units.
        present : callable, optional
            The drive's present parameters in the cascade's form; asked only when ``values`` has one of ``kv`` and
            ``ti`` without the other.

        Returns
        -------
        dict
            ``values`` with ``ti_s`` replaced by ``ki_nm_per_m = kv / ti`` (0 for ``ti = inf``); with ``kv``
            alone, ``ki`` is added so the integral time stays.
        """
        out = dict(values)
        if not self.integral_as_gain or not ({"kv_nm_per_mps", "ti_s"} & set(out)):
            return out
        base = _present(present) if not {"kv_nm_per_mps", "ti_s"} <= set(out) else {}
        kv = float(out.get("kv_nm_per_mps", base.get("kv_nm_per_mps", 0.0)))
        ti = float(out.pop("ti_s", base.get("ti_s", math.inf)))
        out[INTEGRAL_GAIN] = kv / ti if math.isfinite(ti) else 0.0
        return out


def _present(present: Callable[[], Mapping[str, float]] | None) -> Mapping[str, float]:
    if present is None:
        raise ValueError("the drive's present kv and integral are needed to convert one of them alone")
    return present()


def _gain(cascade: Mapping[str, float]) -> float:
    """``ki = kv / ti`` of cascade values (0 for an infinite ``ti``)."""
    ti = float(cascade.get("ti_s", math.inf))
    return float(cascade.get("kv_nm_per_mps", 0.0)) / ti if math.isfinite(ti) else 0.0


#: The keys that say where a parameter lives, and what each means.
LOCATIONS = {
    "object": '{ object = "0xIIII:S" } (a CANopen object)',
    "register": '{ register = "name" } (a register of [modbus.registers])',
    "message": '{ message = "LOOP" } (the serial board\'s LOOP message)',
}
#: The messages a serial board carries its loop in.
MESSAGES = ("LOOP",)


def parse_loop(table, source: str = "", kinds: tuple[str, ...] = ("object",)) -> LoopDescription | None:
    """The ``[loop]`` table of a driver description; None when it has none.

    Parameters
    ----------
    table : dict or None
    source : str
        The file, for error messages.
    kinds : tuple of str
        The keys of :data:`LOCATIONS` the transport accepts (``value`` is always accepted).

    Raises
    ------
    ConfigError
        A parameter missing, unknown or malformed; the message names the key.
    """
    if table is None:
        return None
    if not isinstance(table, dict):
        raise ConfigError("loop", "must be a table of the cascade's parameters", source)
    unknown = sorted(set(table) - set(PARAMETERS) - set(POSITION_TERMS) - set(FEEDFORWARD) - set(ALTERNATIVES))
    if unknown:
        raise ConfigError(
            f"loop.{unknown[0]}",
            f"is no cascade parameter; they are {list(PARAMETERS)} (or {_alternatives()}), the position "
            f"controller's {list(POSITION_TERMS)} and the feed-forward terms {list(FEEDFORWARD)}",
            source,
        )
    forms = {n: [n, *(a for a, (stands, _) in ALTERNATIVES.items() if stands == n)] for n in PARAMETERS}
    names = []
    for name, choices in forms.items():
        given = [c for c in choices if c in table]
        if not given:
            alternative = f" (or {' or '.join(choices[1:])})" if len(choices) > 1 else ""
            raise ConfigError(
                f"loop.{name}",
                f"is missing{alternative}: give the object that holds it or its value ({PARAMETERS[name]})",
                source,
            )
        if len(given) > 1:
            raise ConfigError(f"loop.{given[1]}", f"and loop.{given[0]} are one parameter: give one of them", source)
        names.append(given[0])
    names += [n for n in (*POSITION_TERMS, *FEEDFORWARD) if n in table]
    return LoopDescription({n: _parameter(n, table[n], source, kinds) for n in names})


def _alternatives() -> str:
    return ", ".join(f"{a} for {stands}" for a, (stands, _) in ALTERNATIVES.items())


def _parameter(name: str, entry, source: str, kinds: tuple[str, ...]) -> LoopParameter:
    key = f"loop.{name}"
    entry = _checked_entry(key, entry, source, kinds)
    if "register" in entry:
        register = entry["register"]
        if not isinstance(register, str) or not register:
            raise ConfigError(
                f"{key}.register", f"must name a register of [modbus.registers], got {register!r}", source
            )
        return LoopParameter(name, register=register)
    if "message" in entry:
        if name in ALTERNATIVES:
            stands = ALTERNATIVES[name][0]
            raise ConfigError(f"{key}.message", f"the LOOP message carries {stands}, not {name}", source)
        if entry["message"] not in MESSAGES:
            raise ConfigError(f"{key}.message", f"must be one of {list(MESSAGES)}, got {entry['message']!r}", source)
        return LoopParameter(name, message=entry["message"])
    if "object" in entry:
        scale = _scale(key, entry.get("scale", 1.0), source)
        return LoopParameter(name, address=parse_address(entry["object"], f"{key}.object", source), scale=scale)
    value = entry["value"]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or math.isnan(value) or value < 0:
        raise ConfigError(f"{key}.value", f"must be a number >= 0 (inf allowed), got {value!r}", source)
    return LoopParameter(name, value=float(value))


def _checked_entry(key: str, entry, source: str, kinds: tuple[str, ...]) -> dict:
    """The entry as a table with one location (of ``kinds``) or a value, and no key it cannot have."""
    if isinstance(entry, (int, float)) and not isinstance(entry, bool):
        entry = {"value": entry}
    allowed = " or ".join([LOCATIONS[k] for k in kinds] + ["{ value = ... }"])
    if not isinstance(entry, dict) or len({*LOCATIONS, "value"} & set(entry)) != 1:
        raise ConfigError(key, f"must be {allowed}", source)
    keys = {*kinds, "value"} | ({"scale"} if "object" in entry else set())
    extra = sorted(set(entry) - keys)
    if extra:
        raise ConfigError(
            f"{key}.{extra[0]}", f"is not a key of a loop parameter of this driver ({', '.join(sorted(keys))})", source
        )
    return entry


def _scale(key: str, scale, source: str) -> float:
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not (math.isfinite(scale) and scale > 0):
        raise ConfigError(
            f"{key}.scale", f"must be a finite number > 0 (SI units per stored unit), got {scale!r}", source
        )
    return float(scale)
