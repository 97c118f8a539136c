"""The drive's loop on each transport's gantry twin: margins predicted against the twin's truth, the gains proposed,
uploaded and proven by a closed-loop run, the loop measured by torque injection, the friction's intervals. Run by
hand::

    python bench/loop_tuning.py [--out DIR] [--configs NAME ...] [--driver NAME_OR_FOLDER]

For each shipped gantry config (serial, CANopen, Modbus) two sessions run on its twin:

1. the config as shipped with ``[tuning] upload = true``: the margins of the present gains (without and with the
   notch) predicted from the identified plant against those computed from the twin's own plant and gains, the
   proposal (bandwidth with and without the notch at the same targets), the feed-forward proposed against the
   twin's inertia and friction, the gains written and kept or put back, the closed-loop run's measured response
   and velocity steps against the prediction, the proposal's margins on the twin's own plant;
2. the same with the excitation injected at the torque (``torque_injection``, 2 N*m): the loop measured where the
   injection breaks it against the prediction.

``--driver`` runs the configs' twins behind another driver (``canopen-servo-fixed``: its integral kept as a gain;
a folder ``hilident drivers new`` wrote from a vendor's EDS: its proposed ``[loop]``).

Printed: one table per part, and the friction test's Coulomb and viscous levels with their 95 % intervals against
the twin's truth.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # tests/support: the twin's truth, as the suite computes it
CONFIGS = ("emulated-gantry", "emulated-canopen-gantry", "emulated-modbus-gantry")
GAINS = ("kv_nm_per_mps", "ti_s", "kp_pos_per_s")


def true_figures(cfg, values: dict, notches, loop: str) -> tuple[float, float]:
    """(gain margin dB, phase margin deg) of ``loop`` on the twin's own plant with ``values``."""
    from hilident.control import Cascade, loop_margins
    from hilident.emulator.device import plant_model
    from support.loop_truth import plant_position  # the twin's plant as its loop sees it, exactly

    rate = values["loop_rate_hz"]
    f = np.geomspace(0.5, 0.45 * rate, 6000)
    c = Cascade.from_parameters(values, rate, notches)
    m = loop_margins(f, c.open_loop(f, plant_position(plant_model(cfg.emulator), f, rate), loop))
    return m.gain_margin_db, m.phase_margin_deg


def _session(cfg, out: Path):
    from hilident.session.run import Session

    session = Session(cfg, out)
    started = time.monotonic()
    summary = session.run()
    return session, summary, time.monotonic() - started


def _fmt(x, digits=1) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


def _config(name: str, driver: str | None):
    """The shipped config ``name``, behind ``driver`` when one is given."""
    from hilident.config.tables import load_config

    cfg = load_config(ROOT / "configs" / f"{name}.toml")
    return cfg if driver is None else replace(cfg, device=replace(cfg.device, driver=driver))


def tuned(name: str, out: Path, driver: str | None = None) -> None:
    from hilident.filters.biquad import Biquad
    from hilident.protocol.loop_parameters import FEEDFORWARD, PARAMETERS, POSITION_TERMS

    cfg = _config(name, driver)
    cfg = replace(cfg, tuning=replace(cfg.tuning, upload=True))
    session, summary, took = _session(cfg, out / name)
    loop = summary["loop"]
    tuning = session.emulator.drive.tuning  # as the run left it: with the gains it kept
    up = loop.get("upload") or {}
    values = {n: getattr(tuning, n) for n in (*PARAMETERS, *POSITION_TERMS)} | {"loop_rate_hz": tuning.loop_rate_hz}
    values |= up.get("before") or {}  # the gains the run identified and analysed with
    notches = [Biquad(np.array(n["b"]), np.array(n["a"])) for n in summary["notch_filters"]]
    print(f"\n## {name} ({took:.0f} s)")
    print("| loop | notch | GM predicted / true dB | PM predicted / true deg |")
    print("|---|---|---|---|")
    for lp in ("velocity", "position"):
        for part, filters in (("without_notch", ()), ("with_notch", notches)):
            got = loop[lp][part]
            if got is None:
                continue
            gm, pm = true_figures(cfg, values, filters, lp)
            print(
                f"| {lp} | {part} | {_fmt(got['gain_margin_db'])} / {_fmt(gm)} | "
                f"{_fmt(got['phase_margin_deg'])} / {_fmt(pm)} |"
            )
    t = loop.get("tuning") or {}
    print(f"verdict: {t.get('verdict')}")
    before, after = up.get("before") or {}, up.get("readback") or {}
    print(
        "gains: "
        + ", ".join(
            f"{g} {_fmt(before.get(g), 4)} -> {_fmt(after.get(g), 4)}" for g in (*GAINS, *FEEDFORWARD) if g in after
        )
        + f"; kept {up.get('kept')}"
        + (f" ({up.get('reason')})" if up.get("reason") else "")
    )
    if up.get("uploaded"):
        kept = {**values, **after}
        for lp in ("velocity", "position"):
            gm, pm = true_figures(cfg, kept, notches if up.get("proposal") == "with_notch" else (), lp)
            print(f"  the uploaded gains on the twin's own plant, {lp} loop: GM {_fmt(gm)} dB, PM {_fmt(pm)} deg")
    for key in ("closed_loop_with_friction", "closed_loop"):
        c = up.get(key)
        if c:
            print(
                f"  {key}: {c['lines']} lines ({c['lines_left_out']} left out), max {_fmt(c['max_gain_error_db'], 2)} "
                f"dB at {_fmt(c['max_gain_error_hz'])} Hz, {_fmt(c['max_phase_error_deg'])} deg at "
                f"{_fmt(c['max_phase_error_hz'])} Hz; rms {_fmt(c['rms_gain_error_db'], 2)} dB, "
                f"{_fmt(c['rms_phase_error_deg'])} deg; outside {c['lines_outside']}; bandwidth measured "
                f"{_fmt(c.get('measured_bandwidth_hz'))} / predicted {_fmt(c.get('predicted_bandwidth_hz'))} Hz"
            )
    feedforward(cfg, t.get("feedforward"))
    step = up.get("step")
    if step and "rms_error_percent" in step:
        m, p = step["measured"], step["predicted"]
        print(
            f"  steps +/-{_fmt(step['amplitude_mps'], 4)} m/s, {step['periods']} periods: rms difference "
            f"{_fmt(step['rms_error_percent'], 2)} % of the step (allowed {_fmt(step['tolerance_percent'])} %); "
            f"overshoot measured / predicted {_fmt(m['overshoot_percent'])} / {_fmt(p['overshoot_percent'])} %, "
            f"rise {_fmt(m['rise_time_s'], 3)} / {_fmt(p['rise_time_s'], 3)} s"
        )
    elif step:
        print(f"  steps: {step.get('reason')}")
    friction(cfg, summary)


