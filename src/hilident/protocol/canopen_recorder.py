"""A drive's own signal generator and data recorder, as ``[canopen.generator]`` and
``[canopen.recorder]`` describe them.

Real drives cannot play an arbitrary table, but most have a **generator**
(a parametric signal: PRBS, sine sweep, sine, fed into a torque or velocity
set-point or the torque offset) and a **recorder** (N channels chosen by
writing CiA 301 mapping entries ``index << 16 | sub << 8 | bits`` into
channel-selection objects, a sample period in loop cycles, a trigger, a state,
and the samples read back by SDO). This module parses and validates the
vocabulary of ``driver.toml`` that describes them (see ``docs/canopen_drives.md``,
"Drive generator and recorder"), maps an excitation *recipe* onto the
generator's parameters, and computes the signal the generator plays from the
parameter values it stores, for the host (to compare with what it meant) and
the emulated twin (which plays it).

All pure: dicts in, dataclasses and arrays out.

Example
-------
>>> bits = prbs_bits(4, (3,), 15)
>>> "".join(str(b) for b in bits)
'111101011001000'
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NoReturn

import numpy as np

from hilident.errors import ConfigError

if TYPE_CHECKING:  # canopen_objects imports this module
    from hilident.protocol.canopen_objects import ObjectAddress

__all__ = [
    "KIND_PARAMETERS",
    "MAX_LEN_SEQ_TAPS",
    "SCALE_KINDS",
    "TARGET_ROLES",
    "GeneratorKind",
    "GeneratorSettings",
    "GeneratorSpec",
    "Parameter",
    "RecorderCapability",
    "RecorderSpec",
    "generator_output",
    "parse_recorder",
    "plan_generator",
    "prbs_bits",
]

#: Feedback taps of :func:`scipy.signal.max_len_seq` per register length: the sequence of
#: :func:`hilident.signals.generators.prbs`. ``taps = "max_len_seq"`` in a driver description names them.
MAX_LEN_SEQ_TAPS = {
    2: (1,), 3: (2,), 4: (3,), 5: (3,), 6: (5,), 7: (6,), 8: (7, 6, 1), 9: (5,), 10: (7,), 11: (9,),
    12: (11, 10, 4), 13: (12, 11, 8), 14: (13, 12, 2), 15: (14,), 16: (15, 13, 4), 17: (14,), 18: (11,),
    19: (18, 17, 14), 20: (17,), 21: (19,), 22: (21,), 23: (18,), 24: (23, 22, 17), 25: (22,), 26: (25, 24, 20),
    27: (26, 25, 22), 28: (25,), 29: (27,), 30: (29, 28, 7), 31: (28,), 32: (31, 30, 10),
}
#: Set-points a generator can feed, by the role of the object they stand for.
TARGET_ROLES = ("target_torque", "torque_offset", "target_velocity")
#: A parameter's ``scale`` may name how torque, velocity or position objects of the drive scale.
SCALE_KINDS = ("torque", "velocity", "position")
#: The parameters each generator kind needs (``duration_s`` is optional for every kind).
KIND_PARAMETERS = {
    "prbs": ("amplitude", "register_length", "clock_divider"),
    "chirp": ("amplitude", "f_start_hz", "f_end_hz", "duration_s"),
    "sine": ("amplitude", "frequency_hz"),
}
_RECORDER_OBJECTS = {  # key -> the host writes it
    "control": True, "state": False, "trigger": True, "sample_period": True, "samples": True, "recorded": False,
}
_GENERATOR_OBJECTS = {"control": True, "state": False, "kind": True, "target": True}
_DOMAIN, _OCTET_STRING = 0x0F, 0x0A
_UNSIGNED32 = 0x07


@dataclass(frozen=True)
class Parameter:
    """One generator parameter: its object, SI value per raw unit and the SI range the drive accepts.

    ``scale`` is a number, or ``"torque"``/``"velocity"``/``"position"``: the
    scaling of the drive's torque (per mille of the rated torque), velocity or
    position objects, resolved when the rated torque is known.
    """

    name: str
    address: ObjectAddress
    scale: float | str = 1.0
    minimum: float | None = None
    maximum: float | None = None


@dataclass(frozen=True)
class GeneratorKind:
    """One signal the generator plays.

    Attributes
    ----------
    name : {"prbs", "chirp", "sine"}
        The hilident excitation kind it plays.
    code : int
        Value written to the generator's kind object.
    parameters : dict
        Parameter name -> :class:`Parameter`.
    method : str
        Chirp: ``"linear"`` or ``"logarithmic"``.
    taps : dict
        PRBS: register length -> feedback taps (the :func:`prbs_bits` convention); empty: the sequence is
        not described (the host cannot predict it).
    seed : int
        PRBS: initial register state, bit ``i`` = register cell ``i`` (all ones: ``2**n - 1``, given as -1).
    """

    name: str
    code: int
    parameters: dict
    method: str = ""
    taps: dict = field(default_factory=dict)
    seed: int = -1


@dataclass(frozen=True)
class GeneratorSpec:
    """The ``[canopen.generator]`` table."""

    control: ObjectAddress
    state: ObjectAddress
    kind: ObjectAddress | None
    target: ObjectAddress
    commands: dict[str, int]
    states: dict[str, int]
    targets: dict[str, int]
    kinds: dict[str, GeneratorKind]
    output: ObjectAddress | None = None
    output_scale: float | str = 1.0


@dataclass(frozen=True)
class RecorderSpec:
    """The ``[canopen.recorder]`` table."""

    control: ObjectAddress
    state: ObjectAddress
    trigger: ObjectAddress
    sample_period: ObjectAddress
    samples: ObjectAddress
    recorded: ObjectAddress
    commands: dict[str, int]
    states: dict[str, int]
    triggers: dict[str, int]
    sample_periods: tuple[int, ...]
    max_samples: int
    channels: tuple[ObjectAddress, ...]
    buffers: tuple[ObjectAddress, ...]
    interleaved: bool
    block_transfer: bool


@dataclass(frozen=True)
class RecorderCapability:
    """A drive's recorder and (optionally) its generator."""

    recorder: RecorderSpec
    generator: GeneratorSpec | None
    source: str = ""

    def objects(self) -> dict[str, ObjectAddress]:
        """Dotted key -> ObjectAddress of every object the description references."""
        out: dict[str, ObjectAddress] = {}
        r = self.recorder
        for key in _RECORDER_OBJECTS:
            out[f"canopen.recorder.{key}"] = getattr(r, key)
        for i, a in enumerate(r.channels):
            out[f"canopen.recorder.channels[{i}]"] = a
        for i, a in enumerate(r.buffers):
            out[f"canopen.recorder.buffer{'s' if not r.interleaved else ''}[{i}]"] = a
        g = self.generator
        if g is not None:
            for key in _GENERATOR_OBJECTS:
                if getattr(g, key) is not None:
                    out[f"canopen.generator.{key}"] = getattr(g, key)
            if g.output is not None:
                out["canopen.generator.output"] = g.output
            for kind in g.kinds.values():
                for p in kind.parameters.values():
                    out[f"canopen.generator.kinds.{kind.name}.{p.name}"] = p.address
        return out


