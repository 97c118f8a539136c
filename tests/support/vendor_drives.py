"""Driver folders of CiA 402 drives as vendors describe them: an EDS with standard objects only, a short driver.toml.

The EDS files are written here, object by object, each drive modelled on
traits real vendor files show: few entries per PDO, only two RPDOs, the cycle
period in 0x60C2 or 0x1006, 0x6076 absent or 0, current instead of torque,
0x6502 without a default, 0x6060 as UNSIGNED8. Nothing hilident-specific is in
them: no counters, no table, no loop-rate object.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from hilident.protocol.canopen_profile import encode_supported_modes

# (index, sub, name, type code, access, PDO-mappable, default) of the standard objects a drive may have
_INT8, _INT16, _INT32, _UINT8, _UINT16, _UINT32, _VSTRING = 0x2, 0x3, 0x4, 0x5, 0x6, 0x7, 0x9
_DOMAIN = 0xF


@dataclass
class VendorDrive:
    """The traits of one vendor drive (see the module docstring)."""

    name: str
    modes: tuple[str, ...] = ("csp", "csv", "cst")
    declare_modes: bool = True  # 0x6502 has a default value in the EDS
    rpdos: int = 4
    tpdos: int = 4
    entries: int = 8  # mapping capacity of every PDO
    period: str = "60C2"  # "60C2", "1006", "both" or "none"
    # "rated" (0x6076 = 1000 mN*m), "rated_zero" (0x6076 = 0), "absent" (no 0x6076), "current", or "effort" (no
    # standard torque or current object: a vendor "Control effort" 0x2022, per mille of the rated torque)
    torque: str = "rated"
    unmappable: tuple[int, ...] = ()  # standard objects the EDS declares not PDO-mappable (e.g. 0x607A)
    mode_type: int = _INT8  # 0x6060's data type
    mode_access: str = "rw"
    limits: tuple[str, ...] = ("max_torque", "max_velocity", "position_limits")
    torque_offset: bool = True
    sync_counter: bool = False
    # "", "biquad" (REAL32 a1 a2 b0 b1 b2), "copley" (one octet-string block), "pole_zero" (REAL32 Q pairs)
    filters: str = ""
    abort_connection: bool = True  # 0x6007
    store: bool = True  # 0x1010:1 store parameters
    heartbeat: bool = True  # 0x1017; without it, node guarding (0x100C, 0x100D)
    vendor: str = "ACME Motion"
    loop_rate_hz: float = 4000.0
    max_sample_rate_hz: float = 1000.0
    extra_toml: str = ""
    objects: list = field(default_factory=list)
    recorder: str = ""  # "", "prbs" (recorder + PRBS generator with an output object), "sweep" (per-channel buffers,
    # a sine-sweep and sine generator without an output object)
    recorder_max_samples: int = 8192
    # the drive can produce SYNC (its manual says so; [canopen.sync] producer = true, 0x1006 for the period), as
    # most servo drives can: the twin then keeps the bus clock; False: the host's loop does
    sync_producer: bool = True
    # vendor objects beyond the standard ones, e.g. a documented family's filter objects (tuples as _objects gives
    # them, optionally followed by LowLimit and HighLimit); the family's [filters] table, slots, identity and README
    # (tests/support/filter_families.py)
    vendor_objects: list = field(default_factory=list)
    filter_table: str = ""
    filter_slots: int = 2
    vendor_number: int = 0x0000ACE1
    product_number: int = 0x00001234
    readme: str = ""
    record_names: dict = field(default_factory=dict)  # index -> the record's ParameterName (vendor records)


def _objects(d: VendorDrive) -> list[tuple]:
    """(index, sub or None for a plain variable, name, type, access, mappable, default) in index order."""
    objs: list[tuple] = [
        (0x1000, None, "Device type", _UINT32, "ro", False, 0x00020192),
        (0x1001, None, "Error register", _UINT8, "ro", True, 0),
        (0x1005, None, "COB-ID SYNC", _UINT32, "rw", False, 0x80),
        (0x1008, None, "Manufacturer device name", _VSTRING, "const", False, d.name),
        (0x100A, None, "Manufacturer software version", _VSTRING, "const", False, "2.1"),
        (0x1016, 0, "Number of entries", _UINT8, "ro", False, 1),
        (0x1016, 1, "Consumer heartbeat time 1", _UINT32, "rw", False, 0),
        (0x1018, 0, "Number of entries", _UINT8, "ro", False, 4),
        (0x1018, 1, "Vendor-ID", _UINT32, "ro", False, d.vendor_number),
        (0x1018, 2, "Product code", _UINT32, "ro", False, d.product_number),
        (0x1018, 3, "Revision number", _UINT32, "ro", False, 1),
        (0x1018, 4, "Serial number", _UINT32, "ro", False, 7),
    ]
    if d.heartbeat:
        objs.append((0x1017, None, "Producer heartbeat time", _UINT16, "rw", False, 0))
    else:  # node guarding instead (CiA 301)
        objs += [
            (0x100C, None, "Guard time", _UINT16, "rw", False, 0),
            (0x100D, None, "Life time factor", _UINT8, "rw", False, 0),
        ]
    if d.store:
        objs += [
            (0x1010, 0, "Highest sub-index supported", _UINT8, "ro", False, 1),
            (0x1010, 1, "Save all parameters", _UINT32, "rw", False, 1),
        ]
    if d.period in ("1006", "both") or d.sync_producer:
        objs.append((0x1006, None, "Communication cycle period", _UINT32, "rw", False, 0))
    if d.sync_counter:
        objs.append((0x1019, None, "Synchronous counter overflow value", _UINT8, "rw", False, 0))
    for _kind, base, count, cob in (("Receive", 0x1400, d.rpdos, 0x200), ("Transmit", 0x1800, d.tpdos, 0x180)):
        for n in range(count):
            objs.append((base + n, 0, "Highest sub-index supported", _UINT8, "ro", False, 2))
            objs.append(
                (base + n, 1, "COB-ID", _UINT32, "rw", False, f"$NODEID+0x{cob + 0x100 * n:X}" if n < 4 else 0x80000000)
            )
            objs.append((base + n, 2, "Transmission type", _UINT8, "rw", False, 255))
        for n in range(count):
            objs.append((base + 0x200 + n, 0, "Number of mapped objects", _UINT8, "rw", False, 0))
            for sub in range(1, d.entries + 1):
                objs.append((base + 0x200 + n, sub, f"Mapped object {sub}", _UINT32, "rw", False, 0))
    if d.abort_connection:
        objs.append((0x6007, None, "Abort connection option code", _INT16, "rw", False, 1))
    objs += [
        (0x603F, None, "Error code", _UINT16, "ro", True, 0),
        (0x6040, None, "Controlword", _UINT16, "rww", True, 0),
        (0x6041, None, "Statusword", _UINT16, "ro", True, 0),
        (0x6060, None, "Modes of operation", d.mode_type, d.mode_access, True, 0),
        (0x6061, None, "Modes of operation display", _INT8, "ro", True, 0),
        (0x6064, None, "Position actual value", _INT32, "ro", True, 0),
        (0x606C, None, "Velocity actual value", _INT32, "ro", True, 0),
    ]
    if d.torque == "current":
        objs += [
            (0x6075, None, "Motor rated current", _UINT32, "rw", False, 4000),
            (0x6078, None, "Current actual value", _INT16, "ro", True, 0),
        ]
    elif d.torque == "effort":
        objs.append((0x2022, None, "Control effort", _INT16, "ro", True, 0))
    else:
        objs += [
            (0x6071, None, "Target torque", _INT16, "rww", True, 0),
            (0x6074, None, "Torque demand", _INT16, "ro", True, 0),
            (0x6077, None, "Torque actual value", _INT16, "ro", True, 0),
        ]
        if d.torque != "absent":
            objs.append((0x6076, None, "Motor rated torque", _UINT32, "rw", False, 1000 if d.torque == "rated" else 0))
        if "max_torque" in d.limits:
            objs.append((0x6072, None, "Max torque", _UINT16, "rww", True, 1000))
    objs.append((0x607A, None, "Target position", _INT32, "rww", True, 0))
    if "position_limits" in d.limits:
        objs += [
            (0x607D, 0, "Number of entries", _UINT8, "ro", False, 2),
            (0x607D, 1, "Min position limit", _INT32, "rw", False, -(2**31)),
            (0x607D, 2, "Max position limit", _INT32, "rw", False, 2**31 - 1),
        ]
    if "max_velocity" in d.limits:
        objs.append((0x6080, None, "Max motor speed", _UINT32, "rw", False, 2**31))
    if d.torque_offset and d.torque != "current":
        objs.append((0x60B2, None, "Torque offset", _INT16, "rww", True, 0))
    if "ip" in d.modes:
        objs += [
            (0x60C1, 0, "Highest sub-index supported", _UINT8, "ro", False, 1),
            (0x60C1, 1, "Interpolation data record 1", _INT32, "rww", True, 0),
        ]
    if d.period in ("60C2", "both"):
        objs += [
            (0x60C2, 0, "Highest sub-index supported", _UINT8, "ro", False, 2),
            (0x60C2, 1, "Interpolation time period value", _UINT8, "rw", False, 1),
            (0x60C2, 2, "Interpolation time index", _INT8, "rw", False, -3),
        ]
    objs += _filter_objects(d.filters) + d.vendor_objects
    objs += _recorder_objects(d)
    objs.append((0x60FF, None, "Target velocity", _INT32, "rww", True, 0))
    objs.append(
        (
            0x6502,
            None,
            "Supported drive modes",
            _UINT32,
            "ro",
            False,
            encode_supported_modes(d.modes) if d.declare_modes else None,
        )
    )
    return [o[:5] + (False,) + o[6:] if o[0] in d.unmappable else o for o in objs]


_REAL32, _OCTETS = 0x8, 0xA
#: Filter capabilities of the project's test drives: EDS objects of two slots, and the [filters] table.
FILTERS = {
    "biquad": (
        [
            (
                0x2300 + n,
                [(1, "Enable", _UINT8, 0)]
                + [(2 + i, f, _REAL32, 0.0) for i, f in enumerate(("a1", "a2", "b0", "b1", "b2"))],
            )
            for n in range(2)
        ],
        '[filters]\nencoding = "real32"\norder = ["a1", "a2", "b0", "b1", "b2"]\nfeedback_sign = "minus"\n'
        'objects = ["0x2300", "0x2301"]\nenable_subindex = 1\n'
        "fields = { a1 = 2, a2 = 3, b0 = 4, b1 = 5, b2 = 6 }\n",
    ),
    "copley": (
        [(0x2106, None), (0x2108, None)],
        '[filters]\nencoding = "word_block"\npreset = "copley"\nobjects = ["0x2106", "0x2108"]\n',
    ),
    "pole_zero": (
        [
            (
                0x2400 + n,
                [(1, "Enable", _UINT8, 0)]
                + [
                    (2 + i, f, _REAL32, 100.0 if "hz" in f else 0.5)
                    for i, f in enumerate(("pole_hz", "pole_q", "zero_hz", "zero_q"))
                ],
            )
            for n in range(2)
        ],
        '[filters]\nencoding = "pole_zero_q"\nranges = { pole_hz = [5, 5000], zero_hz = [5, 5000], '
        'pole_q = [0.2, 20], zero_q = [0.1, 5] }\nobjects = ["0x2400", "0x2401"]\nenable_subindex = 1\n'
        "fields = { pole_hz = 2, pole_q = 3, zero_hz = 4, zero_q = 5 }\n",
    ),
}


def _filter_objects(kind: str) -> list[tuple]:
    objs = []
    for index, members in FILTERS[kind][0] if kind else []:
        if members is None:  # a Copley-style block: 9 words, word 0 = 0xFFFF: disabled
            objs.append(
                (
                    index,
                    None,
                    f"Filter coefficients 0x{index:04X}",
                    _OCTETS,
                    "rw",
                    False,
                    bytes.fromhex("FFFF") + bytes(16),
                )
            )
            continue
        objs.append((index, 0, "Highest sub-index supported", _UINT8, "ro", False, len(members)))
        objs += [(index, sub, name, dtype, "rw", False, default) for sub, name, dtype, default in members]
    return objs


def _recorder_objects(d: VendorDrive) -> list[tuple]:
    """A data recorder (0x2500-0x2503) and a signal generator (0x2510-0x2512), in a vendor's style."""
    if not d.recorder:
        return []
    objs = [
        (0x2500, 0, "Highest sub-index supported", _UINT8, "ro", False, 7),
        (0x2500, 1, "Recorder control", _UINT8, "rw", False, 0),
        (0x2500, 2, "Recorder status", _UINT8, "ro", False, 0),
        (0x2500, 3, "Trigger source", _UINT8, "rw", False, 0),
        (0x2500, 4, "Sampling period", _UINT16, "rw", False, 1),
        (0x2500, 5, "Number of samples", _UINT32, "rw", False, 1000),
        (0x2500, 6, "Recorded samples", _UINT32, "ro", False, 0),
        (0x2500, 7, "Maximum samples", _UINT32, "const", False, d.recorder_max_samples),
        (0x2501, 0, "Number of channels", _UINT8, "ro", False, 6),
    ]
    objs += [(0x2501, sub, f"Channel {sub} object", _UINT32, "rw", False, 0) for sub in range(1, 7)]
    if d.recorder == "prbs":
        objs.append((0x2502, None, "Recorder data buffer", _DOMAIN, "ro", False, None))
    else:
        objs.append((0x2503, 0, "Highest sub-index supported", _UINT8, "ro", False, 6))
        objs += [(0x2503, sub, f"Channel {sub} data", _DOMAIN, "ro", False, None) for sub in range(1, 7)]
    objs += [
        (0x2510, 0, "Highest sub-index supported", _UINT8, "ro", False, 5 if d.recorder == "prbs" else 4),
        (0x2510, 1, "Generator control", _UINT8, "rw", False, 0),
        (0x2510, 2, "Generator status", _UINT8, "ro", False, 0),
        (0x2510, 3, "Signal type", _UINT8, "rw", False, 0),
        (0x2510, 4, "Signal target", _UINT8, "rw", False, 0),
    ]
    if d.recorder == "prbs":
        objs.append((0x2510, 5, "Generator output", _INT16, "ro", True, 0))
        objs += [
            (0x2511, 0, "Highest sub-index supported", _UINT8, "ro", False, 4),
            (0x2511, 1, "PRBS amplitude", _UINT16, "rw", False, 0),
            (0x2511, 2, "PRBS register length", _UINT8, "rw", False, 10),
            (0x2511, 3, "PRBS clock divider", _UINT16, "rw", False, 1),
            (0x2511, 4, "PRBS duration", _UINT32, "rw", False, 0),
        ]
    else:
        objs += [
            (0x2512, 0, "Highest sub-index supported", _UINT8, "ro", False, 4),
            (0x2512, 1, "Sweep amplitude", _UINT16, "rw", False, 0),
            (0x2512, 2, "Sweep start frequency", _UINT32, "rw", False, 100),
            (0x2512, 3, "Sweep end frequency", _UINT32, "rw", False, 10000),
            (0x2512, 4, "Sweep duration", _UINT32, "rw", False, 1000),
            (0x2513, 0, "Highest sub-index supported", _UINT8, "ro", False, 2),
            (0x2513, 1, "Sine amplitude", _UINT16, "rw", False, 0),
            (0x2513, 2, "Sine frequency", _UINT32, "rw", False, 1000),
        ]
    return objs