def feedforward(cfg, proposed) -> None:
    """The feed-forward proposed against the twin's own inertia and friction."""
    if not proposed or not (proposed.get("terms") or proposed.get("left_out")):
        print("  feed-forward: the drive has no terms")
        return
    em = cfg.emulator
    truth = {
        "velocity_feedforward": 1.0,
        "accel_feedforward_nm_per_mps2": (em.plant.m1 + em.plant.m2) / em.plant.c,
        "viscous_feedforward_nm_per_mps": em.friction.Fv,
        "friction_feedforward_nm": em.friction.Fc,
    }
    terms = proposed.get("terms") or {}
    print(
        "  feed-forward proposed / true: "
        + ", ".join(f"{k} {_fmt(v, 4)} / {_fmt(truth[k], 4)}" for k, v in terms.items())
    )
    for k, why in (proposed.get("left_out") or {}).items():
        print(f"  feed-forward {k} left out: {why}")


def friction(cfg, summary) -> None:
    fr = summary.get("friction") or {}
    ci = fr.get("ci95") or {}
    truth = cfg.emulator.friction
    for p in ("Fc", "Fv"):
        value = (fr.get("params") or {}).get(p)
        interval = ci.get(p)
        print(f"  friction {p}: {_fmt(value, 4)} (95 % {interval}) against {getattr(truth, p)}")
    if fr.get("extension"):
        print(f"  friction test: {fr['extension']}")


def injected(name: str, out: Path, driver: str | None = None) -> None:
    cfg = _config(name, driver)
    cfg = replace(cfg, excitation=replace(cfg.excitation, mode="torque_injection", amplitude_nm=2.0))
    _, summary, took = _session(cfg, out / f"{name}-injection")
    m = (summary.get("loop") or {}).get("measured")
    if not m:
        print(f"  {name} torque injection: no measured loop ({took:.0f} s)")
        return
    got, want = m.get("measured") or {}, m["predicted"]
    print(
        f"  torque injection ({took:.0f} s): both loops closed, broken at the torque: PM measured "
        f"{_fmt(got.get('phase_margin_deg'))} / predicted {_fmt(want['phase_margin_deg'])} deg at "
        f"{_fmt(got.get('crossover_hz'), 2)} / {_fmt(want['crossover_hz'], 2)} Hz; Ms "
        f"{_fmt(got.get('sensitivity_peak_db'), 2)} / {_fmt(want['sensitivity_peak_db'], 2)} dB"
    )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", help="keep the runs here (default: a temporary folder)")
    parser.add_argument("--configs", nargs="*", default=list(CONFIGS))
    parser.add_argument("--driver", help="a driver name or folder to run the configs' twins behind")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out or tmp)
        for name in args.configs:
            tuned(name, out, args.driver)
            injected(name, out, args.driver)
    return 0


if __name__ == "__main__":
    sys.exit(main())
