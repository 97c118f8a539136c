"""A drive's own signal generator and data recorder, as ``[canopen.generator]`` and
``[canopen.recorder]`` describe them.

Real drives cannot play an arbitrary table, but most have a **generator**
(a parametric signal: PRBS, sine sweep, sine, fed into a torque or velocity
set-point or the torque offset) and a **recorder** (N channels chosen by
writing CiA 301 mapping entries ``index << 16 | sub << 8 | bits`` into
channel-selection objects, a sample period in loop cycles, a trigger, a state,
and the samples read back by SDO). This module parses and validates the
vocabulary of ``driver.toml`` that describes them (see ``docs/canopen_drives.md``,
"Drive generator and recorder"), its keys declared as tables of
:mod:`hilident.config.schema` like every other table hilident reads, maps an excitation *recipe* onto the
generator's parameters, and computes the signal the generator plays from the
parameter values it stores, for the host (to compare with what it meant) and
the emulated twin (which plays it).

All pure: dicts in, dataclasses and arrays out.

Examples
--------
>>> bits = prbs_bits(4, (3,), 15)
>>> "".join(str(b) for b in bits)
'111101011001000'
"""

from __future__ import annotations

import builtins  # `object` is also a key of a generator parameter table: its type is `builtins.object`
import dataclasses
import math
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from hilident.config.schema import build_table, spec
from hilident.errors import ConfigError
from hilident.protocol.canopen_types import ObjectAddress, parse_address

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
    2: (1,),
    3: (2,),
    4: (3,),
    5: (3,),
    6: (5,),
    7: (6,),
    8: (7, 6, 1),
    9: (5,),
    10: (7,),
    11: (9,),
    12: (11, 10, 4),
    13: (12, 11, 8),
    14: (13, 12, 2),
    15: (14,),
    16: (15, 13, 4),
    17: (14,),
    18: (11,),
    19: (18, 17, 14),
    20: (17,),
    21: (19,),
    22: (21,),
    23: (18,),
    24: (23, 22, 17),
    25: (22,),
    26: (25, 24, 20),
    27: (26, 25, 22),
    28: (25,),
    29: (27,),
    30: (29, 28, 7),
    31: (28,),
    32: (31, 30, 10),
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
    "control": True,
    "state": False,
    "trigger": True,
    "sample_period": True,
    "samples": True,
    "recorded": False,
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
#
# The keys are declared as tables of :mod:`hilident.config.schema` below; what a table cannot say (either ``buffer`` or
# ``buffers``, one buffer per channel, the parameter tables each kind needs, PRBS taps and seed, the set-point roles,
# the objects in the EDS) is checked by the small functions after them.


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
            raise ConfigError(
                "canopen.generator", "a generator needs a [canopen.recorder] to record what it plays", source
            )
        return None
    recorder = _recorder(rec, source)
    generator = _generator(gen, source) if gen is not None else None
    cap = RecorderCapability(recorder, generator, source)
    if od is not None:
        _check_objects(cap, od, source)
    return cap


def _address(value: str, key: str, source: str) -> None:
    """A schema ``check``: ``value`` is an object address like ``"0x2500:1"``."""
    parse_address(value, key, source)


def _addresses(values: list[str], key: str, source: str) -> None:
    """A schema ``check``: a non-empty list of object addresses."""
    if not values:
        raise ConfigError(key, 'must list objects, e.g. ["0x2501:1", "0x2501:2"]', source)
    for value in values:
        _address(value, key, source)


def _sample_periods(values: list[int], key: str, source: str) -> None:
    """A schema ``check``: a non-empty list of sample periods 1..65535 (loop cycles)."""
    if not values or any(not 1 <= x <= 65535 for x in values):
        raise ConfigError(key, f"must list the allowed sample periods in loop cycles, got {values!r}", source)


def _scale(value: builtins.object, key: str, source: str) -> None:
    """A schema ``check``: a positive finite number, or one of :data:`SCALE_KINDS`."""
    positive = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
    if value not in SCALE_KINDS and not positive:
        raise ConfigError(key, f"must be a positive number or one of {SCALE_KINDS}, got {value!r}", source)


def _check_scale_is_no_bool(table: builtins.object, name: str, prefix: str, source: str) -> None:
    """A scale of ``true`` or ``false`` is refused as :func:`_scale` says (the schema, reading a key typed
    ``object``, would say "must be object")."""
    value = table.get(name) if isinstance(table, dict) else None
    if isinstance(value, bool):
        _scale(value, prefix + name, source)


