"""Emergency (EMCY) error codes of CiA 301 and CiA 402 (IEC 61800-7-201) with their names.

An EMCY frame's first two bytes are the error code (also in 0x603F and in the
error history 0x1003). CiA 301 divides the 16-bit code into classes by its high
nibble or byte (0x2xxx current, 0x81xx communication, 0xFFxx device specific,
...) and names a few exact codes; CiA 402 (drive profile, the same table as
IEC 61800-7-201) refines the classes down to exact codes for power drives
(0x2311 continuous over-current No. 1, 0x8611 following error, ...).
:func:`emcy_name` gives the most specific name the tables hold: the exact code,
else the group it belongs to (the code with its low nibble, then its low byte,
cleared), else its class; codes 0xFF00-0xFFFF are the manufacturer's own.

Sources (names as there, lower-cased, not copied code):

- CiA 301 classes and communication codes: CANopenNode,
  ``301/CO_Emergency.h`` (``CO_EM_errorCode_t``),
  https://github.com/CANopenNode/CANopenNode; the class masks agree with
  python-canopen's ``canopen.emcy.EmcyError.DESCRIPTIONS``.
- CiA 402 drive codes: ``402/CO_402_ErrorCodes.h`` in the CANopenNode fork
  https://github.com/CISSOIDjmr/CANopenNode ("standard error codes according to
  CiA DS-402"), cross-checked against Synapticon's ``cia402_error_codes.h``
  ("error codes defined by IEC 61800-7-201").

Pure data and functions on integers: no bus, no clock.

Examples
--------
>>> emcy_name(0x8611)
'following error'
>>> emcy_name(0x2315)
'continuous over-current (group 0x231x)'
>>> emcy_name(0xFF42)
'manufacturer-specific 0xFF42 (device specific)'
"""

from __future__ import annotations

__all__ = [
    "CLASSES",
    "CODES",
    "ERROR_REGISTER_BITS",
    "MANUFACTURER_SPECIFIC",
    "emcy_class",
    "emcy_name",
    "error_register_names",
]

#: Start of the manufacturer-specific (CiA 301: "device specific") codes, 0xFF00-0xFFFF.
MANUFACTURER_SPECIFIC = 0xFF00

#: CiA 301 error code classes as (value, mask, name): ``code & mask == value``. 0x5xxx and 0x7xxx are whole
#: classes as CiA 402 uses them (CiA 301 alone names 0x50xx and 0x70xx); 0xA000-0xEFFF and 0xF100-0xFEFF are
#: reserved.
CLASSES: tuple[tuple[int, int, str], ...] = (
    (0x0000, 0xFF00, "error reset or no error"),
    (0x1000, 0xFF00, "generic error"),
    (0x2000, 0xF000, "current"),
    (0x3000, 0xF000, "voltage"),
    (0x4000, 0xF000, "temperature"),
    (0x5000, 0xF000, "device hardware"),
    (0x6000, 0xF000, "device software"),
    (0x7000, 0xF000, "additional modules"),
    (0x8000, 0xF000, "monitoring"),
    (0x9000, 0xFF00, "external error"),
    (0xF000, 0xFF00, "additional functions"),
    (0xFF00, 0xFF00, "device specific"),
)

