"""Command line: ``hilident run``, ``identify``, ``batch``, ``upload``, ``report``, ``show``, ``export``,
``emulate serial|modbus|canopen|fleet``, ``drivers``, ``init``, ``ports``.

Thin on purpose: it parses arguments and calls the session, the emulator
factory or the driver loader. Every :class:`~hilident.errors.HilidentError`
becomes one line on stderr and a non-zero exit code.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import time
from pathlib import Path

from hilident import __version__
from hilident.errors import HilidentError


def _run(args) -> int:
    from dataclasses import replace

    from hilident.config.tables import load_config, node_ids

    cfg = load_config(args.config)
    from hilident.progress import Progress  # after the config: its error comes without the session's imports
    from hilident.session.run import Session

    if args.clear_fault:
        cfg = replace(cfg, device=replace(cfg.device, allow_fault_reset=True))
    out = _out_folder(args.out, Path(args.config).stem, args.overwrite or args.dry_run)  # a dry run writes nothing
    several = len(node_ids(cfg.device)) > 1  # several nodes of one CANopen bus: hilident.session.nodes_run
    common = {"confirm": _go_ahead(args.yes), "dry_run": args.dry_run, "plots": not args.no_plots}
    if several:
        from hilident.session.nodes_run import NodesSession

        session: Session | NodesSession = NodesSession(cfg, out, Progress(enabled=not args.quiet), **common)
    else:
        session = Session(cfg, out, Progress(enabled=not args.quiet), save=args.save, **common)
    summary = session.run()
    if args.dry_run:
        if session.plan is not None:  # made before the dry run returns
            print(session.plan.describe())
        print("dry run: device reached and checked; nothing moved")
        return 0
    if several:
        _print_nodes_summary(summary)
    else:
        _print_run_summary(summary, args.quiet)
    print(f"wrote {out / 'summary.json'}")
    _print_report(out)
    return 0


def _print_nodes_summary(summary: dict) -> None:
    """What a run of several nodes found and did: the modes of all of them, every node's notches and their
    verification, and the warnings."""
    from hilident.io.summary import designed_and_stored

    modes = (summary.get("mimo") or {}).get("modes") or []
    found = ", ".join(f"{m['frequency_hz']:.2f} Hz (zeta {m['damping_ratio']:.3f})" for m in modes)
    print(f"modes of all nodes: {found or 'none found'}")
    for notch, slot in designed_and_stored(summary):
        stored = "read back and enabled" if slot.get("matches") else "not stored"
        print(
            f"node {notch['node']}: notch at {notch['center_hz']:.2f} Hz, {notch['width_hz']:.3g} Hz wide, "
            f"slot {notch['slot']}: {stored}"
        )
    for row in (summary.get("verification") or {}).get("resonances", []):
        print(
            f"verification: node {row['node']}: {row['frequency_hz']:.2f} Hz: the largest response near it fell "
            f"by {row['band_reduction_db']:.1f} dB ({row['reduction_db']:.1f} dB at the line)"
        )
    for warning in summary["warnings"]:
        print(f"warning: {warning}")


def _print_run_summary(summary: dict, quiet: bool) -> None:
    """What a run found and did, a line each: resonances, friction, model, verification, move test, upload,
    stream and warnings (with ``quiet``, also the automatic excitation amplitude, which the progress did not show)."""
    res = ", ".join(f"{r['frequency_hz']:.2f} Hz (zeta {r['damping_ratio']:.3f})" for r in summary["resonances"])
    print(f"resonances: {res or 'none found'}")
    auto = (summary.get("excitation") or {}).get("auto")
    if auto and quiet:  # otherwise the progress already showed it
        print(auto["line"])
    _print_friction(summary["friction"])
    _print_loop(summary.get("loop"))
    _print_model(summary.get("model"))
    _print_verification(summary["verification"])
    _print_map_verification((summary.get("workspace") or {}).get("verification"))
    _print_moves(summary.get("move_test"))
    if summary["upload"].get("saved"):
        print("saved: the device stored its parameters in non-volatile memory")
    s = summary["stream"]
    print(
        f"stream: {s['samples']} samples, {s['lost_blocks']} lost blocks, {s['corrupt_frames']} corrupt frames, "
        f"{s['underruns']} underruns"
    )
    for w in summary["warnings"]:
        print(f"warning: {w}")


def _print_friction(f: dict | None) -> None:
    """The friction line: the fitted Coulomb + viscous or Stribeck parameters (N*m, N*m/(m/s), m/s)."""
    if not f:
        return
    p = f["params"]
    ci = f.get("ci95") or {}

    def pm(name: str) -> str:  # the 95 % half-width, where the fit gives one
        return f" +- {ci[name]:.2g}" if isinstance(ci.get(name), (int, float)) else ""

    if f.get("structure") == "coulomb_viscous":
        print(f"friction: Coulomb + viscous: Fc {p['Fc']:.3g}{pm('Fc')} N*m, Fv {p['Fv']:.3g}{pm('Fv')} N*m/(m/s)")
    else:
        print(
            f"friction: Stribeck: Fc {p['Fc']:.3g} N*m, Fs {p['Fs']:.3g} N*m, Fv {p['Fv']:.3g} N*m/(m/s), "
            f"vs {p['vs']:.3g} m/s"
        )


def _print_loop(loop: dict | None) -> None:
    """The drive's loop: the velocity loop's margins with the present gains (without and with the notch), what the
    notch buys or costs, and the gains uploaded (kept or put back)."""
    if not loop:
        return

    def margins(figures: dict | None) -> str:
        if not figures:
            return "-"
        gm, pm = figures.get("gain_margin_db"), figures.get("phase_margin_deg")
        return f"GM {'-' if gm is None else f'{gm:.1f}'} dB, PM {'-' if pm is None else f'{pm:.1f}'} deg"

    v = loop["velocity"]
    notched = f"; with the notch {margins(v['with_notch'])}" if v.get("with_notch") else ""
    print(f"loop: velocity loop with the present gains {margins(v['without_notch'])}{notched}")
    if loop.get("tuning"):
        print(f"loop: {loop['tuning']['verdict']}")
    up = loop.get("upload")
    if up:
        if up.get("kept"):
            print(f"loop: gains {up.get('readback')} written, read back and proven by the closed-loop run")
        else:
            print(f"loop: gains not kept: {up.get('reason', '')}")


def _print_verification(ver: dict) -> None:
    """The verification line: the reduction (dB) at the resonance line, and near the resonance when measured."""
    if ver["peak_reduction_db"] is None:
        return
    band = ver.get("band_reduction_db")
    head = "" if band is None else f"largest response near the resonance reduced by {band:.1f} dB, "
    print(f"verification: {head}{ver['peak_reduction_db']:.1f} dB at the resonance line")


def _print_map_verification(mapped: dict | None) -> None:
    """The map verification line: the worst band reduction (dB) over the mapped positions, where (m) and on
    what, and the holding loop's worst."""
    if not mapped or mapped.get("worst_band_reduction_db") is None:
        return
    on = "command to velocity" if mapped["measured_on"] == "filtered_plant" else "excitation to velocity"
    worst = min(mapped["positions"], key=lambda r: r["band_reduction_db"])
    # a floor of no finite value (a record without coherence) is null in summary.json
    floor = (
        f", at its record's noise floor {worst['floor_db']:.1f} dB"
        if worst.get("floor_limited") and worst.get("floor_db") is not None
        else ""
    )
    print(
        f"map verification: band figure {mapped['worst_band_reduction_db']:.1f} dB at worst "
        f"({mapped['worst_position_m']:+.3f} m, {on}{floor}); the holding loop's "
        f"{mapped['worst_loop_band_reduction_db']:.1f} dB at worst"
    )