# --- parsing ------------------------------------------------------------------------------------


def parse_recorder(sections: dict, source: str = "", od=None) -> RecorderCapability | None:
    """The recorder and generator a driver description declares, validated (None: it declares no recorder).

    Parameters
    ----------
    sections : dict
        The parsed ``driver.toml``.
    source : str
        Its path, for messages.
    od : canopen.ObjectDictionary, optional
        The drive's EDS: every object named must exist in it with a compatible access and type.

    Raises
    ------
    ConfigError
        A key is missing or malformed, or names an object the EDS lacks; the message names the dotted key
        and ``source``.
    """
    co = sections.get("canopen")
    if not isinstance(co, dict):
        co = {}
    rec, gen = co.get("recorder"), co.get("generator")
    if rec is None:
        if gen is not None:
            raise ConfigError("canopen.generator", "a generator needs a [canopen.recorder] to record what it plays",
                              source)
        return None
    p = _Parser(source, od)
    recorder = p.recorder(p.table(rec, "canopen.recorder"))
    generator = p.generator(p.table(gen, "canopen.generator")) if gen is not None else None
    cap = RecorderCapability(recorder, generator, source)
    if od is not None:
        p.check_objects(cap)
    return cap


class _Parser:
    def __init__(self, source: str, od):
        self.source, self.od = source, od

    def fail(self, key: str, text: str) -> NoReturn:
        raise ConfigError(key, text, self.source)

    def table(self, value, key: str) -> dict:
        if not isinstance(value, dict):
            self.fail(key, f"must be a table, got {value!r}"[:200])
        return value

    def address(self, value, key: str) -> ObjectAddress:
        from hilident.protocol.canopen_objects import parse_address

        if value is None:
            self.fail(key, 'is required: an object address like "0x2500:1"')
        return parse_address(value, key, self.source)

    def integer(self, value, key: str, low: int, high: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            self.fail(key, f"must be an integer {low}..{high}, got {value!r}")
        return value

    def codes(self, t: dict, key: str, names: tuple[str, ...], defaults: dict) -> dict:
        value = t.get(key.rsplit(".", 1)[-1], defaults)
        if not isinstance(value, dict):
            self.fail(key, f"must be a table of {', '.join(f'{n} = <int>' for n in names)}")
        out = {}
        for name in names:
            if name not in value:
                self.fail(f"{key}.{name}", "is required")
            out[name] = self.integer(value[name], f"{key}.{name}", 0, 0xFFFF)
        unknown = set(value) - set(names)
        if unknown:
            self.fail(f"{key}.{min(unknown)}", f"is not one of {', '.join(names)}")
        return out

    def recorder(self, t: dict) -> RecorderSpec:
        k = "canopen.recorder"
        objs = {name: self.address(t.get(name), f"{k}.{name}") for name in _RECORDER_OBJECTS}
        channels = t.get("channels")
        if not isinstance(channels, list) or not channels:
            self.fail(f"{k}.channels", "must list the channel-selection objects, e.g. [\"0x2501:1\", \"0x2501:2\"]")
        chans = tuple(self.address(c, f"{k}.channels") for c in channels)
        if ("buffer" in t) == ("buffers" in t):
            self.fail(f"{k}.buffer", "give either buffer (one interleaved DOMAIN) or buffers (one DOMAIN per channel)")
        buffers: tuple[ObjectAddress, ...]
        if "buffer" in t:
            buffers, interleaved = (self.address(t["buffer"], f"{k}.buffer"),), True
        else:
            if not isinstance(t["buffers"], list) or len(t["buffers"]) != len(chans):
                self.fail(f"{k}.buffers", f"must list one DOMAIN per channel ({len(chans)})")
            buffers, interleaved = tuple(self.address(b, f"{k}.buffers") for b in t["buffers"]), False
        periods = t.get("sample_periods", [1])
        if (not isinstance(periods, list) or not periods
                or any(isinstance(x, bool) or not isinstance(x, int) or not 1 <= x <= 65535 for x in periods)):
            self.fail(f"{k}.sample_periods", f"must list the allowed sample periods in loop cycles, got {periods!r}")
        encoding = t.get("channel_encoding", "mapping_entry")
        if encoding != "mapping_entry":
            self.fail(f"{k}.channel_encoding", f'must be "mapping_entry" (index << 16 | sub << 8 | bits), got '
                                               f"{encoding!r}")
        block = t.get("block_transfer", True)
        if not isinstance(block, bool):
            self.fail(f"{k}.block_transfer", f"must be true or false, got {block!r}")
        return RecorderSpec(
            **objs,
            commands=self.codes(t, f"{k}.commands", ("stop", "start"), {"stop": 0, "start": 1}),
            states=self.codes(t, f"{k}.states", ("idle", "waiting", "recording", "done"),
                              {"idle": 0, "waiting": 1, "recording": 2, "done": 3}),
            triggers=self.codes(t, f"{k}.triggers", ("immediate", "generator"), {"immediate": 0, "generator": 1}),
            sample_periods=tuple(sorted(set(periods))),
            max_samples=self.integer(t.get("max_samples"), f"{k}.max_samples", 1, 2**31 - 1),
            channels=chans, buffers=buffers, interleaved=interleaved, block_transfer=block)

    def parameter(self, name: str, value, key: str) -> Parameter:
        if not isinstance(value, dict):
            self.fail(key, 'must be { object = "0x2511:1", scale = <number or "torque">, min = .., max = .. }')
        scale = value.get("scale", 1.0)
        if isinstance(scale, bool) or not (scale in SCALE_KINDS or (
                isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0)):
            self.fail(f"{key}.scale", f"must be a positive number or one of {SCALE_KINDS}, got {scale!r}")
        bounds: list[float | None] = []
        for end in ("min", "max"):
            b = value.get(end)
            if b is not None and (isinstance(b, bool) or not isinstance(b, (int, float)) or not math.isfinite(b)):
                self.fail(f"{key}.{end}", f"must be a number, got {b!r}")
            bounds.append(None if b is None else float(b))
        low, high = bounds
        if low is not None and high is not None and low > high:
            self.fail(f"{key}.min", f"{low:g} exceeds max {high:g}")
        unknown = set(value) - {"object", "scale", "min", "max"}
        if unknown:
            self.fail(f"{key}.{min(unknown)}", "is not a parameter key (object, scale, min, max)")
        return Parameter(name, self.address(value.get("object"), f"{key}.object"),
                         scale if isinstance(scale, str) else float(scale), low, high)

    def kind(self, name: str, t, key: str) -> GeneratorKind:
        if name not in KIND_PARAMETERS:
            self.fail(key, f"is not a generator kind hilident plays ({', '.join(KIND_PARAMETERS)})")
        t = self.table(t, key)
        code = self.integer(t.get("code"), f"{key}.code", 0, 0xFFFF)
        params = {}
        for pname in (*KIND_PARAMETERS[name], "duration_s"):
            if pname in t:
                params[pname] = self.parameter(pname, t[pname], f"{key}.{pname}")
            elif pname != "duration_s":
                self.fail(f"{key}.{pname}", f"is required for a {name} generator")
        extra = set(t) - set(params) - {"code", "method", "taps", "seed"}
        if extra:
            self.fail(f"{key}.{min(extra)}", f"is not a key of a {name} generator")
        method, taps, seed = "", {}, -1
        if name == "chirp":
            method = t.get("method", "linear")
            if method not in ("linear", "logarithmic"):
                self.fail(f"{key}.method", f'must be "linear" or "logarithmic", got {method!r}')
        if name == "prbs":
            taps = self.taps(t.get("taps"), f"{key}.taps")
            seed = t.get("seed", -1)
            if isinstance(seed, str):
                try:
                    seed = int(seed, 0)
                except ValueError:
                    self.fail(f"{key}.seed", f"must be an integer (register state), got {seed!r}")
            self.integer(seed, f"{key}.seed", -1, 2**32 - 1)
            if seed == 0:
                self.fail(f"{key}.seed", "0 locks a PRBS register: its sequence would be constant")
        return GeneratorKind(name, code, params, method, taps, seed)

    def taps(self, value, key: str) -> dict:
        if value is None:
            return {}
        if value == "max_len_seq":
            return dict(MAX_LEN_SEQ_TAPS)
        if not isinstance(value, dict):
            self.fail(key, f'must be "max_len_seq" or a table register_length = [taps], got {value!r}')
        out = {}
        for length, taps in value.items():
            n = int(length) if str(length).isdigit() else 0
            if not 2 <= n <= 32 or not isinstance(taps, list) or not taps or any(
                    isinstance(x, bool) or not isinstance(x, int) or not 0 < x < n for x in taps):
                self.fail(f"{key}.{length}", f"must map a register length 2..32 to taps 1..length-1, got {taps!r}")
            out[n] = tuple(taps)
        return out

    def generator(self, t: dict) -> GeneratorSpec:
        k = "canopen.generator"
        objs = {name: self.address(t.get(name), f"{k}.{name}") for name in ("control", "state", "target")}
        kinds_table = self.table(t.get("kinds"), f"{k}.kinds")
        if not kinds_table:
            self.fail(f"{k}.kinds", "must describe at least one kind (prbs, chirp, sine)")
        kinds = {name: self.kind(name, v, f"{k}.kinds.{name}") for name, v in kinds_table.items()}
        kind_object = self.address(t["kind"], f"{k}.kind") if "kind" in t else None
        if kind_object is None and len(kinds) > 1:
            self.fail(f"{k}.kind", "is required when the generator has more than one kind")
        targets = t.get("targets")
        if not isinstance(targets, dict) or not targets or any(r not in TARGET_ROLES for r in targets):
            self.fail(f"{k}.targets", f"must map set-point roles ({', '.join(TARGET_ROLES)}) to the code written to "
                                      f"the target object, got {targets!r}")
        targets = {r: self.integer(c, f"{k}.targets.{r}", 0, 0xFFFF) for r, c in targets.items()}
        output = self.address(t["output"], f"{k}.output") if "output" in t else None
        scale = t.get("output_scale", 1.0)
        if isinstance(scale, bool) or not (scale in SCALE_KINDS or (isinstance(scale, (int, float)) and scale > 0)):
            self.fail(f"{k}.output_scale", f"must be a positive number or one of {SCALE_KINDS}, got {scale!r}")
        return GeneratorSpec(
            **objs, kind=kind_object,
            commands=self.codes(t, f"{k}.commands", ("stop", "start"), {"stop": 0, "start": 1}),
            states=self.codes(t, f"{k}.states", ("idle", "running", "done"), {"idle": 0, "running": 1, "done": 2}),
            targets=targets, kinds=kinds, output=output,
            output_scale=scale if isinstance(scale, str) else float(scale))

    def check_objects(self, cap: RecorderCapability) -> None:
        """Every object exists in the EDS, the host can write what it writes and read what it reads."""
        written = {f"canopen.recorder.{k}" for k, w in _RECORDER_OBJECTS.items() if w}
        written |= {f"canopen.generator.{k}" for k, w in _GENERATOR_OBJECTS.items() if w}
        for key, addr in cap.objects().items():
            var = self.od.get_variable(addr.index, addr.subindex)
            if var is None:
                self.fail(key, f"object {addr} is not in the EDS")
            write = key in written or ".kinds." in key or key.startswith("canopen.recorder.channels")
            if write and not var.writable:
                self.fail(key, f"object {addr} is read-only in the EDS; the host must write it")
            if not write and not var.readable:
                self.fail(key, f"object {addr} is write-only in the EDS; the host must read it")
            buffer = key.startswith("canopen.recorder.buffer")
            if buffer and var.data_type not in (_DOMAIN, _OCTET_STRING):
                self.fail(key, f"object {addr} must be a DOMAIN (or OCTET_STRING) to hold samples, the EDS says "
                               f"data type 0x{var.data_type:04X}")
            if not buffer and var.data_type in (_DOMAIN, _OCTET_STRING, 0x09):
                self.fail(key, f"object {addr} must be a number, the EDS says data type 0x{var.data_type:04X}")
            if key.startswith("canopen.recorder.channels") and var.data_type != _UNSIGNED32:
                self.fail(key, f"object {addr} takes a mapping entry: it must be UNSIGNED32, the EDS says "
                               f"data type 0x{var.data_type:04X}")


# --- signals ------------------------------------------------------------------------------------


def prbs_bits(register_length: int, taps, length: int, seed: int = -1) -> np.ndarray:
    """``length`` bits of a Fibonacci shift register, in :func:`scipy.signal.max_len_seq`'s convention.

    Each step outputs cell ``i`` (the cell at the moving index), then stores
    there the XOR of it with the cells ``taps`` further on. With the taps of
    :data:`MAX_LEN_SEQ_TAPS` and all cells one (``seed = -1``) it is exactly
    ``scipy.signal.max_len_seq(register_length)``.

    Parameters
    ----------
    register_length : int
    taps : sequence of int
    length : int
    seed : int
        Initial cells, bit ``i`` = cell ``i``; -1: all ones.
    """
    n = int(register_length)
    state = [1] * n if seed < 0 else [(seed >> i) & 1 for i in range(n)]
    out = np.empty(int(length), dtype=np.int8)
    idx = 0
    period = 2**n - 1
    first = []
    for i in range(min(int(length), period)):
        bit = state[idx]
        out[i] = bit
        fb = bit
        for t in taps:
            fb ^= state[(t + idx) % n]
        state[idx] = fb
        idx = (idx + 1) % n
        first.append(bit)
    if length > period:  # a maximal sequence repeats after 2**n - 1 bits (a non-maximal one earlier: then not used)
        out[:] = np.resize(np.asarray(first, dtype=np.int8), int(length))
    return out


def generator_output(kind: GeneratorKind, values: dict, ticks: np.ndarray, loop_rate_hz: float) -> np.ndarray:
    """The generator's output (SI) at loop ticks ``ticks`` counted from its start.

    ``values`` are the parameters in SI (and raw integers for
    ``register_length`` and ``clock_divider``, in loop cycles per bit). Past
    ``duration_s`` (when given) the output is 0. The signals:

    * prbs: ``+amplitude`` for bit 1, ``-amplitude`` for bit 0, bit ``tick // clock_divider`` of the
      register's sequence (:func:`prbs_bits`, repeating with period ``2**n - 1``);
    * sine: ``amplitude * sin(2 pi f t)``;
    * chirp: ``amplitude * sin(phase(t))`` with the phase of :func:`scipy.signal.chirp` (linear or
      logarithmic) from ``f_start_hz`` to ``f_end_hz`` over ``duration_s``.
    """
    t = np.asarray(ticks, dtype=np.int64)
    tau = t / float(loop_rate_hz)
    a = float(values["amplitude"])
    if kind.name == "prbs":
        n = int(values["register_length"])
        taps = kind.taps.get(n)
        if taps is None:
            raise ValueError(f"the PRBS sequence of register length {n} is not described")
        period = 2**n - 1
        bits = prbs_bits(n, taps, period, kind.seed)
        y = np.where(bits[(t // int(values["clock_divider"])) % period] == 1, a, -a).astype(float)
    elif kind.name == "sine":
        y = a * np.sin(2 * np.pi * float(values["frequency_hz"]) * tau)
    else:
        f0, f1, big_t = float(values["f_start_hz"]), float(values["f_end_hz"]), float(values["duration_s"])
        if kind.method == "logarithmic":
            beta = math.log(f1 / f0)
            phase = 2 * np.pi * f0 * big_t / beta * np.expm1(tau * beta / big_t)
        else:
            phase = 2 * np.pi * (f0 * tau + 0.5 * (f1 - f0) / big_t * tau * tau)
        y = a * np.sin(phase)
    if "duration_s" in values:
        y = np.where(tau < float(values["duration_s"]) - 0.5 / loop_rate_hz, y, 0.0)
    return y


@dataclass(frozen=True)
class GeneratorSettings:
    """What the host writes to the generator for one run.

    Attributes
    ----------
    kind : GeneratorKind
    target : str
        Role of the set-point it feeds.
    raw : dict
        Parameter name -> raw value to write.
    values : dict
        Parameter name -> the SI value the drive stores (raw times scale).
    """

    kind: GeneratorKind
    target: str
    raw: dict
    values: dict


def plan_generator(cap: RecorderCapability, recipe: dict, target: str, samples: int, sample_period: int,
                   loop_rate_hz: float, scales: dict) -> GeneratorSettings:
    """Map an excitation recipe onto the generator's parameters, or refuse it before anything moves.

    Parameters
    ----------
    cap : RecorderCapability
    recipe : dict
        ``kind``, ``amplitude`` (SI of the mode), ``f_min_hz``, ``f_max_hz``, ``frequency_hz``,
        ``duration_s``, ``register_length``, ``clock_divider`` (samples per bit), ``chirp_method``;
        optionally ``amplitude_key``, the config key the amplitude came from (messages name it; default
        ``"excitation.amplitude_nm"``).
    target : str
        Role of the set-point the mode excites (``target_torque``, ``torque_offset``, ``target_velocity``).
    samples : int
        Samples the recorder takes.
    sample_period : int
        Loop cycles per recorded sample.
    loop_rate_hz : float
    scales : dict
        ``"torque"``/``"velocity"``/``"position"`` -> SI per raw unit of the drive's objects of that kind.

    Raises
    ------
    ConfigError
        The generator cannot play it: the message names the ``[excitation]`` key and the driver's generator.
    """
    kind = _playable_kind(cap, recipe, target, samples, sample_period)
    where = f"the drive's generator ([canopen.generator] of {cap.source})"
    wanted = _wanted_parameters(kind, recipe, samples, sample_period, loop_rate_hz, where)
    raw, values = {}, {}
    for name, (key, si) in wanted.items():
        raw[name] = _raw_parameter(kind, name, key, si, scales, where)
        p = kind.parameters[name]
        scale = scales[p.scale] if isinstance(p.scale, str) else p.scale
        values[name] = raw[name] * scale if name not in ("register_length", "clock_divider") else raw[name]
    return GeneratorSettings(kind, target, raw, values)


def _playable_kind(cap: RecorderCapability, recipe: dict, target: str, samples: int, sample_period: int):
    """The generator's kind for ``recipe``, refused when the generator cannot feed ``target`` or the recorder
    cannot hold ``samples``."""
    g = cap.generator
    where = f"the drive's generator ([canopen.generator] of {cap.source})"
    kind_name = recipe.get("kind")
    if g is None:
        raise ConfigError("excitation.kind", f"{kind_name!r}: the driver describes no generator ([canopen.generator] "
                                             f"of {cap.source}); a recorder run needs one")
    if kind_name not in g.kinds:
        raise ConfigError("excitation.kind", f"{kind_name!r} cannot be played by {where}: it plays "
                                             f"{', '.join(g.kinds)}")
    kind = g.kinds[kind_name]
    if target not in g.targets:
        raise ConfigError("excitation.mode", f"{recipe.get('mode')!r} excites {target}; {where} feeds "
                                             f"{', '.join(g.targets)}")
    if samples > cap.recorder.max_samples:
        raise ConfigError("excitation.duration_s",
                          f"{samples} samples at a sample period of {sample_period} loop cycles exceed the "
                          f"recorder's {cap.recorder.max_samples} ([canopen.recorder] max_samples of {cap.source})")
    if kind.name == "chirp" and recipe.get("chirp_method", "linear") != kind.method:
        raise ConfigError("excitation.chirp_method", f"{recipe.get('chirp_method')!r}: {where} sweeps "
                                                     f"{kind.method}ly")
    return kind


def _wanted_parameters(kind, recipe: dict, samples: int, sample_period: int, loop_rate_hz: float,
                       where: str) -> dict[str, tuple[str, float]]:
    """Generator parameter -> (the ``[excitation]`` key it comes from, its SI value)."""
    amplitude_key = recipe.get("amplitude_key", "excitation.amplitude_nm")  # the mode's key: amplitude_mps, ...
    wanted = {"amplitude": (amplitude_key, float(recipe.get("amplitude", 0.0)))}
    if kind.name == "prbs":
        wanted["register_length"] = ("excitation.register_length", int(recipe.get("register_length", 0)))
        wanted["clock_divider"] = ("excitation.clock_divider", int(recipe.get("clock_divider", 1)) * sample_period)
        if kind.taps and wanted["register_length"][1] not in kind.taps:
            raise ConfigError("excitation.register_length", f"{wanted['register_length'][1]}: {where} describes its "
                                                            f"sequence for register lengths {sorted(kind.taps)}")
    elif kind.name == "chirp":
        wanted["f_start_hz"] = ("excitation.f_min_hz", float(recipe.get("f_min_hz", 0.0)))
        wanted["f_end_hz"] = ("excitation.f_max_hz", float(recipe.get("f_max_hz", 0.0)))
        wanted["duration_s"] = ("excitation.duration_s", float(recipe.get("duration_s", 0.0)))
    else:
        wanted["frequency_hz"] = ("excitation.frequency_hz", float(recipe.get("frequency_hz", 0.0)))
    if "duration_s" in kind.parameters and "duration_s" not in wanted:
        wanted["duration_s"] = ("excitation.duration_s", samples * sample_period / loop_rate_hz)
    return wanted


def _raw_parameter(kind, name: str, key: str, si: float, scales: dict, where: str) -> int:
    """The raw value of generator parameter ``name`` for ``si``, refused outside the parameter's range."""
    p = kind.parameters[name]
    scale = scales[p.scale] if isinstance(p.scale, str) else p.scale
    if (p.minimum is not None and si < p.minimum - 1e-12 * abs(si)) or (
            p.maximum is not None and si > p.maximum + 1e-12 * abs(si)):
        raise ConfigError(key, f"{si:g} is outside the range [{_show(p.minimum)}, {_show(p.maximum)}] of {where} "
                               f"({kind.name} {name}, object {p.address})")
    if name in ("register_length", "clock_divider"):
        return int(si)
    if name == "duration_s":  # never a cycle short of the last sample
        return math.ceil(si / scale - 1e-9)
    return round(si / scale)


def _show(x) -> str:
    return "-inf" if x is None else f"{x:g}"
