"""`drivers new` and `drivers check` on every vendor EDS/DCF in a folder, as a table.

For each ``*.eds`` / ``*.dcf`` in DIR a driver folder is written (in a
temporary folder, or under ``--out``) exactly as ``hilident drivers new`` would,
then validated with ``hilident drivers check``. Nothing is edited by hand in
between. One row per file:

| column | meaning |
|---|---|
| warnings | quirks of the file that the loader repaired or reported |
| cyclic | cyclic modes available, in the preference order written to driver.toml |
| PDOs | RPDOs x most entries, TPDOs x most entries |
| period | object the cycle period is written to, and its default |
| torque ref | what torque is scaled by: rated_torque (0x6076), torque (no 0x6076), current, none |
| placeholders | keys of driver.toml whose values were assumed |
| vendor F/R/G | manufacturer objects that look like filters / recorders / generators |
| check | ``ok`` or the number of errors |

Usage::

    python bench/drives_eds.py DIR [--out FOLDER] [-v]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)
from hilident.drivers.tools import check_driver_folder, new_driver_folder
from hilident.errors import HilidentError

COLUMNS = ("file", "warnings", "cyclic", "PDOs", "period", "torque ref", "placeholders", "vendor F/R/G", "check")


def row(eds: Path, out: Path) -> tuple[list[str], list[str]]:
    """One table row for ``eds`` and the details (warnings, errors) behind it."""
    try:
        new = new_driver_folder(eds, out / eds.stem)
    except HilidentError as exc:
        return [eds.name, "-", "-", "-", "-", "-", "-", "-", "new failed"], [str(exc)]
    s = new.summary
    check = check_driver_folder(new.folder)
    period = s.period.object or "none"
    if s.period.seconds:
        period += f" {s.period.seconds * 1e3:g} ms"
    cells = [
        eds.name,
        str(len(new.warnings)),
        ",".join(s.cyclic_modes) or "none",
        f"{len(s.rpdo_entries)}x{s.rpdo_max_entries} / {len(s.tpdo_entries)}x{s.tpdo_max_entries}",
        period,
        s.torque_reference,
        str(len(new.placeholders)),
        f"{len(s.vendor_filters)}/{len(s.vendor_recorders)}/{len(s.vendor_generators)}",
        "ok" if check.ok else f"{len(check.errors)} errors",
    ]
    details = [f"warning: {w}" for w in new.warnings] + [f"placeholder: {p}" for p in new.placeholders]
    details += [f"vendor object: 0x{i:04X} {n}" for i, n in s.vendor_filters + s.vendor_recorders + s.vendor_generators]
    details += [f"check error: {e}" for e in check.errors]
    return cells, details


def table(rows: list[list[str]]) -> str:
    widths = [max(len(r[i]) for r in [list(COLUMNS)] + rows) for i in range(len(COLUMNS))]
    lines = [
        "| " + " | ".join(c.ljust(w) for c, w in zip(COLUMNS, widths, strict=True)) + " |",
        "|" + "|".join("-" * (w + 2) for w in widths) + "|",
    ]
    lines += ["| " + " | ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) + " |" for r in rows]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dir", type=Path, help="folder of vendor .eds/.dcf files")
    ap.add_argument("--out", type=Path, help="write the driver folders here (default: a temporary folder)")
    ap.add_argument(
        "-v", "--verbose", action="store_true", help="print each file's warnings, placeholders and vendor objects"
    )
    args = ap.parse_args(argv)
    files = sorted(p for p in args.dir.iterdir() if p.suffix.lower() in (".eds", ".dcf"))
    if not files:
        print(f"no .eds or .dcf files in {args.dir}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        t0 = time.perf_counter()
        rows, failed = [], 0
        for eds in files:
            cells, details = row(eds, out)
            rows.append(cells)
            failed += cells[-1] != "ok"
            if args.verbose:
                print(f"== {eds.name}")
                print("\n".join(f"  {d}" for d in details))
        print(table(rows))
        print(f"{len(files)} files, {len(files) - failed} pass `drivers check`, {time.perf_counter() - t0:.1f} s")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