def _print_moves(test: dict | None) -> None:
    """The move test's line: the worst RMS reduction, and at how many places the move with the notch rang no
    more than the axis does at rest."""
    moves = (test or {}).get("moves") or []
    worst = [m for m in moves if m.get("rms_reduction_db") is not None]
    if not worst:
        return
    w = min(worst, key=lambda m: m["rms_reduction_db"])
    at_rest = sum(
        1 for m in moves if m.get("standstill_rms_m") is not None and m.get("rms_reduction_above_standstill_db") is None
    )
    p2p = w.get("peak_to_peak_reduction_db")
    p2p = "" if p2p is None else f", {p2p:.1f} dB peak to peak"
    print(
        f"move test: ringing after the move reduced by {w['rms_reduction_db']:.1f} dB RMS at worst (from "
        f"{w['start_m']:+.3f} m{p2p}); with the notch, {at_rest} of {len(moves)} move(s) rang no more than the "
        "axis at rest"
    )
    _print_shaped_moves(moves)


def _print_shaped_moves(moves: list[dict]) -> None:
    """One line per input shaper of the move test: its worst RMS reduction, and at how many places its move rang
    no more than the axis does at rest."""
    names = list(dict.fromkeys(s["name"] for m in moves for s in m.get("shapers") or []))
    for name in names:
        rows = [(m, s) for m in moves for s in m.get("shapers") or [] if s["name"] == name]
        measured = [(m, s) for m, s in rows if s.get("rms_reduction_db") is not None]
        if not measured:
            continue
        place, worst = min(measured, key=lambda pair: pair[1]["rms_reduction_db"])
        rest = sum(1 for _, shaped in rows if shaped.get("rms_reduction_above_standstill_db") is None)
        print(
            f"move test: with the {name} ({worst['kind']}), reduced by {worst['rms_reduction_db']:.1f} dB RMS at "
            f"worst (from {place['start_m']:+.3f} m, {1e3 * worst['added_delay_s']:.0f} ms later); {rest} of "
            f"{len(rows)} move(s) rang no more than the axis at rest"
        )


def _out_folder(given: str | None, stem: str, overwrite: bool) -> Path:
    """Where run and identify write (and upload, given ``--out``): ``--out``, else ``runs/<stem>-<YYYYmmdd-HHMMSS>``.

    Raises
    ------
    UsageError
        ``--out`` is a folder that already holds files and ``overwrite`` is not set.
    """
    from hilident.errors import UsageError

    if given is None:
        base = Path("runs") / f"{stem}-{time.strftime('%Y%m%d-%H%M%S')}"
        out, n = base, 1
        while out.exists():  # two runs within one second
            n += 1
            out = base.with_name(f"{base.name}-{n}")
        return out
    out = Path(given)
    if not overwrite and out.is_dir() and any(out.iterdir()):
        raise UsageError(
            f"--out {out}: holds earlier results; pass --overwrite to write over them, or leave --out "
            "out for a new folder runs/<name>-<date>-<time>"
        )
    return out


def _go_ahead(
    yes: bool,
    question: str = "Move the axis as planned?",
    refusal: str = "this run moves a real axis: confirm at a terminal, or pass --yes "
    "(hilident run --dry-run shows the plan without moving)",
):
    """How a run (or an upload) on a real port gets its go-ahead: ``--yes``, or the user at a terminal."""

    def confirm(plan) -> bool:
        print(plan.describe(), file=sys.stderr, flush=True)
        if yes:
            return True
        if not (sys.stdin.isatty() and sys.stderr.isatty()):
            from hilident.errors import ArmingRefused

            raise ArmingRefused(refusal)
        answer = input(f"{question} Type 'yes' to go ahead: ")
        return answer.strip().lower() == "yes"

    return confirm