def _scale_value(value: builtins.object) -> float | str:
    """A scale :func:`_scale` accepted, as a float or the name of a kind of object."""
    if isinstance(value, str):
        return value
    if isinstance(value, (int, float)):
        return float(value)
    raise TypeError(f"a scale is a number or a name, got {value!r}")  # _scale refused anything else


def _object(doc: str):
    """A required object address key."""
    return spec(check=_address, doc=doc)


def _code(doc: str = ""):
    """A required UNSIGNED16 code."""
    return spec(ge=0, le=0xFFFF, doc=doc)


@dataclass(frozen=True, kw_only=True)
class _StartStop:
    """``commands``: the codes written to a control object."""

    stop: int = _code("stops (the recorder: disarms)")
    start: int = _code("starts (the recorder: arms, it then waits for its trigger)")


@dataclass(frozen=True, kw_only=True)
class _RecorderStates:
    """``[canopen.recorder.states]``: the codes the recorder's state object reports."""

    idle: int = _code()
    waiting: int = _code("armed, waiting for its trigger")
    recording: int = _code()
    done: int = _code()


@dataclass(frozen=True, kw_only=True)
class _RecorderTriggers:
    """``[canopen.recorder.triggers]``: the codes of the trigger object."""

    immediate: int = _code()
    generator: int = _code("the generator's start")


@dataclass(frozen=True, kw_only=True)
class _RecorderTable:
    """``[canopen.recorder]``."""

    control: str = _object("object the host writes commands.start (arm) or commands.stop to")
    state: str = _object("object reporting states.idle, waiting (for its trigger), recording, done")
    trigger: str = _object("object taking triggers.immediate or triggers.generator")
    sample_period: str = _object("object taking the sample period in loop cycles")
    samples: str = _object("object taking the number of samples to record")
    recorded: str = _object("object reporting the number of samples recorded")
    channels: list[str] = spec(
        check=_addresses,
        max_items=64,
        doc="channel-selection objects (UNSIGNED32 mapping entries): the most channels a run records",
    )
    buffer: str | None = spec(None, check=_address, doc="one interleaved DOMAIN (or give buffers)")
    buffers: list[str] | None = spec(None, check=_addresses, max_items=64, doc="one DOMAIN per channel")
    sample_periods: list[int] = spec([1], check=_sample_periods, doc="allowed sample periods, loop cycles")
    channel_encoding: str = spec(
        "mapping_entry",
        choices=("mapping_entry",),
        doc="a channel is chosen by its mapping entry index << 16 | sub << 8 | bits",
    )
    block_transfer: bool = spec(True, doc="read the buffers by SDO block upload, else segmented")
    commands: _StartStop = spec(_StartStop(stop=0, start=1))
    states: _RecorderStates = spec(_RecorderStates(idle=0, waiting=1, recording=2, done=3))
    triggers: _RecorderTriggers = spec(_RecorderTriggers(immediate=0, generator=1))
    max_samples: int = spec(ge=1, le=2**31 - 1, doc="most samples per channel the recorder holds")


@dataclass(frozen=True, kw_only=True)
class _GeneratorStates:
    """``[canopen.generator.states]``: the codes the generator's state object reports."""

    idle: int = _code()
    running: int = _code()
    done: int = _code()


@dataclass(frozen=True, kw_only=True)
class _TargetCodes:
    """``[canopen.generator.targets]``: the code written to the target object per set-point role (at least one)."""

    target_torque: int | None = spec(None, ge=0, le=0xFFFF)
    torque_offset: int | None = spec(None, ge=0, le=0xFFFF)
    target_velocity: int | None = spec(None, ge=0, le=0xFFFF)


@dataclass(frozen=True, kw_only=True)
class _GeneratorTable:
    """``[canopen.generator]``; its ``kinds`` are read by :func:`_kind`."""

    control: str = _object("object the host writes commands.start or commands.stop to")
    state: str = _object("object reporting states.idle, running, done")
    target: str = _object("object taking the code of targets for the set-point the signal feeds")
    kinds: dict = spec(doc="kind name (prbs, chirp, sine) -> its table: code, parameters, ...")
    kind: str | None = spec(None, check=_address, doc="object taking the kind's code; required with more than one kind")
    targets: _TargetCodes = spec(doc="set-point role -> code written to the target object")
    output: str | None = spec(None, check=_address, doc="object reporting the present output, recordable")
    output_scale: builtins.object = spec(
        1.0, check=_scale, doc='SI per raw unit of output: a number, or "torque", "velocity", "position"'
    )
    commands: _StartStop = spec(_StartStop(stop=0, start=1))
    states: _GeneratorStates = spec(_GeneratorStates(idle=0, running=1, done=2))