#: Named codes and groups of CiA 301 and CiA 402 (0xFF00-0xFFFF are the manufacturer's). A key with a zero low
#: byte or nibble also names the group below it (0x2300 "current, device output side" for 0x23xx; 0x2310
#: "continuous over-current" for 0x231x).
CODES: dict[int, str] = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    # current (CiA 301 groups, CiA 402 codes)
    0x2000: "current",
    0x2100: "current, device input side",
    0x2110: "short circuit or earth leakage (input)",
    0x2120: "earth leakage (input)",
    0x2121: "earth leakage phase L1",
    0x2122: "earth leakage phase L2",
    0x2123: "earth leakage phase L3",
    0x2130: "short circuit (input)",
    0x2131: "short circuit phases L1-L2",
    0x2132: "short circuit phases L2-L3",
    0x2133: "short circuit phases L3-L1",
    0x2200: "current inside the device",
    0x2211: "internal current No. 1",
    0x2212: "internal current No. 2",
    0x2213: "over-current in ramp function",
    0x2214: "over-current in the sequence",
    0x2220: "continuous over-current (device internal)",
    0x2221: "continuous over-current No. 1 (device internal)",
    0x2222: "continuous over-current No. 2 (device internal)",
    0x2230: "short circuit or earth leakage (device internal)",
    0x2240: "earth leakage (device internal)",
    0x2250: "short circuit (device internal)",
    0x2300: "current, device output side",
    0x2310: "continuous over-current",
    0x2311: "continuous over-current No. 1",
    0x2312: "continuous over-current No. 2",
    0x2320: "short circuit or earth leakage (motor side)",
    0x2330: "earth leakage (motor side)",
    0x2331: "earth leakage phase U",
    0x2332: "earth leakage phase V",
    0x2333: "earth leakage phase W",
    0x2340: "short circuit (motor side)",
    0x2341: "short circuit phases U-V",
    0x2342: "short circuit phases V-W",
    0x2343: "short circuit phases W-U",
    0x2350: "load level fault (I2t, thermal state)",
    0x2351: "load level warning (I2t, thermal state)",
    # voltage
    0x3000: "voltage",
    0x3100: "mains voltage",
    0x3110: "mains over-voltage",
    0x3111: "mains over-voltage phase L1",
    0x3112: "mains over-voltage phase L2",
    0x3113: "mains over-voltage phase L3",
    0x3120: "mains under-voltage",
    0x3121: "mains under-voltage phase L1",
    0x3122: "mains under-voltage phase L2",
    0x3123: "mains under-voltage phase L3",
    0x3130: "phase failure",
    0x3131: "phase failure L1",
    0x3132: "phase failure L2",
    0x3133: "phase failure L3",
    0x3134: "phase sequence",
    0x3140: "mains frequency",
    0x3141: "mains frequency too great",
    0x3142: "mains frequency too small",
    0x3200: "voltage inside the device",
    0x3210: "DC link over-voltage",
    0x3211: "over-voltage No. 1",
    0x3212: "over-voltage No. 2",
    0x3220: "DC link under-voltage",
    0x3221: "under-voltage No. 1",
    0x3222: "under-voltage No. 2",
    0x3230: "load error",
    0x3300: "output voltage",
    0x3310: "output over-voltage",
    0x3311: "output over-voltage phase U",
    0x3312: "output over-voltage phase V",
    0x3313: "output over-voltage phase W",
    0x3320: "armature circuit",
    0x3321: "armature circuit interrupted",
    0x3330: "field circuit",
    0x3331: "field circuit interrupted",
    # temperature
    0x4000: "temperature",
    0x4100: "ambient temperature",
    0x4110: "excess ambient temperature",
    0x4120: "too low ambient temperature",
    0x4130: "temperature supply air",
    0x4140: "temperature air outlet",
    0x4200: "device temperature",
    0x4210: "excess temperature, device",
    0x4220: "too low temperature, device",
    0x4300: "drive temperature",
    0x4310: "excess temperature, drive",
    0x4320: "too low temperature, drive",
    0x4400: "supply temperature",
    0x4410: "excess temperature, supply",
    0x4420: "too low temperature, supply",
    # device hardware
    0x5000: "device hardware",
    0x5100: "supply",
    0x5110: "supply low voltage",
    0x5111: "U1 supply +/-15 V",
    0x5112: "U2 supply +24 V",
    0x5113: "U3 supply +5 V",
    0x5114: "U4 supply (manufacturer-specific)",
    0x5115: "U5 supply (manufacturer-specific)",
    0x5116: "U6 supply (manufacturer-specific)",
    0x5117: "U7 supply (manufacturer-specific)",
    0x5118: "U8 supply (manufacturer-specific)",
    0x5119: "U9 supply (manufacturer-specific)",
    0x5120: "supply intermediate circuit",
    0x5200: "control",
    0x5210: "measurement circuit",
    0x5220: "computing circuit",
    0x5300: "operating unit",
    0x5400: "power section",
    0x5410: "output stages",
    0x5420: "chopper",
    0x5430: "input stages",
    0x5440: "contacts",
    0x5441: "contact 1 (manufacturer-specific)",
    0x5442: "contact 2 (manufacturer-specific)",
    0x5443: "contact 3 (manufacturer-specific)",
    0x5444: "contact 4 (manufacturer-specific)",
    0x5445: "contact 5 (manufacturer-specific)",
    0x5450: "fuses",
    0x5451: "fuse S1 (L1)",
    0x5452: "fuse S2 (L2)",
    0x5453: "fuse S3 (L3)",
    0x5454: "fuse S4 (manufacturer-specific)",
    0x5455: "fuse S5 (manufacturer-specific)",
    0x5456: "fuse S6 (manufacturer-specific)",
    0x5457: "fuse S7 (manufacturer-specific)",
    0x5458: "fuse S8 (manufacturer-specific)",
    0x5459: "fuse S9 (manufacturer-specific)",
    0x5500: "hardware memory",
    0x5510: "RAM",
    0x5520: "ROM/EPROM",
    0x5530: "EEPROM",
    # device software
    0x6000: "device software",
    0x6010: "software reset (watchdog)",
    0x6100: "internal software",
    0x6200: "user software",
    0x6300: "data set",
    0x6310: "loss of parameters",
    0x6320: "parameter error",
    # additional modules
    0x7000: "additional modules",
    0x7100: "power",
    0x7110: "brake chopper",
    0x7111: "failure brake chopper",
    0x7112: "over-current brake chopper",
    0x7113: "protective circuit brake chopper",
    0x7120: "motor",
    0x7121: "motor blocked",
    0x7122: "motor error or commutation malfunction",
    0x7123: "motor tilted",
    0x7200: "measurement circuit",
    0x7300: "sensor",
    0x7301: "tacho fault",
    0x7302: "tacho wrong polarity",
    0x7303: "resolver 1 fault",
    0x7304: "resolver 2 fault",
    0x7305: "incremental sensor 1 fault",
    0x7306: "incremental sensor 2 fault",
    0x7307: "incremental sensor 3 fault",
    0x7310: "speed",
    0x7320: "position",
    0x7400: "computation circuit",
    0x7500: "communication",
    0x7510: "serial interface No. 1",
    0x7520: "serial interface No. 2",
    0x7600: "data storage (external)",
    # monitoring: communication (CiA 301)
    0x8000: "monitoring",
    0x8100: "communication",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard or heartbeat error",
    0x8140: "recovered from bus off",
    0x8150: "CAN-ID collision",
    0x8200: "protocol error",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8230: "DAM MPDO not processed, destination object not available",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
    # monitoring: drive control (CiA 402)
    0x8300: "torque control",
    0x8311: "excess torque",
    0x8312: "difficult start up",
    0x8313: "standstill torque",
    0x8321: "insufficient torque",
    0x8331: "torque fault",
    0x8400: "velocity/speed controller",
    0x8500: "position controller",
    0x8600: "positioning controller",
    0x8611: "following error",
    0x8612: "reference limit",
    0x8613: "homing error",
    0x8700: "sync controller",
    0x8800: "winding controller",
    0x8900: "process data monitoring",
    0x8A00: "control",
    0x9000: "external error",
    0xF000: "additional functions",
}