def _upload_gains(args, cfg) -> int:
    """``hilident upload --gains``: the gains of an earlier run (or ``--gain`` ones) into the drive."""
    from hilident.errors import UsageError
    from hilident.progress import Progress
    from hilident.session.gain_upload import GainUploadCommand, parse_gain_overrides

    if args.slot is not None:
        raise UsageError("--slot: filter slots take notches; --gains writes the drive's loop gains")
    confirm = _go_ahead(
        args.yes,
        "Write these gains to the drive?",
        "this upload changes the loop gains of a real drive: confirm at a terminal, or pass --yes "
        "(hilident upload --gains --dry-run shows what would be written)",
    )
    command = GainUploadCommand(
        cfg,
        getattr(args, "from"),
        args.out,
        Progress(enabled=not args.quiet),
        confirm=confirm,
        gains=parse_gain_overrides(args.gain),
        save=args.save,
        dry_run=args.dry_run,
    )
    if args.out and not args.dry_run:
        _out_folder(args.out, "", args.overwrite)
    try:
        summary = command.run()
    finally:
        if command.plan is not None and (args.dry_run or not command.summary):
            print(command.describe())
    for w in summary["warnings"]:
        print(f"warning: {w}")
    if args.dry_run:
        print("dry run: the drive reached, its gains read and the new ones checked; nothing written")
        return 0
    g = summary["gains"]
    print(f"gains: read back as written {g['readback']}" + ("; saved" if g["saved"] else ""))
    print(f"wrote {command.out / 'summary.json'}")
    return 0


def _upload(args) -> int:
    from hilident.config.tables import load_config

    cfg = load_config(args.config)
    if args.gains or args.gain:
        return _upload_gains(args, cfg)
    from hilident.progress import Progress
    from hilident.session.upload import UploadCommand

    confirm = _go_ahead(
        args.yes,
        "Write these filters to the device?",
        "this upload changes the filters of a real drive: confirm at a terminal, or pass --yes "
        "(hilident upload --dry-run shows what would be written)",
    )
    command = UploadCommand(
        cfg,
        getattr(args, "from"),
        args.out,
        Progress(enabled=not args.quiet),
        confirm=confirm,
        slot=args.slot,
        save=args.save,
        dry_run=args.dry_run,
    )
    if args.out and not args.dry_run:  # the default is always a new folder; a dry run writes nothing
        _out_folder(args.out, "", args.overwrite)
    try:
        summary = command.run()
    except HilidentError:
        if command.summary:
            _say(
                f"hilident: wrote {command.out / 'summary.json'} up to the failed step; every slot written "
                "was put back as it was"
            )
        raise
    if args.dry_run:
        if command.plan is not None:  # made before the dry run returns
            print(command.plan.describe())
        for w in summary["warnings"]:
            print(f"warning: {w}")
        print("dry run: device reached and its slots read; nothing written")
        return 0
    for s in summary["upload"]["slots"]:
        a = s["achieved"]
        print(
            f"slot {s['slot']}: read back as written, enabled; {a['attenuation_at_design_center_db']:.1f} dB at "
            f"the designed centre (designed {a['attenuation_at_design_center_db'] - a['depth_error_db']:.1f} dB, "
            f"realisable on the device {a['realisable_db']:.1f} dB), deepest at {a['center_hz']:.5g} Hz"
        )
    if summary["upload"]["saved"]:
        print("saved: the device stored its parameters in non-volatile memory")
    for w in summary["warnings"]:
        print(f"warning: {w}")
    print(f"wrote {command.out / 'summary.json'}")
    _print_report(command.out)
    return 0


def _export(args) -> int:
    from hilident.io.export import run_export

    written = run_export(args.dir, args.format, args.out, args.rate_hz, args.axis)
    print(f"wrote {written}")
    return 0


def _print_model(m: dict | None) -> None:
    """One line: grey-box parameters with standard deviations, and the fit % on each record."""
    if not m:
        return
    params = ", ".join(
        f"{k} {v:.5g} ± {m['stderr'][k]:.2g} ({m['relative_stderr_percent'][k]:.2g} %)" for k, v in m["params"].items()
    )

    def figures(v: dict) -> str:
        rel = v.get("relative_error")
        return f"{v['fit_percent']:.1f} %" + (f" (relative error {rel:.3g})" if rel is not None else "")

    checks = ", ".join(f"{figures(v)} on {name}" for name, v in m["validation"].items())
    excluded = m["estimation"].get("low_speed_rows_excluded")
    print(
        f"{m['kind']}: {params}; fit {figures(m['estimation'])} on the estimation data"
        + (f", {checks}" if checks else "")
        + (f"; {excluded} low-speed rows left out" if excluded else "")
    )


def _identify(args) -> int:
    from hilident.config.tables import load_config

    cfg = load_config(args.config) if args.config else None
    from hilident.progress import Progress
    from hilident.session.offline import identify_recording  # after the config, as in _run

    out = _out_folder(args.out, Path(args.data).stem, args.overwrite)
    started = time.time()
    try:
        summary = identify_recording(cfg, args.data, out, Progress(enabled=not args.quiet), args.validation)
    except HilidentError:
        written = out / "summary.json"
        if written.is_file() and written.stat().st_mtime >= started - 1.0:  # this run's (filesystems round)
            # the steps that succeeded are in it, and the one that failed is named
            _say(f"hilident: wrote {written} up to the failed step")
        raise
    if summary["data"].get("configuration") == "stored in the recording":
        print(f"configuration: the one stored in {args.data} (mode {summary['data'].get('recorded_mode')})")
    res = ", ".join(f"{r['frequency_hz']:.4g} Hz (zeta {r['damping_ratio']:.3f})" for r in summary["resonances"])
    print(f"resonances: {res or 'none found'}")
    _print_model(summary.get("model"))
    for w in summary["warnings"]:
        print(f"warning: {w}")
    print(f"wrote {out / 'summary.json'}")
    _print_report(out)
    return 0


