"""The emulated drive's plant exactly, as its loop sees it tick by tick: the truth for loop predictions."""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from hilident.emulator.plant import state_matrices


def plant_position(model, frequency_hz, rate_hz: float) -> np.ndarray:
    """Motor torque held over a tick to the encoder position read at the tick's start, m per N·m (exact ZOH)."""
    A, B = state_matrices(model)
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n] = A, B * model.c
    E = expm(M / rate_hz)
    phi, gamma = E[:n, :n], E[:n, n]
    z = np.exp(2j * np.pi * np.asarray(frequency_hz, dtype=float) / rate_hz)
    return np.array([np.linalg.solve(zk * np.eye(n) - phi, gamma)[0] for zk in np.atleast_1d(z)])


def true_loop_figures(emulator_cfg, tuning, notches=(), grid=None) -> dict:
    """The twin's loops exactly, from its own plant and gains: ``{loop: {"without_notch", "with_notch"}:
    LoopFigures}`` as ``summary.json["loop"]`` holds them (with_notch None without notches)."""
    from hilident.control import Cascade, bandwidth_hz, loop_margins
    from hilident.emulator.device import plant_model
    from hilident.pipeline.loop_analysis import LoopFigures

    f = np.geomspace(0.5, 0.45 * tuning.loop_rate_hz, 6000) if grid is None else grid
    h = plant_position(plant_model(emulator_cfg), f, tuning.loop_rate_hz)
    values = {
        name: getattr(tuning, name, 0.0)  # a position I or D term the tuning does not name is absent
        for name in (
            "kv_nm_per_mps",
            "ti_s",
            "kp_pos_per_s",
            "ki_pos_per_s2",
            "kd_pos",
            "velocity_filter_hz",
            "current_loop_hz",
            "delay_ticks",
        )
    }
    out = {}
    for loop in ("velocity", "position"):
        out[loop] = {}
        for label, filters in (("without_notch", ()), ("with_notch", tuple(notches))):
            if label == "with_notch" and not notches:
                out[loop][label] = None
                continue
            c = Cascade.from_parameters(values, tuning.loop_rate_hz, filters)
            margins = loop_margins(f, c.open_loop(f, h, loop))
            out[loop][label] = LoopFigures(margins, bandwidth_hz(f, c.closed_loop(f, h, loop)))
    return out


def assert_loop_figures_match(summary_loop: dict, truth: dict, db: float = 1.0, deg: float = 5.0) -> None:
    """The predicted margins within ``db`` and ``deg`` of the truth, the sensitivity peak within ``db``."""
    for loop, parts in truth.items():
        for label, true in parts.items():
            got = summary_loop[loop][label]
            if true is None:
                assert got is None, (loop, label)
                continue
            m = true.margins
            assert abs(got["gain_margin_db"] - m.gain_margin_db) < db, (loop, label, got, m)
            assert abs(got["phase_margin_deg"] - m.phase_margin_deg) < deg, (loop, label, got, m)
            assert abs(got["sensitivity_peak_db"] - m.sensitivity_peak_db) < db, (loop, label, got, m)


def assert_proposal_keeps_targets_on_the_truth(summary_loop: dict, emulator_cfg, tuning, notches, db=1.0, deg=5.0):
    """Each proposed set of gains, run on the twin's own plant, keeps the targets (within ``db`` and ``deg``)."""
    from hilident.control import Cascade, loop_margins
    from hilident.emulator.device import plant_model

    part = summary_loop["tuning"]
    targets = part["targets"]
    f = np.geomspace(0.5, 0.45 * tuning.loop_rate_hz, 6000)
    h = plant_position(plant_model(emulator_cfg), f, tuning.loop_rate_hz)
    values = {n: getattr(tuning, n) for n in ("velocity_filter_hz", "current_loop_hz", "delay_ticks")}
    checked = 0
    for label, filters in (("without_notch", ()), ("with_notch", tuple(notches))):
        proposed = part[label]
        if proposed is None:
            continue
        c = Cascade.from_parameters({**values, **proposed["gains"]}, tuning.loop_rate_hz, filters)
        for loop in ("velocity", "position"):
            m = loop_margins(f, c.open_loop(f, h, loop))
            assert m.gain_margin_db >= targets["gain_margin_db"] - db, (label, loop, m)
            assert m.phase_margin_deg >= targets["phase_margin_deg"] - deg, (label, loop, m)
            assert m.sensitivity_peak_db <= 20 * np.log10(targets["sensitivity_peak"]) + db, (label, loop, m)
        checked += 1
    assert checked, "no gains were proposed"