@dataclass(frozen=True, kw_only=True)
class _ParameterTable:
    """One generator parameter: ``{ object = "0x2511:1", scale = .., min = .., max = .. }``."""

    object: str = _object("object the host writes the raw value to")
    scale: builtins.object = spec(
        1.0,
        check=_scale,
        doc='SI per raw unit: a number, or "torque", "velocity", "position" (the drive\'s scaling of such objects)',
    )
    min: float | None = spec(None, doc="lowest SI value the drive accepts")
    max: float | None = spec(None, doc="highest SI value the drive accepts")


@dataclass(frozen=True, kw_only=True)
class _KindTable:
    """The keys of ``[canopen.generator.kinds.<kind>]`` every kind has; :func:`_kind` reads the rest."""

    open_table: ClassVar[bool] = True  # the kind's parameter tables, PRBS taps and seed
    code: int = _code("value written to the generator's kind object")
    method: str = spec("linear", choices=("linear", "logarithmic"), doc="chirp: how its frequency sweeps")


_KIND_KEYS = ("code", "method", "taps", "seed")


def _to_address(text: str) -> ObjectAddress:
    """An address a schema ``check`` accepted."""
    return parse_address(text)


def _recorder(raw: builtins.object, source: str) -> RecorderSpec:
    """``[canopen.recorder]``: its schema, then either ``buffer`` or one of ``buffers`` per channel."""
    k = "canopen.recorder"
    t = build_table(_RecorderTable, raw, f"{k}.", source)
    if (t.buffer is None) == (t.buffers is None):
        raise ConfigError(
            f"{k}.buffer", "give either buffer (one interleaved DOMAIN) or buffers (one DOMAIN per channel)", source
        )
    if t.buffers is not None and len(t.buffers) != len(t.channels):
        raise ConfigError(f"{k}.buffers", f"must list one DOMAIN per channel ({len(t.channels)})", source)
    buffers = [t.buffer] if t.buffer is not None else t.buffers or []
    return RecorderSpec(
        control=_to_address(t.control),
        state=_to_address(t.state),
        trigger=_to_address(t.trigger),
        sample_period=_to_address(t.sample_period),
        samples=_to_address(t.samples),
        recorded=_to_address(t.recorded),
        commands=dataclasses.asdict(t.commands),
        states=dataclasses.asdict(t.states),
        triggers=dataclasses.asdict(t.triggers),
        sample_periods=tuple(sorted(set(t.sample_periods))),
        max_samples=t.max_samples,
        channels=tuple(map(_to_address, t.channels)),
        buffers=tuple(map(_to_address, buffers)),
        interleaved=t.buffer is not None,
        block_transfer=t.block_transfer,
    )


def _check_target_roles(raw: builtins.object, source: str) -> None:
    """``targets`` names at least one set-point role and no other key (the schema would name the key itself)."""
    targets = raw.get("targets") if isinstance(raw, dict) else None
    if isinstance(targets, dict) and (not targets or any(r not in TARGET_ROLES for r in targets)):
        raise ConfigError(
            "canopen.generator.targets",
            f"must map set-point roles ({', '.join(TARGET_ROLES)}) to the "
            f"code written to the target object, got {targets!r}",
            source,
        )


def _generator(raw: builtins.object, source: str) -> GeneratorSpec:
    """``[canopen.generator]``: its schema, its kinds, and a kind object when there is more than one kind."""
    k = "canopen.generator"
    _check_target_roles(raw, source)
    _check_scale_is_no_bool(raw, "output_scale", f"{k}.", source)
    t = build_table(_GeneratorTable, raw, f"{k}.", source)
    if not t.kinds:
        raise ConfigError(f"{k}.kinds", "must describe at least one kind (prbs, chirp, sine)", source)
    kinds = {name: _kind(name, value, f"{k}.kinds.{name}", source) for name, value in t.kinds.items()}
    if t.kind is None and len(kinds) > 1:
        raise ConfigError(f"{k}.kind", "is required when the generator has more than one kind", source)
    targets = {role: code for role, code in dataclasses.asdict(t.targets).items() if code is not None}
    return GeneratorSpec(
        control=_to_address(t.control),
        state=_to_address(t.state),
        target=_to_address(t.target),
        kind=None if t.kind is None else _to_address(t.kind),
        commands=dataclasses.asdict(t.commands),
        states=dataclasses.asdict(t.states),
        targets=targets,
        kinds=kinds,
        output=None if t.output is None else _to_address(t.output),
        output_scale=_scale_value(t.output_scale),
    )