def _batch(args) -> int:
    from hilident.config.tables import load_config

    cfg = load_config(args.config) if args.config else None
    from hilident.batch.runner import run_batch  # after the config, as in _run
    from hilident.progress import Progress

    try:
        outcome = run_batch(
            args.inputs,
            cfg,
            args.out,
            scheduler=args.scheduler,
            workers=args.workers,
            retry_failed=args.retry_failed,
            progress=Progress(enabled=not args.quiet),
        )
    except KeyboardInterrupt as exc:
        from hilident import endings

        endings.ignore_further_signals()
        finished = getattr(exc, "outcome", None)
        _say(
            f"hilident: {exc or 'interrupted'}; "
            + (
                "nothing was identified yet"
                if finished is None
                else f"the cluster is closed; {finished.done} recordings finished are in {finished.table}"
            )
        )
        return getattr(exc, "exit_code", 130)
    for row in outcome.failures:
        error = row["error"]  # a DataError names its file already
        print(f"failed: {error}" if error.startswith(row["path"]) else f"failed: {row['path']}: {error}")
    print(
        f"batch: {outcome.recordings} recordings: {outcome.done - outcome.failed} identified, {outcome.failed} "
        f"failed, {outcome.skipped} skipped (already in the table)"
    )
    from hilident.batch.verdicts import verdict_lines

    for line in verdict_lines(outcome.drifts):
        print(line)
    if outcome.done:
        print(
            f"wall time {outcome.wall_s:.1f} s, {outcome.per_recording_s:.3g} s per recording "
            f"({outcome.workers} worker{'s' * (outcome.workers != 1)}; one task took {outcome.mean_task_s:.3g} s "
            "on average)"
        )
    print(f"wrote {outcome.table} and {outcome.csv}")
    if outcome.report is not None:
        print(f"wrote {outcome.report} (open it in a browser) and {outcome.report.with_name('drift.json')}")
    return 0


def _print_report(folder: Path) -> None:
    """Name the report the command wrote (a report that could not be written was a warning line already)."""
    report, summary = folder / "report.html", folder / "summary.json"
    if report.is_file() and report.stat().st_mtime >= summary.stat().st_mtime:
        print(f"wrote {report} (open it in a browser)")


def _report(args) -> int:
    from hilident.html_report import write_report

    folder = Path(args.dir)
    if folder.name == "summary.json" and folder.is_file():  # the summary itself, as upload --from takes it
        folder = folder.parent
    print(f"wrote {write_report(folder)}")
    return 0


def _show(args) -> int:
    from hilident.plots.show import parse_channel_list, show_recording

    channels = None
    if args.channels is not None:
        channels = parse_channel_list(args.channels)
        if not channels:
            from hilident.errors import UsageError

            raise UsageError("--channels: give channel names separated by commas, e.g. --channels excitation,torque_nm")
    shown = show_recording(args.recording, channels, args.out)
    if shown.png is not None:
        print(f"wrote {shown.png}" + (f" ({shown.note}: no window opened)" if shown.note else ""))
    return 0