# A CiA 402 code group 0x63x1-0x63xF: data record No. n.
CODES.update({0x6300 + n: f"data record No. {n}" for n in range(1, 16)})

#: Bits of the error register (0x1001, byte 2 of an EMCY frame), CiA 301.
ERROR_REGISTER_BITS: dict[int, str] = {
    0: "generic error",
    1: "current",
    2: "voltage",
    3: "temperature",
    4: "communication error",
    5: "device profile specific",
    6: "reserved",
    7: "manufacturer-specific",
}

#: Groups below a class, most specific first: (mask, shift, wildcard) for 0x231x and 0x23xx.
_GROUPS = ((0xFFF0, 4, "x"), (0xFF00, 8, "xx"))


def _checked(code: int) -> int:
    if isinstance(code, bool) or not isinstance(code, int) or not 0 <= code <= 0xFFFF:
        raise ValueError(f"an EMCY error code is an integer in 0x0000-0xFFFF, got {code!r}")
    return code


def emcy_class(code: int) -> str:
    """The CiA 301 class of an error code (``"current"`` for 0x2311), or ``"reserved"``.

    Raises
    ------
    ValueError
        ``code`` is not an integer in 0x0000-0xFFFF.
    """
    code = _checked(code)
    for value, mask, name in CLASSES:
        if code & mask == value:
            return name
    return "reserved"


def emcy_name(code: int) -> str:
    """The most specific name of an EMCY error code.

    Parameters
    ----------
    code : int
        The 16-bit error code (EMCY bytes 0-1, 0x603F, 0x1003 bits 0-15).

    Returns
    -------
    str
        The code's own name; else its group's name with the group written
        out, e.g. ``"continuous over-current (group 0x231x)"``; else
        ``"<class> (class 0x2xxx)"``; ``"manufacturer-specific 0xFFnn (device
        specific)"`` for 0xFF00-0xFFFF and ``"reserved code 0xnnnn"`` for codes
        CiA 301 does not assign.

    Raises
    ------
    ValueError
        ``code`` is not an integer in 0x0000-0xFFFF.
    """
    code = _checked(code)
    if code >= MANUFACTURER_SPECIFIC:
        return f"manufacturer-specific 0x{code:04X} (device specific)"
    if code in CODES:
        return CODES[code]
    for mask, shift, wildcard in _GROUPS:
        group = code & mask
        # a key XY00 is the group 0xXYxx, not 0xXY0x: only XYZ0 with Z != 0 names a nibble group
        if mask == 0xFFF0 and not group & 0x00F0:
            continue
        if group != code and group in CODES:
            return f"{CODES[group]} (group 0x{group >> shift:0{4 - len(wildcard)}X}{wildcard})"
    for value, mask, name in CLASSES:
        if code & mask == value:
            return f"{name} (class 0x{value >> 12:X}xxx)"
    return f"reserved code 0x{code:04X}"


def error_register_names(register: int) -> list[str]:
    """Names of the bits set in an error register value (0x1001), lowest bit first.

    Raises
    ------
    ValueError
        ``register`` is not an integer in 0-255.
    """
    if isinstance(register, bool) or not isinstance(register, int) or not 0 <= register <= 0xFF:
        raise ValueError(f"an error register is an integer in 0-255, got {register!r}")
    return [name for bit, name in ERROR_REGISTER_BITS.items() if register >> bit & 1]