def _kind(name: str, raw: builtins.object, key: str, source: str) -> GeneratorKind:
    """One ``[canopen.generator.kinds.<name>]``: its keys, the parameters :data:`KIND_PARAMETERS` asks, PRBS taps
    and seed."""
    if name not in KIND_PARAMETERS:
        raise ConfigError(key, f"is not a generator kind hilident plays ({', '.join(KIND_PARAMETERS)})", source)
    t = build_table(_KindTable, raw, f"{key}.", source)
    assert isinstance(raw, dict)  # build_table refused anything else
    params = {}
    for pname in (*KIND_PARAMETERS[name], "duration_s"):
        if pname in raw:
            params[pname] = _parameter(pname, raw[pname], f"{key}.{pname}", source)
        elif pname != "duration_s":
            raise ConfigError(f"{key}.{pname}", f"is required for a {name} generator", source)
    extra = set(raw) - set(params) - set(_KIND_KEYS)
    if extra:
        raise ConfigError(f"{key}.{min(extra)}", f"is not a key of a {name} generator", source)
    if name != "prbs":
        return GeneratorKind(name, t.code, params, t.method if name == "chirp" else "")
    return GeneratorKind(
        name,
        t.code,
        params,
        "",
        _taps(raw.get("taps"), f"{key}.taps", source),
        _seed(raw.get("seed", -1), f"{key}.seed", source),
    )


def _parameter(name: str, raw: builtins.object, key: str, source: str) -> Parameter:
    """One generator parameter table; ``min`` must not exceed ``max``."""
    _check_scale_is_no_bool(raw, "scale", f"{key}.", source)
    t = build_table(_ParameterTable, raw, f"{key}.", source)
    if t.min is not None and t.max is not None and t.min > t.max:
        raise ConfigError(f"{key}.min", f"{t.min:g} exceeds max {t.max:g}", source)
    return Parameter(name, _to_address(t.object), _scale_value(t.scale), t.min, t.max)


def _taps(value: builtins.object, key: str, source: str) -> dict[int, tuple[int, ...]]:
    """PRBS ``taps``: absent (the sequence is not described), ``"max_len_seq"``, or register length -> taps."""
    if value is None:
        return {}
    if value == "max_len_seq":
        return dict(MAX_LEN_SEQ_TAPS)
    if not isinstance(value, dict):
        raise ConfigError(key, f'must be "max_len_seq" or a table register_length = [taps], got {value!r}', source)
    out = {}
    for length, taps in value.items():
        n = int(length) if str(length).isdigit() else 0
        if (
            not 2 <= n <= 32
            or not isinstance(taps, list)
            or not taps
            or any(isinstance(x, bool) or not isinstance(x, int) or not 0 < x < n for x in taps)
        ):
            raise ConfigError(
                f"{key}.{length}", f"must map a register length 2..32 to taps 1..length-1, got {taps!r}", source
            )
        out[n] = tuple(taps)
    return out


def _seed(value: builtins.object, key: str, source: str) -> int:
    """PRBS ``seed``: an integer or integer text (``"0x35"``), -1 (all ones) or a non-zero register state."""
    if isinstance(value, str):
        try:
            value = int(value, 0)
        except ValueError:
            raise ConfigError(key, f"must be an integer (register state), got {value!r}", source) from None
    if isinstance(value, bool) or not isinstance(value, int) or not -1 <= value <= 2**32 - 1:
        raise ConfigError(key, f"must be an integer -1..{2**32 - 1}, got {value!r}", source)
    if value == 0:
        raise ConfigError(key, "0 locks a PRBS register: its sequence would be constant", source)
    return value


def _check_objects(cap: RecorderCapability, od, source: str) -> None:
    """Every object exists in the EDS, the host can write what it writes and read what it reads, buffers hold
    samples, channel-selection objects take a mapping entry and the others are numbers."""
    written = {f"canopen.recorder.{k}" for k, w in _RECORDER_OBJECTS.items() if w}
    written |= {f"canopen.generator.{k}" for k, w in _GENERATOR_OBJECTS.items() if w}
    for key, addr in cap.objects().items():
        var = od.get_variable(addr.index, addr.subindex)
        if var is None:
            raise ConfigError(key, f"object {addr} is not in the EDS", source)
        write = key in written or ".kinds." in key or key.startswith("canopen.recorder.channels")
        if write and not var.writable:
            raise ConfigError(key, f"object {addr} is read-only in the EDS; the host must write it", source)
        if not write and not var.readable:
            raise ConfigError(key, f"object {addr} is write-only in the EDS; the host must read it", source)
        _check_data_type(key, addr, var.data_type, source)