_RECORDER_TOML = """[canopen.recorder]
control = "0x2500:1"
state = "0x2500:2"
trigger = "0x2500:3"
sample_period = "0x2500:4"
samples = "0x2500:5"
recorded = "0x2500:6"
sample_periods = [1, 2, 4, 8]
max_samples = {max_samples}
channels = ["0x2501:1", "0x2501:2", "0x2501:3", "0x2501:4", "0x2501:5", "0x2501:6"]
"""
#: Recorder and generator capabilities of the project's test drives: the [canopen.recorder] and
#: [canopen.generator] tables (the EDS objects are written by _recorder_objects).
RECORDERS = {
    "prbs": (
        "recorder + PRBS generator, one interleaved buffer, a generator output object",
        _RECORDER_TOML
        + """buffer = "0x2502"

[canopen.generator]
control = "0x2510:1"
state = "0x2510:2"
kind = "0x2510:3"
target = "0x2510:4"
output = "0x2510:5"
output_scale = "torque"
targets = { target_torque = 1, torque_offset = 2 }

[canopen.generator.kinds.prbs]
code = 1
taps = "max_len_seq"
amplitude = { object = "0x2511:1", scale = "torque", min = 0.0, max = 20.0 }
register_length = { object = "0x2511:2", min = 7, max = 14 }
clock_divider = { object = "0x2511:3", min = 1, max = 1000 }
duration_s = { object = "0x2511:4", scale = 0.001 }
""",
    ),
    "sweep": (
        "recorder with one buffer per channel + sine-sweep and sine generator, no output object",
        _RECORDER_TOML
        + """buffers = ["0x2503:1", "0x2503:2", "0x2503:3", "0x2503:4", "0x2503:5", "0x2503:6"]
block_transfer = false

[canopen.generator]
control = "0x2510:1"
state = "0x2510:2"
kind = "0x2510:3"
target = "0x2510:4"
targets = { target_torque = 1 }

[canopen.generator.kinds.chirp]
code = 2
method = "logarithmic"
amplitude = { object = "0x2512:1", scale = "torque", min = 0.0, max = 10.0 }
f_start_hz = { object = "0x2512:2", scale = 0.01, min = 0.1, max = 200.0 }
f_end_hz = { object = "0x2512:3", scale = 0.01, min = 0.1, max = 200.0 }
duration_s = { object = "0x2512:4", scale = 0.001, max = 60.0 }

[canopen.generator.kinds.sine]
code = 3
amplitude = { object = "0x2513:1", scale = "torque", min = 0.0, max = 10.0 }
frequency_hz = { object = "0x2513:2", scale = 0.01, min = 0.1, max = 200.0 }
""",
    ),
}


