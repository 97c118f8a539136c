"""Generate the EDS files of the hilident CiA 402 servo drivers from one common source.

The drives ``drivers/canopen-servo`` (REAL32 filter slots) and
``drivers/canopen-servo-fixed`` (INTEGER32 Q2.29 filter slots) share one object
dictionary, ``scripts/eds/cia402-servo.eds.in``. What differs is read from each
driver's ``driver.toml``:

- ``[driver] name`` gives the order code; ``[canopen] eds``, ``vendor_id`` and
  ``product_code`` the file name and the identity object 0x1018;
- ``[filters]`` (encoding, objects, enable_subindex, fields, fractional_bits,
  total_bits) gives the filter-slot records, their data type and defaults, the
  product name and the description;
- ``[loop]`` whether 0x2400:2 holds the velocity loop's integral time (``ti_s``, REAL32, s) or its integral
  gain (``ki_nm_per_m``, UNSIGNED32 in the units of its ``scale``), as vendors' drives do.

Usage::

    python scripts/generate_eds.py           # rewrite the shipped EDS files
    python scripts/generate_eds.py --check   # exit 1 if a shipped file differs

``tests/test_driver_eds_generated.py`` checks that regenerating gives exactly
the shipped files: edit the template or ``driver.toml``, never the EDS.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The common object dictionary; ``@NAME@`` marks what each driver fills in.
TEMPLATE = ROOT / "scripts" / "eds" / "cia402-servo.eds.in"
#: Driver folders whose EDS is generated from :data:`TEMPLATE`.
GENERATED_DRIVERS = ("canopen-servo", "canopen-servo-fixed")
PRODUCT_NAME = "hilident CiA 402 servo"
FEATURES = "CiA 402 cyclic synchronous modes, excitation table and capture buffer"
#: CiA 301 data types of a coefficient: REAL32, and INTEGER8/16/32 by width in bits.
REAL32 = 0x0008
INTEGER_TYPES = {8: 0x0002, 16: 0x0003, 32: 0x0004}
UNSIGNED8 = 0x0005
UNSIGNED32 = 0x0007


def generate(folder: Path) -> str:
    """The EDS text of the driver in ``folder``, from its ``driver.toml`` and :data:`TEMPLATE`."""
    description = tomllib.loads((folder / "driver.toml").read_text(encoding="utf-8"))
    canopen, filters = description["canopen"], description["filters"]
    coefficient = _coefficient_type(filters)
    values = {
        "FILE_NAME": canopen["eds"],
        "ORDER_CODE": description["driver"]["name"],
        "VENDOR_ID": f"0x{canopen['vendor_id']:08X}",
        "PRODUCT_CODE": f"0x{canopen['product_code']:08X}",
        "PRODUCT_NAME": PRODUCT_NAME + coefficient["product_suffix"],
        "DESCRIPTION": f"{PRODUCT_NAME}{coefficient['product_suffix']}: {FEATURES}, {coefficient['label']} "
        "notch filter slots",
        **_integral_object(description.get("loop", {})),
        "FILTER_SLOTS": "".join(
            _slot_record(slot, int(index, 16), filters, coefficient) for slot, index in enumerate(filters["objects"])
        ).rstrip("\n"),
    }
    text = TEMPLATE.read_text(encoding="utf-8")
    for name, value in values.items():
        text = text.replace(f"@{name}@", value)
    _check_listed(text, filters["objects"], folder)
    return text


def _integral_object(loop: dict) -> dict:
    """Name, data type and default of 0x2400:2: the integral time, or the integral gain in its ``scale``'s unit.

    The default is the emulated drive's (kv 100 N*m/(m/s), ti 0.05 s: ki 2000 N*m/m).
    """
    if "ki_nm_per_m" not in loop:
        return {
            "LOOP_INTEGRAL_NAME": "Velocity loop integral time (s)",
            "LOOP_INTEGRAL_TYPE": "0x0008",
            "LOOP_INTEGRAL_DEFAULT": "0.05",
        }
    scale = loop["ki_nm_per_m"].get("scale", 1.0)
    return {
        "LOOP_INTEGRAL_NAME": f"Velocity loop integral gain ({scale:g} N*m per m)",
        "LOOP_INTEGRAL_TYPE": f"0x{UNSIGNED32:04X}",
        "LOOP_INTEGRAL_DEFAULT": str(round(2000.0 / scale)),
    }


def _coefficient_type(filters: dict) -> dict:
    """Data type, defaults of 1 and 0, and wording of a filter coefficient under ``[filters] encoding``."""
    if filters["encoding"] == "real32":
        return {"type": REAL32, "one": "1.0", "zero": "0.0", "label": "REAL32", "product_suffix": ""}
    if filters["encoding"] == "fixed":
        bits, fraction = filters["total_bits"], filters["fractional_bits"]
        return {
            "type": INTEGER_TYPES[bits],
            "one": f"0x{1 << fraction:08X}",
            "zero": "0",
            "label": f"INTEGER{bits} Q{bits - fraction - 1}.{fraction}",
            "product_suffix": " (fixed-point filters)",
        }
    raise SystemExit(f"[filters] encoding = {filters['encoding']!r}: no EDS coefficient type for it")


def _slot_record(slot: int, index: int, filters: dict, coefficient: dict) -> str:
    """The EDS sections of one filter-slot record: sub 0, the enable flag and the coefficients."""
    subs = {filters["enable_subindex"]: ("Enable", UNSIGNED8, "0")}
    for name, sub in filters["fields"].items():
        subs[sub] = (name, coefficient["type"], coefficient["one"] if name == "b0" else coefficient["zero"])
    highest = max(subs)
    sections = [
        _section(
            f"{index:04X}", ParameterName=f"Notch filter slot {slot}", ObjectType="0x9", SubNumber=str(highest + 1)
        ),
        _sub(index, 0, "Highest sub-index supported", UNSIGNED8, "ro", str(highest)),
    ]
    sections += [_sub(index, sub, *subs[sub][:2], "rw", subs[sub][2]) for sub in sorted(subs)]
    return "".join(sections)


def _sub(index: int, sub: int, name: str, data_type: int, access: str, default: str) -> str:
    return _section(
        f"{index:04X}sub{sub}",
        ParameterName=name,
        ObjectType="0x7",
        DataType=f"0x{data_type:04X}",
        AccessType=access,
        DefaultValue=default,
        PDOMapping="0",
    )


def _section(name: str, **entries: str) -> str:
    return f"[{name}]\n" + "".join(f"{key}={value}\n" for key, value in entries.items()) + "\n"


def _check_listed(text: str, objects: list[str], folder: Path) -> None:
    """Every filter object must be listed in the template's [ManufacturerObjects]."""
    listed = text.split("[ManufacturerObjects]", 1)[1].split("\n\n", 1)[0].upper()
    missing = [o for o in objects if f"={o.upper()}\n" not in listed + "\n"]
    if missing:
        raise SystemExit(
            f"{folder / 'driver.toml'}: [filters] objects {missing} are not in the template's "
            f"[ManufacturerObjects] ({TEMPLATE})"
        )


def shipped_path(folder: Path) -> Path:
    """Where the driver in ``folder`` ships its EDS (``[canopen] eds``)."""
    description = tomllib.loads((folder / "driver.toml").read_text(encoding="utf-8"))
    return folder / description["canopen"]["eds"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="report shipped files that differ; write nothing")
    args = parser.parse_args(argv)
    stale = []
    for name in GENERATED_DRIVERS:
        folder = ROOT / "drivers" / name
        text, path = generate(folder), shipped_path(folder)
        if args.check:
            if not path.exists() or path.read_text(encoding="utf-8") != text:
                stale.append(path)
        else:
            path.write_text(text, encoding="utf-8", newline="\n")
    for path in stale:
        print(f"{path}: differs from what scripts/generate_eds.py generates", file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    sys.exit(main())