def _check_data_type(key: str, addr: ObjectAddress, data_type: int, source: str) -> None:
    """A buffer is a DOMAIN (or OCTET_STRING), a channel-selection object UNSIGNED32, any other object a number."""
    buffer = key.startswith("canopen.recorder.buffer")
    if buffer and data_type not in (_DOMAIN, _OCTET_STRING):
        raise ConfigError(
            key,
            f"object {addr} must be a DOMAIN (or OCTET_STRING) to hold samples, the EDS says "
            f"data type 0x{data_type:04X}",
            source,
        )
    if not buffer and data_type in (_DOMAIN, _OCTET_STRING, 0x09):
        raise ConfigError(key, f"object {addr} must be a number, the EDS says data type 0x{data_type:04X}", source)
    if key.startswith("canopen.recorder.channels") and data_type != _UNSIGNED32:
        raise ConfigError(
            key,
            f"object {addr} takes a mapping entry: it must be UNSIGNED32, the EDS says data type 0x{data_type:04X}",
            source,
        )


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


def plan_generator(
    cap: RecorderCapability,
    recipe: dict,
    target: str,
    samples: int,
    sample_period: int,
    loop_rate_hz: float,
    scales: dict,
) -> GeneratorSettings:
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
        raise ConfigError(
            "excitation.kind",
            f"{kind_name!r}: the driver describes no generator ([canopen.generator] "
            f"of {cap.source}); a recorder run needs one",
        )
    if kind_name not in g.kinds:
        raise ConfigError(
            "excitation.kind", f"{kind_name!r} cannot be played by {where}: it plays {', '.join(g.kinds)}"
        )
    kind = g.kinds[kind_name]
    if target not in g.targets:
        raise ConfigError(
            "excitation.mode", f"{recipe.get('mode')!r} excites {target}; {where} feeds {', '.join(g.targets)}"
        )
    if samples > cap.recorder.max_samples:
        raise ConfigError(
            "excitation.duration_s",
            f"{samples} samples at a sample period of {sample_period} loop cycles exceed the "
            f"recorder's {cap.recorder.max_samples} ([canopen.recorder] max_samples of {cap.source})",
        )
    if kind.name == "chirp" and recipe.get("chirp_method", "linear") != kind.method:
        raise ConfigError("excitation.chirp_method", f"{recipe.get('chirp_method')!r}: {where} sweeps {kind.method}ly")
    return kind


def _wanted_parameters(
    kind, recipe: dict, samples: int, sample_period: int, loop_rate_hz: float, where: str
) -> dict[str, tuple[str, float]]:
    """Generator parameter -> (the ``[excitation]`` key it comes from, its SI value)."""
    amplitude_key = recipe.get("amplitude_key", "excitation.amplitude_nm")  # the mode's key: amplitude_mps, ...
    wanted = {"amplitude": (amplitude_key, float(recipe.get("amplitude", 0.0)))}
    if kind.name == "prbs":
        wanted["register_length"] = ("excitation.register_length", int(recipe.get("register_length", 0)))
        wanted["clock_divider"] = ("excitation.clock_divider", int(recipe.get("clock_divider", 1)) * sample_period)
        if kind.taps and wanted["register_length"][1] not in kind.taps:
            raise ConfigError(
                "excitation.register_length",
                f"{wanted['register_length'][1]}: {where} describes its "
                f"sequence for register lengths {sorted(kind.taps)}",
            )
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
        p.maximum is not None and si > p.maximum + 1e-12 * abs(si)
    ):
        raise ConfigError(
            key,
            f"{si:g} is outside the range [{_show(p.minimum)}, {_show(p.maximum)}] of {where} "
            f"({kind.name} {name}, object {p.address})",
        )
    if name in ("register_length", "clock_divider"):
        return int(si)
    if name == "duration_s":  # never a cycle short of the last sample
        return math.ceil(si / scale - 1e-9)
    return round(si / scale)


def _show(x) -> str:
    return "-inf" if x is None else f"{x:g}"