def eds_text(d: VendorDrive) -> str:
    """The EDS of drive ``d``, as a vendor tool writes one (CiA 306)."""
    objs = _objects(d)
    indices = sorted({o[0] for o in objs})
    lines = [
        "[FileInfo]",
        f"FileName={d.name}.eds",
        "FileVersion=1",
        "EDSVersion=4.0",
        "",
        "[DeviceInfo]",
        f"VendorName={d.vendor}",
        f"VendorNumber=0x{d.vendor_number:08X}",
        f"ProductName={d.name}",
        f"ProductNumber=0x{d.product_number:08X}",
        "BaudRate_1000=1",
        "SimpleBootUpSlave=1",
        "Granularity=8",
        f"NrOfRXPDO={d.rpdos}",
        f"NrOfTXPDO={d.tpdos}",
        "",
    ]
    mandatory = [i for i in indices if i in (0x1000, 0x1001, 0x1018)]
    optional = [i for i in indices if i < 0x2000 and i not in mandatory]
    optional += [i for i in indices if i >= 0x6000]
    manufacturer = [i for i in indices if 0x2000 <= i < 0x6000]
    for title, group in (("MandatoryObjects", mandatory), ("OptionalObjects", optional)):
        lines.append(f"[{title}]")
        lines.append(f"SupportedObjects={len(group)}")
        lines += [f"{n}=0x{i:04X}" for n, i in enumerate(group, start=1)]
        lines.append("")
    lines += ["[ManufacturerObjects]", f"SupportedObjects={len(manufacturer)}"]
    lines += [f"{n}=0x{i:04X}" for n, i in enumerate(manufacturer, start=1)] + [""]
    for index in indices:
        members = [o for o in objs if o[0] == index]
        if members[0][1] is None:
            lines += [f"[{index:04X}]"] + _variable_lines(members[0]) + [""]
            continue
        lines += [
            f"[{index:04X}]",
            f"ParameterName={d.record_names.get(index) or _record_name(index)}",
            "ObjectType=0x9",
            f"SubNumber={len(members)}",
            "",
        ]
        for member in members:
            lines += [f"[{index:04X}sub{member[1]:X}]"] + _variable_lines(member) + [""]
    return "\r\n".join(lines)