def _serve_until_stopped(device) -> int:
    """Keep an emulated device running until Ctrl-C or SIGTERM; re-raise what stopped it otherwise."""
    stop = []
    signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
    try:
        while not stop and device.server.error is None:
            time.sleep(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        device.close()
    if device.server.error is not None:
        raise device.server.error
    return 0


def _emulate_serial(args) -> int:
    from hilident.emulator.serial.server import start_serial_board

    cfg, emu_cfg, driver = _emulator_setup(args, "serial", "myrio-board")
    baud = args.baudrate or cfg.device.baudrate or driver.default_baudrate
    device = start_serial_board(emu_cfg, driver, baud, link="tcp" if args.tcp else "pty")
    print(device.port, flush=True)
    print(f"emulated {driver.name} at {baud} baud; Ctrl-C to stop", file=sys.stderr, flush=True)
    return _serve_until_stopped(device)


def _emulator_setup(args, transport: str, default_driver: str):
    """Configuration, ``[emulator]`` table (with ``--time-scale``) and driver of a standalone emulator."""
    import math
    from dataclasses import replace

    from hilident.config.tables import load_config, parse_config
    from hilident.drivers.description import find_driver
    from hilident.errors import ConfigError, UsageError

    if args.time_scale and not (math.isfinite(args.time_scale) and 0 < args.time_scale <= 1000):
        raise UsageError(
            f"--time-scale {args.time_scale:g}: must be a number of simulated seconds per second in (0, 1000]"
        )
    if getattr(args, "port", 0) and not 0 < args.port < 65536:
        raise UsageError(f"--port {args.port}: must be a TCP port, 1..65535 (0: any free one)")
    if getattr(args, "baudrate", 0) and not 0 < args.baudrate <= 100_000_000:
        raise UsageError(f"--baudrate {args.baudrate}: must be a positive line rate in baud")

    minimal = "[limits]\ntorque_nm = 1.0\nvelocity_mps = 1.0\nposition_min_m = -1.0\nposition_max_m = 1.0\n"
    cfg = load_config(args.config) if args.config else parse_config(minimal, "<defaults>")
    emu_cfg = replace(cfg.emulator, time_scale=args.time_scale) if args.time_scale else cfg.emulator
    driver = find_driver(args.driver or (cfg.device.driver if args.config else default_driver), cfg.device.driver_paths)
    if driver.transport != transport:
        raise ConfigError(
            "device.driver",
            f"{driver.name!r} is a {driver.transport} driver, not a {transport} one (--driver {default_driver})",
        )
    return cfg, emu_cfg, driver


def _emulate_modbus(args) -> int:
    from hilident.emulator.modbus.server import start

    cfg, emu_cfg, driver = _emulator_setup(args, "modbus", "modbus-servo")
    device = start(emu_cfg, driver, cfg.device, link="pty" if args.rtu else "tcp")
    print(device.port, flush=True)
    line = f"Modbus RTU at {device.device.baudrate} baud, parity N" if args.rtu else "Modbus TCP"
    print(
        f"emulated {driver.name} ({line}, device id {device.device.modbus.device_id}); Ctrl-C to stop",
        file=sys.stderr,
        flush=True,
    )
    return _serve_until_stopped(device)


def _emulate_canopen(args) -> int:
    from hilident.emulator.canopen.server import start_socketcand

    cfg, emu_cfg, driver = _emulator_setup(args, "canopen", "canopen-servo")
    # the process is the drive's hardware: its bus and timer threads get the interpreter within 0.1 ms (the
    # 5 ms default would make its SYNCs and relayed frames late for no reason of the drive's)
    sys.setswitchinterval(1e-4)
    device = start_socketcand(emu_cfg, driver, cfg.device, port=args.port)
    print(device.port, flush=True)
    print(
        f"emulated {driver.name}, {_nodes_text(device.device)}, on socketcand: [device.canopen] "
        f'can_interface = "socketcand", [device] port = "{device.port}"; Ctrl-C to stop',
        file=sys.stderr,
        flush=True,
    )
    return _serve_until_stopped(device)


def _nodes_text(device) -> str:
    """``node 1``, or ``nodes 1, 2 on one mechanism`` for the twin of several nodes."""
    ids = list(device.canopen.node_ids) or [device.canopen.node_id]
    return f"node {ids[0]}" if len(ids) == 1 else f"nodes {', '.join(map(str, ids))} on one mechanism"


def _emulate_fleet(args) -> int:
    import datetime as dt

    from hilident.config.tables import load_config
    from hilident.errors import UsageError

    base = load_config(args.config) if args.config else None
    try:
        start = dt.date.fromisoformat(args.start)
    except ValueError:
        raise UsageError(f"--start {args.start!r}: must be a date, YYYY-MM-DD") from None
    from hilident.batch.fleet import SAMPLE_RATES_HZ, write_fleet
    from hilident.progress import Progress

    progress = Progress(enabled=not args.quiet)
    result = write_fleet(
        args.out,
        args.axes,
        args.days,
        seed=args.seed,
        base=base,
        start=start,
        duration_s=args.duration_s,
        drifting_share=args.drifting_share,
        damaged=args.damaged,
        sample_rates_hz=tuple(args.sample_rate_hz) if args.sample_rate_hz else SAMPLE_RATES_HZ,
        viscous=args.viscous,
        overwrite=args.overwrite,
        progress=progress.fraction("recordings"),
        say=progress.step,
    )
    print(
        f"wrote {result.recordings} recordings of {args.axes} axes ({result.drifting} drifting, {result.damaged} "
        f"damaged on purpose), {result.total_bytes / 1e6:.1f} MB, and the truth in {result.out / 'fleet.json'}"
    )
    return 0


def _drivers(args) -> int:
    from hilident.drivers.description import available_drivers, find_driver, search_path

    if getattr(args, "action", None) == "new":
        return _drivers_new(args)
    if getattr(args, "action", None) == "check":
        return _drivers_check(args)
    for name in available_drivers():
        try:
            d = find_driver(name)
        except HilidentError as exc:  # one broken folder does not hide the others
            folder = next(p / name for p in search_path() if (p / name / "driver.toml").is_file())
            print(f"{name}\t?\t{folder}\n  cannot be loaded: {exc}")
        else:
            folder = d.folder
            print(f"{name}\t{d.transport}\t{folder}")
        if args.verbose:
            from hilident.drivers.tools import describe_driver

            print(describe_driver(folder))
    if args.verbose:
        print("searched: " + ", ".join(str(p) for p in search_path()))
    return 0


def _drivers_new(args) -> int:
    from hilident.drivers.tools import new_driver_folder

    r = new_driver_folder(args.eds, args.out, args.name)
    for w in r.warnings:
        print(f"warning: {w}")
    print(f"wrote {r.folder / 'driver.toml'} and {r.folder / r.eds_file}")
    print(f"cyclic modes: {', '.join(r.summary.cyclic_modes) or 'none'}")
    if r.proposal is not None:
        print(
            f"[filters] proposed for {r.proposal.family.name}, recognised by {r.proposal.how}: every key a placeholder"
        )
    for p in r.placeholders:
        print(f"placeholder: {p}")
    return 0


def _drivers_check(args) -> int:
    from dataclasses import replace

    from hilident.drivers.tools import check_driver_folder

    r = check_driver_folder(args.folder)
    tried = False
    if r.ok and not args.no_twin:  # what run does to the filters, on a twin of a folder whose objects are known good
        from hilident.cli.driver_trial import try_filter_slots

        trial = try_filter_slots(args.folder)
        tried = trial.tried
        r = replace(r, errors=r.errors + trial.errors, warnings=r.warnings + trial.warnings)
    for w in r.warnings:
        print(f"warning: {w}")
    for p in r.placeholders:
        print(f"placeholder: {p} (accepted on the emulator, refused on a real port)")
    for e in r.errors:
        print(f"error: {e}")
    if tried and r.ok:
        print("filter slot 0: read, written bypassed, read back, enabled, read back and restored on a twin")
    print(f"{args.folder}: " + ("ok" if r.ok else f"{len(r.errors)} error(s)"))
    return 0 if r.ok else 2


def _init(args) -> int:
    from hilident.drivers.starter_config import starter_config, write_starter_config

    out = Path(args.out)
    text = starter_config(args.transport, args.driver).replace("THIS_FILE", str(out))
    write_starter_config(out, text, overwrite=args.overwrite)
    print(f"wrote {out}: check the keys marked CHECK, then: hilident run {out} --dry-run")
    return 0


def _ports(args) -> int:
    from hilident.adapters.ports import can_interfaces, describe_ports, serial_ports

    serial_list = serial_ports()
    can_list, notes = can_interfaces() if not args.no_can else ([], ["CAN channels not searched (--no-can)"])
    print(describe_ports(serial_list, can_list, notes))
    return 0


def build_parser() -> argparse.ArgumentParser:
    from hilident.cli import help_text as cli_help

    raw = argparse.RawDescriptionHelpFormatter
    p = argparse.ArgumentParser(
        prog="hilident",
        formatter_class=raw,
        epilog=cli_help.TOP,
        description="Hardware-in-the-loop excitation, identification and notch tuning.",
    )
    p.add_argument("--version", action="version", version=f"hilident {__version__}")
    p.add_argument(
        "--log-level",
        type=str.lower,
        choices=("debug", "info", "warning", "error"),
        help="send the log of hilident and the libraries it drives (python-can, canopen, pymodbus) at "
        "this level and above to stderr (default: none configured, only the one-line messages)",
    )
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser(
        "run", help="run a whole bench session from a config file", formatter_class=raw, epilog=cli_help.RUN
    )
    run.add_argument("config", help="TOML configuration")
    run.add_argument("--out", help="output folder (default: a new folder runs/<config name>-<YYYYmmdd-HHMMSS>)")
    run.add_argument("--overwrite", action="store_true", help="write into --out even when it holds earlier results")
    run.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    run.add_argument(
        "--yes",
        action="store_true",
        help="go ahead without asking (on a real port the plan is "
        "still printed; without --yes a terminal is needed to confirm)",
    )
    run.add_argument(
        "--dry-run",
        action="store_true",
        help="connect, identify the device, check every capability and rate, print the plan, and move nothing",
    )
    run.add_argument(
        "--no-plots",
        action="store_true",
        help="write summary.json and the recordings, no PNGs (scripted and nightly runs)",
    )
    run.add_argument(
        "--clear-fault",
        action="store_true",
        help="clear a fault the device has latched "
        "(a limit trip, a watchdog) when connecting, as [device] allow_fault_reset = true",
    )
    run.add_argument(
        "--save",
        action="store_true",
        help="once the notches are uploaded, read back and verified, "
        "have the device store its parameters in non-volatile memory (they survive a power cycle)",
    )
    run.set_defaults(func=_run)

    ide = sub.add_parser(
        "identify",
        help="identify the plant in a recording (hilident HDF5, CSV or .mat)",
        formatter_class=raw,
        epilog=cli_help.IDENTIFY,
    )
    ide.add_argument("data", help="recording file")
    ide.add_argument(
        "--config",
        help="TOML configuration with [data] (column mapping) and [model]; not needed "
        "for a hilident recording, which holds its run's configuration (a config given overrides it "
        "table by table)",
    )
    ide.add_argument("--out", help="output folder (default: a new folder runs/<data name>-<YYYYmmdd-HHMMSS>)")
    ide.add_argument("--overwrite", action="store_true", help="write into --out even when it holds earlier results")
    ide.add_argument(
        "--validation",
        help="a second recording of the same axis to validate the [model] fit on "
        "(default: the last [model].holdout of the data)",
    )
    ide.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    ide.set_defaults(func=_identify)

    bat = sub.add_parser(
        "batch",
        help="identify many recordings in parallel on Dask into one table "
        "(batch.parquet, batch.csv); a re-run skips those already in it",
        formatter_class=raw,
        epilog=cli_help.BATCH,
    )
    bat.add_argument(
        "inputs",
        nargs="+",
        metavar="INPUT",
        help="recordings, folders (searched at any depth for .h5, .hdf5, .csv, .mat) or globs",
    )
    bat.add_argument(
        "--config",
        help="TOML configuration as for identify (not needed for hilident recordings); "
        "its [batch] table sets the drift verdict",
    )
    bat.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="folder of the table: batch.parquet and batch.csv (an earlier table there is extended)",
    )
    bat.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="a Dask scheduler to run on (tcp://HOST:8786), or "
        "'synchronous' for a plain loop in this process (default: a local cluster on 127.0.0.1)",
    )
    bat.add_argument(
        "--workers", type=int, metavar="N", help="worker processes of the local cluster (default: one per core)"
    )
    bat.add_argument(
        "--retry-failed",
        action="store_true",
        help="identify again the recordings whose earlier row is a failure (default: skipped like the others)",
    )
    bat.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    bat.set_defaults(func=_batch)

    upl = sub.add_parser(
        "upload",
        help="upload the notches of an earlier run or identify to a device, with "
        "read-back, enable-after-match and rollback",
        formatter_class=raw,
        epilog=cli_help.UPLOAD,
    )
    upl.add_argument(
        "--from", required=True, metavar="RUN_DIR|SUMMARY", help="a run or identify folder, or its summary.json"
    )
    upl.add_argument(
        "--config",
        required=True,
        help="TOML configuration of the device ([device], [emulator] for "
        "the twin, [notch] for a notch designed at another filter rate)",
    )
    upl.add_argument(
        "--slot",
        type=int,
        help="first filter slot (the notches go to it and the ones after it; "
        "default: the slots they were designed for)",
    )
    upl.add_argument(
        "--save",
        action="store_true",
        help="once every slot read back as written, have the device store its parameters in non-volatile memory",
    )
    upl.add_argument(
        "--dry-run",
        action="store_true",
        help="connect, read the slots, print what would be written "
        "(the stored form and its attenuation); write nothing",
    )
    upl.add_argument(
        "--gains",
        action="store_true",
        help="write the loop gains the run proposed ([tuning]) instead of notches: refused when they would not keep "
        "the loops stable on the run's plant (loop_plant.npz), read back, the old ones put back on any failure",
    )
    upl.add_argument(
        "--gain",
        action="append",
        metavar="NAME=VALUE",
        help="with --gains: this gain instead of the proposal's, SI units (kv_nm_per_mps, ti_s, kp_pos_per_s, "
        "velocity_filter_hz); repeatable",
    )
    upl.add_argument(
        "--yes", action="store_true", help="go ahead on a real port without asking (the plan is still printed)"
    )
    upl.add_argument("--out", help="output folder (default: a new folder beside the source, <source>-upload)")
    upl.add_argument("--overwrite", action="store_true", help="write into --out even when it holds earlier results")
    upl.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    upl.set_defaults(func=_upload)

    shw = sub.add_parser(
        "show", help="plot a recording: its channels over time with units, its events and the run's metadata"
    )
    shw.add_argument("recording", help="a recording (.h5) written by hilident run")
    shw.add_argument(
        "--channels",
        metavar="A,B,...",
        help="channels to draw, separated by commas (default: all but sample_index and time_s)",
    )
    shw.add_argument(
        "--out",
        metavar="PNG",
        help="write the figure to this PNG instead of opening a window "
        "(without a display it goes to <recording>.png beside the recording)",
    )
    shw.set_defaults(func=_show)

    exp = sub.add_parser(
        "export",
        help="write the plant model (transfer function and state space, continuous "
        "and at the drive's loop rate), the modal state space of every input and output of an identify with "
        "several, grey-box parameters and notches for MATLAB, JSON or python-control",
    )
    exp.add_argument("dir", metavar="DIR", help="a run, identify or upload output folder (or its summary.json)")
    exp.add_argument(
        "--format",
        required=True,
        choices=["mat", "json", "python-control", "klipper", "marlin", "shaper", "shaper-table"],
        help="mat: MATLAB structs (scipy.io.savemat); json: one documented file; python-control: a small "
        "script that rebuilds control.TransferFunction / StateSpace objects (needs pip install "
        "'hilident[control]'; in Python, hilident.io.export.to_control gives them directly); the input shaper "
        "the measured resonances favour: klipper ([input_shaper] section), marlin (M593), shaper (JSON impulses); "
        "shaper-table: the shaper scheduled by position of a run with [map] (CSV position -> frequency)",
    )
    exp.add_argument(
        "--axis", default="x", choices=["x", "y", "z"], help="klipper, marlin: the axis the shaper is for (default x)"
    )
    exp.add_argument(
        "--out",
        metavar="FILE",
        help="file to write (default in DIR: model.mat, model.json, model_control.py, input_shaper.cfg, "
        "input_shaper.gcode, input_shaper.json or input_shaper_schedule.csv)",
    )
    exp.add_argument(
        "--rate-hz",
        type=float,
        metavar="HZ",
        help="discretise at this rate, Hz (default: the drive's loop rate the summary names)",
    )
    exp.set_defaults(func=_export)

    rep = sub.add_parser(
        "report",
        help="write report.html again from the summary.json, plots and recordings of a run, identify or upload folder",
    )
    rep.add_argument("dir", metavar="DIR", help="the output folder (it must hold summary.json), or its summary.json")
    rep.set_defaults(func=_report)

    emu = sub.add_parser("emulate", help="run an emulated device standalone")
    emu_sub = emu.add_subparsers(dest="transport", required=True)
    ser = emu_sub.add_parser("serial", help="emulated serial board on a pseudo-terminal; prints its device path or URL")
    ser.add_argument("--config", help="take [emulator] (plant, friction, drive) from this config")
    ser.add_argument("--driver", help="driver name or folder (default: the config's, or myrio-board)")
    ser.add_argument(
        "--baudrate", type=int, default=0, help="line rate in baud (default: the config's, else the driver's)"
    )
    ser.add_argument("--time-scale", type=float, default=0.0, help="simulated seconds per second (default 1)")
    ser.add_argument(
        "--tcp", action="store_true", help="serve a raw TCP line on 127.0.0.1 (socket://) instead of a pty"
    )
    ser.set_defaults(func=_emulate_serial)
    mb = emu_sub.add_parser("modbus", help="emulated Modbus drive (TCP on 127.0.0.1, or RTU on a pty); prints its port")
    mb.add_argument("--config", help="take [emulator] and [device] (device_id, baudrate) from this config")
    mb.add_argument("--driver", help="driver name or folder (default: the config's, or modbus-servo)")
    mb.add_argument("--time-scale", type=float, default=0.0, help="simulated seconds per second (default 1)")
    mb.add_argument("--rtu", action="store_true", help="Modbus RTU on a pseudo-terminal instead of Modbus TCP")
    mb.set_defaults(func=_emulate_modbus)
    co = emu_sub.add_parser(
        "canopen", help="emulated CiA 402 drive on a socketcand server on 127.0.0.1; prints HOST:PORT/CHANNEL"
    )
    co.add_argument("--config", help="take [emulator] and [device] (node_id) from this config")
    co.add_argument("--driver", help="driver name or folder (default: the config's, or canopen-servo)")
    co.add_argument("--time-scale", type=float, default=0.0, help="simulated seconds per second (default 1)")
    co.add_argument("--port", type=int, default=0, help="TCP port (default: any free one)")
    co.set_defaults(func=_emulate_canopen)
    flt = emu_sub.add_parser(
        "fleet",
        help="write nightly identification recordings of N emulated axes over D days "
        "(some drifting, a few damaged) and their truth, fleet.json: test data for many "
        "recordings at once",
    )
    flt.add_argument("--axes", type=int, required=True, help="number of axes")
    flt.add_argument("--days", type=int, required=True, help="number of days, one recording per axis per night")
    flt.add_argument("--out", required=True, help="the fleet folder (fleet.json and one folder per axis)")
    flt.add_argument("--seed", type=int, default=1, help="seed of everything random in the fleet (default 1)")
    flt.add_argument(
        "--duration-s",
        type=float,
        help="analysed length of each recording, s, whole excitation "
        "periods, at most 600 (default: the base's [excitation] duration_s; one lead-in period more is "
        "recorded)",
    )
    flt.add_argument(
        "--drifting-share",
        type=float,
        default=0.3,
        help="share of the axes whose stiffness drifts (default 0.3; at least one axis when there are two or more)",
    )
    flt.add_argument(
        "--sample-rate-hz",
        type=float,
        nargs="+",
        metavar="HZ",
        help="sample rates given to the axes in turn (default: 500 1000 2000)",
    )
    flt.add_argument("--start", default="2026-01-01", help="the first day, YYYY-MM-DD (default 2026-01-01)")
    flt.add_argument(
        "--config",
        help="base configuration: its [emulator.plant] (two_mass), [excitation] "
        "(a multisine in torque) and [identification] (default: the gantry axis of "
        "configs/emulated-gantry.toml without friction)",
    )
    flt.add_argument(
        "--viscous",
        action="store_true",
        help="keep the base's viscous friction (Fv); its Coulomb "
        "and static parts are always dropped (default: no friction)",
    )
    flt.add_argument(
        "--damaged",
        type=int,
        help="number of recordings damaged on purpose (default: about 2 %%, at least 2 from 20 recordings on)",
    )
    flt.add_argument(
        "--overwrite",
        action="store_true",
        help="write into --out even when it holds files (an earlier "
        "fleet's recordings and fleet.json there are removed first)",
    )
    flt.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    flt.set_defaults(func=_emulate_fleet)

    drv = sub.add_parser(
        "drivers", help="list the driver descriptions found; write or check a CANopen driver folder from a vendor EDS"
    )
    drv.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="each driver's channels, rates, modes, filter slots and capabilities",
    )
    drv.set_defaults(func=_drivers)
    drv_sub = drv.add_subparsers(dest="action")
    dnew = drv_sub.add_parser("new", help="write a driver folder from a vendor EDS/DCF (assumed values marked)")
    dnew.add_argument("--eds", required=True, help="the vendor's EDS or DCF file")
    dnew.add_argument("--out", required=True, help="the driver folder to write")
    dnew.add_argument("--name", help="driver name (default: from the EDS file name)")
    dchk = drv_sub.add_parser("check", help="validate a driver folder against its EDS; exit 2 on errors")
    dchk.add_argument("folder", help="the driver folder")
    dchk.add_argument(
        "--no-twin",
        action="store_true",
        help="check against the EDS only; without it, a folder that passes has its filter slot 0 written, read "
        "back, enabled and restored on a throw-away twin of the folder, as hilident run uploads a notch",
    )

    ini = sub.add_parser(
        "init",
        help="write a commented configuration to start from (runs on the emulated twin "
        "as written; keys to check before a real port are marked CHECK)",
    )
    ini.add_argument(
        "--transport",
        choices=("serial", "canopen", "modbus"),
        help="serial board, CANopen CiA 402 drive or Modbus drive (default: the driver's, else serial)",
    )
    ini.add_argument(
        "--driver",
        help="driver name or folder (default: myrio-board, canopen-servo or modbus-servo "
        "for the transport; hilident drivers lists them)",
    )
    ini.add_argument("--out", default="hilident.toml", help="the file to write (default: hilident.toml)")
    ini.add_argument("--overwrite", action="store_true", help="replace --out when it exists")
    ini.set_defaults(func=_init)

    prt = sub.add_parser("ports", help="list the serial ports and CAN channels found, for [device] port")
    prt.add_argument("--no-can", action="store_true", help="serial ports only (skip python-can's detection)")
    prt.set_defaults(func=_ports)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the exit code (see the bench guide, docs/bench-guide.md: 0 success, 2 configuration
    or usage, 3 data, 4 device, 5 safety-limit trip, 128 + signal when a signal ended it: 129 SIGHUP, 130 SIGINT,
    143 SIGTERM)."""
    from hilident import endings
    from hilident.errors import Interrupted

    args = build_parser().parse_args(argv)
    _no_last_resort()
    if args.log_level:
        _configure_logging(args.log_level)
    try:
        if args.command in ("run", "upload", "batch"):
            with endings.signals_end_the_session():
                return args.func(args)
        return args.func(args)
    except HilidentError as exc:
        _say(f"hilident: error: {exc}")
        return exc.exit_code
    except Interrupted as exc:
        endings.ignore_further_signals()
        _say(f"hilident: {exc}; axis stopped, recordings closed as aborted")
        return exc.exit_code
    except KeyboardInterrupt:
        _say("hilident: interrupted; axis stopped")
        return 130
    except BrokenPipeError:
        # the reader of our output went away (e.g. `| head`): the work is done, stay quiet
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


#: Loggers whose records reach stderr only through ``--log-level``: hilident's (a twin's too) and the CAN libraries'.
_LIBRARY_LOGGERS = ("hilident", "canopen", "can")


def _no_last_resort() -> None:
    """Give the library loggers a handler that drops records, so that without ``--log-level`` Python's
    last-resort handler never prints their warnings and tracebacks on the terminal; the records still
    propagate to the handlers ``--log-level`` configures."""
    for name in _LIBRARY_LOGGERS:
        log = logging.getLogger(name)
        if not any(isinstance(h, logging.NullHandler) for h in log.handlers):
            log.addHandler(logging.NullHandler())


def _configure_logging(level: str) -> None:
    """Send the library's log records at ``level`` and above to stderr (``--log-level``)."""
    logging.basicConfig(level=getattr(logging, level.upper()), format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger().setLevel(getattr(logging, level.upper()))


def _say(line: str) -> None:
    """One line on stderr, if anyone still reads it (a closed terminal must not turn an ending into a traceback)."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass
