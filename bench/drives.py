"""Every CiA 402 EDS/DCF in a folder, from the vendor's file to a whole emulated session. Run by hand::

    python bench/drives.py FOLDER [--out DIR] [--duration S]
    python bench/drives.py ../shared/drives/eds

For each file: ``hilident drivers new`` writes a driver folder (no hand edit),
``hilident drivers check`` validates it, and, when the drive has any cyclic
mode, the gantry session of ``configs/emulated-canopen-gantry.toml`` runs
against the drive's twin, built from that folder alone, host-streamed. The
excitation enters where the drive lets it: torque (CST), the torque offset
0x60B2 while CSP, IP or CSV holds the axis, else a velocity (CSV) or position
(CSP, IP) set-point perturbation in closed loop. The friction test runs in CSV,
or as a position profile in CSP or IP. Printed per
drive: the modes used, the TPDOs mapped, the samples lost, the resonance and
friction errors against the twin's truth, the notch (uploaded and achieved, or
why not), and the time taken.

Also run, with ``--project-drives``: the project's own test drives
(``tests/support/vendor_drives.py``) that describe a filter capability, to show the
notch uploaded, read back and verified on each encoding, and one whose own
PRBS generator and data recorder play and record the run
(``acquisition = "recorder"``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import traceback
from dataclasses import replace
from pathlib import Path

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "emulated-canopen-gantry.toml"


#: Set-point perturbations for drives that take no torque excitation: a few percent of the speed limit and a
#: tenth of a millimetre, enough for a coherent response in the gantry's band.
SETPOINT_AMPLITUDES = {"velocity": ("amplitude_mps", 0.05), "position": ("amplitude_m", 0.002)}


def _session_config(folder: Path, mode: str, friction: bool, duration_s: float, acquisition: str = "streamed"):
    from hilident.config.tables import load_config
    from hilident.drivers.description import declared_modes, load_driver

    cfg = load_config(CONFIG)
    excitation = replace(cfg.excitation, mode=mode, duration_s=duration_s)
    if mode in SETPOINT_AMPLITUDES:
        key, value = SETPOINT_AMPLITUDES[mode]
        excitation = replace(excitation, **{key: value})
    if acquisition == "recorder":  # the drive's own generator plays a PRBS: four periods of a 10-bit register
        excitation = replace(
            excitation,
            kind="prbs",
            register_length=10,
            clock_divider=1,
            duration_s=3 * 1023 / cfg.run.sample_rate_hz,
            f_max_hz=200.0,
        )
    friction_test = replace(cfg.friction_test, enabled=friction)
    if "velocity" not in declared_modes(load_driver(folder)):
        # the legs run as a position profile: the position loop needs longer to settle after each ramp
        friction_test = replace(friction_test, hold_s=friction_test.hold_s + 0.5, settle_s=friction_test.settle_s + 0.5)
    return replace(
        cfg,
        device=replace(cfg.device, driver=str(folder), acquisition=acquisition),
        friction_test=friction_test,
        excitation=excitation,
    )


def _truth(cfg):
    from hilident.emulator.factory import true_modes

    ((f, _),) = true_modes(cfg.emulator)
    return f, cfg.emulator.friction


def run_drive(folder: Path, out: Path, duration_s: float, acquisition: str = "streamed") -> dict:
    """The session on the twin of ``folder``; a row of the table."""
    from hilident.drivers.description import declared_modes, load_driver
    from hilident.protocol.canopen_profile import mode_name_of_code
    from hilident.session.run import Session

    driver = load_driver(folder)
    modes = declared_modes(driver)
    mode = next((m for m in ("torque", "torque_injection", "velocity", "position") if m in modes), None)
    row = {"modes": ", ".join(modes) or "none"}
    if mode is None:
        row["result"] = "not run: no cyclic mode (CST, CSV, CSP or IP)"
        return row
    friction = bool({"velocity", "position"} & set(modes)) and any(c.name == "torque_nm" for c in driver.channels)
    friction = friction and acquisition == "streamed"  # the friction legs are host-streamed
    cfg = _session_config(folder, mode, friction, duration_s, acquisition)
    session = Session(cfg, out, plots=False)
    summary = session.run()
    true_f, true_friction = _truth(cfg)
    ad = session.adapter

    def named(m):
        code = ad.desc.modes[m].code
        return (mode_name_of_code(code) or str(code)).upper()

    row["modes"] = f"{mode} ({named(mode)})" + (f", friction in {named(session.friction_mode)}" if friction else "")
    stream = summary["stream"]
    row["lost"] = stream.get("lost_samples", 0)
    late = [w.split(":")[0] for w in summary["warnings"] if "SYNCs (" in w and "late" in w]
    if late:  # nothing lost, but sampled at uneven instants: the figures below are distorted
        row["lost"] = f"{row['lost']} (many late SYNCs in {', '.join(late)})"
    found = summary["resonances"]
    row["resonance"] = (
        f"{100 * (min(found, key=lambda r: abs(r['frequency_hz'] - true_f))['frequency_hz'] - true_f) / true_f:+.2f} %"
        if found
        else "none found"
    )
    if friction and summary.get("friction"):
        got = summary["friction"]["params"]
        row["friction"] = (
            f"Fc {100 * (got['Fc'] - true_friction.Fc) / true_friction.Fc:+.1f} %, "
            f"Fv {100 * (got['Fv'] - true_friction.Fv) / true_friction.Fv:+.1f} %"
        )
    else:
        why = "no torque channel" if acquisition == "streamed" else "its legs are host-streamed"
        row["friction"] = f"{why}: not measured" if not friction else "-"
    upload = summary["upload"]
    if upload.get("written"):
        v = summary["verification"]
        band, line = v.get("band_reduction_db"), v.get("peak_reduction_db")
        row["notch"] = (
            f"uploaded, read back {'ok' if upload['verified_readback'] else 'DIFFERS'}, "
            f"{band:.1f} dB in the band ({line:.1f} dB at the resonance)"
            if band is not None
            else "uploaded"
        )
    else:
        notches = summary.get("notch_filters") or []
        designed = f"designed {notches[0]['center_hz']:.2f} Hz; " if notches else ""
        row["notch"] = designed + (upload.get("not_uploaded") or "no notch")
    row["pdos"] = (
        f"{len(ad.layout.tpdos)} TPDO ({'+'.join(str(len(t.columns)) for t in ad.layout.tpdos)} objects)"
        if acquisition == "streamed"
        else f"none: the drive's {acquisition}"
    )
    row["result"] = "ok"
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("folder", nargs="?", help="folder of vendor EDS/DCF files")
    p.add_argument("--out", help="where the driver folders and sessions go (default: a temporary folder)")
    p.add_argument("--duration", type=float, default=16.0, help="identification run length, s (default 16)")
    p.add_argument(
        "--project-drives",
        action="store_true",
        help="also run the project's test drives that describe a filter capability",
    )
    args = p.parse_args(argv)
    sys.path.insert(0, str(ROOT / "tests"))
    from hilident.drivers.tools import check_driver_folder, new_driver_folder

    out = Path(args.out) if args.out else Path(tempfile.mkdtemp(prefix="hilident-drives-"))
    files = (
        sorted(f for f in Path(args.folder).iterdir() if f.suffix.lower() in (".eds", ".dcf")) if args.folder else []
    )
    rows = []
    for eds in files:
        started = time.monotonic()
        row = {"drive": eds.name}
        try:
            new = new_driver_folder(eds, out / "drivers" / eds.stem)
            check = check_driver_folder(new.folder)
            row["check"] = "ok" if check.ok else f"{len(check.errors)} error(s): {check.errors[0]}"
            row["placeholders"] = len(check.placeholders)
            row["warnings"] = len(new.warnings)
            if check.ok:
                row.update(run_drive(new.folder, out / "sessions" / new.name, args.duration))
        except Exception as exc:  # the bench reports every drive, whatever breaks
            row["result"] = f"FAILED: {type(exc).__name__}: {exc}"[:300]
            traceback.print_exc()
        row["time"] = f"{time.monotonic() - started:.0f} s"
        rows.append(row)
        print(_line(row), flush=True)
    if args.project_drives:
        rows += _project_drives(out, args.duration)
    print()
    print(_table(rows))
    print(f"\ndriver folders and sessions in {out}")
    return 0


def _project_drives(out: Path, duration_s: float) -> list[dict]:
    from support.vendor_drives import FILTER_DRIVES, VendorDrive, write_vendor_drive

    rows = []
    runs = [(drive, "streamed") for drive in FILTER_DRIVES]
    runs.append((VendorDrive("acme-recorder", recorder="prbs"), "recorder"))  # the drive's generator and recorder
    for drive, acquisition in runs:
        started = time.monotonic()
        folder = write_vendor_drive(out / "project-drives", drive)
        row = {"drive": f"{drive.name} (project)", "check": "-", "placeholders": 0, "warnings": 0}
        try:
            row.update(run_drive(folder, out / "sessions" / drive.name, duration_s, acquisition))
        except Exception as exc:
            row["result"] = f"FAILED: {type(exc).__name__}: {exc}"[:300]
            traceback.print_exc()
        row["time"] = f"{time.monotonic() - started:.0f} s"
        rows.append(row)
        print(_line(row), flush=True)
    return rows


COLUMNS = (
    "drive",
    "check",
    "placeholders",
    "warnings",
    "modes",
    "pdos",
    "lost",
    "resonance",
    "friction",
    "notch",
    "result",
    "time",
)


def _line(row: dict) -> str:
    return " | ".join(f"{k}: {row[k]}" for k in COLUMNS if k in row)


def _table(rows: list[dict]) -> str:
    head = "| " + " | ".join(COLUMNS) + " |"
    rule = "|" + "|".join("---" for _ in COLUMNS) + "|"
    body = ["| " + " | ".join(str(r.get(k, "")) for k in COLUMNS) + " |" for r in rows]
    return "\n".join([head, rule, *body])


if __name__ == "__main__":
    sys.exit(main())