def _record_name(index: int) -> str:
    if 0x1400 <= index < 0x1600:
        return f"RPDO communication parameter {index - 0x1400 + 1}"
    if 0x1600 <= index < 0x1800:
        return f"RPDO mapping parameter {index - 0x1600 + 1}"
    if 0x1800 <= index < 0x1A00:
        return f"TPDO communication parameter {index - 0x1800 + 1}"
    if 0x1A00 <= index < 0x1C00:
        return f"TPDO mapping parameter {index - 0x1A00 + 1}"
    return {
        0x1016: "Consumer heartbeat time",
        0x1018: "Identity object",
        0x607D: "Software position limit",
        0x60C1: "Interpolation data record",
        0x60C2: "Interpolation time period",
    }.get(index, f"Object {index:04X}")


def _variable_lines(obj: tuple) -> list[str]:
    _, _, name, dtype, access, mappable, default = obj[:7]
    lines = [
        f"ParameterName={name}",
        "ObjectType=0x7",
        f"DataType=0x{dtype:04X}",
        f"AccessType={access}",
        f"PDOMapping={int(mappable)}",
    ]
    if default is not None:
        if isinstance(default, bytes):
            value = default.hex().upper()
        elif isinstance(default, (str, float)):
            value = str(default)
        else:
            value = f"0x{default:X}" if default >= 0 else str(default)
        lines.append(f"DefaultValue={value}")
    for key, limit in zip(("LowLimit", "HighLimit"), obj[7:], strict=False):
        lines.append(f"{key}={limit}")
    return lines


def driver_toml(d: VendorDrive) -> str:
    """The short driver.toml of ``d``: mechanics, torque reference and mode preference only."""
    scaling = ["position_unit_m = 1e-7", "velocity_unit_mps = 1e-6"]
    if d.torque in ("rated_zero", "absent", "effort"):
        scaling.append("rated_torque_nm = 1.0")
    if d.torque == "current":
        scaling.append("torque_constant_nm_per_a = 0.25")
    if d.torque == "effort":
        scaling.append('\n[canopen.objects]\ntorque_demand = "0x2022"  # the vendor\'s control effort')
    emulator = "" if d.declare_modes else f"\n[emulator]\nsupported_modes = {list(d.modes)!r}\n".replace("'", '"')
    if d.filters or d.filter_table:
        emulator += "\n" + (d.filter_table or FILTERS[d.filters][1])
    if d.recorder:
        emulator += "\n" + RECORDERS[d.recorder][1].replace("{max_samples}", str(d.recorder_max_samples))
    return f"""[driver]
name = "{d.name}"
description = "a CiA 402 drive described by its vendor EDS"
transport = "canopen"
default_baudrate = 1000000

[board]
loop_rate_hz = {d.loop_rate_hz}
max_sample_rate_hz = {d.max_sample_rate_hz}
filter_slots = {d.filter_slots if d.filters or d.filter_table else 0}

[canopen]
eds = "{d.name}.eds"
heartbeat_ms = 50
heartbeat_timeout_ms = 500

{SYNC_PRODUCER if d.sync_producer else ""}
[canopen.scaling]
{chr(10).join(scaling)}
{emulator}{d.extra_toml}"""


#: ``[canopen.sync]`` of a drive whose manual says it produces SYNC and monitors it.
SYNC_PRODUCER = """[canopen.sync]
producer = true
window_us = 400
"""


def write_vendor_drive(folder: Path, d: VendorDrive) -> Path:
    """Write the driver folder of ``d`` under ``folder``; returns it."""
    path = Path(folder) / d.name
    path.mkdir(parents=True, exist_ok=True)
    (path / f"{d.name}.eds").write_bytes(eds_text(d).encode("latin-1"))
    (path / "driver.toml").write_text(driver_toml(d))
    if d.readme:
        (path / "README.md").write_text(d.readme)
    return path


#: The project's drives with a filter capability, one per kind of encoding (bench/drives.py --project-drives).
FILTER_DRIVES = [VendorDrive(f"acme-{kind}", filters=kind) for kind in FILTERS]
