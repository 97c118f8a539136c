"""Gains into the drive: refused when unstable, read back, proven by a closed-loop run, put back otherwise."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from tests.support.loop_truth import assert_proposal_keeps_targets_on_the_truth, plant_position

from hilident.config.tables import load_config
from hilident.control import Cascade
from hilident.control.tuning import PRESETS
from hilident.emulator.device import plant_model
from hilident.pipeline import closed_loop
from hilident.pipeline.gain_check import check_gains
from hilident.pipeline.loop_analysis import LoopAnalysis
from hilident.pipeline.loop_plant import SeenPlant
from hilident.session.gain_step import GainStep

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "emulated-canopen-gantry.toml"
RATE = 4000.0


def _truth(cfg, f=None) -> SeenPlant:
    """The twin's own plant as the loop sees it, on a dense grid."""
    f = np.geomspace(0.5, 0.999 * RATE, 8000) if f is None else f
    return SeenPlant(f, plant_position(plant_model(cfg.emulator), f, RATE), "lines", (f[0], f[-1]))


def _cascade(kv=100.0, ti=0.05, kp=20.0) -> Cascade:
    return Cascade(RATE, kv, ti, kp, 400.0, 1000.0, 1)


def test_predicted_setpoint_response_is_the_tick_response_when_every_tick_is_recorded():
    cfg = load_config(CONFIG)
    seen, c = _truth(cfg), _cascade()
    f = np.linspace(2.0, 80.0, 40)
    (got,) = closed_loop.predicted_setpoint_response(c, seen, f, RATE)
    assert np.allclose(got, c.closed_loop(f, seen.at(f)[0], "velocity"), rtol=1e-6)
    (recorded,) = closed_loop.predicted_setpoint_response(c, seen, f, 500.0)  # held over 8 ticks: lags more
    lag = np.degrees(np.angle(recorded / got))
    assert np.all(lag < 0) and abs(lag[-1]) > 10 * abs(lag[0])


def test_gains_that_leave_the_loop_unstable_are_refused_naming_the_margin():
    cfg = load_config(CONFIG)
    seen = _truth(cfg)
    fine = check_gains(_cascade(), seen, PRESETS["medium"])
    assert fine.stable
    wild = check_gains(_cascade(kv=20000.0), seen, PRESETS["medium"])
    assert not wild.stable and wild.meets_targets is False
    worst = wild.worst()
    assert worst["gain_margin_db"] < 0 or worst["phase_margin_deg"] < 0
    assert "velocity loop" in wild.describe() and "margin" in wild.describe()


def test_a_line_is_allowed_its_own_scatter_and_untrusted_lines_are_left_out():
    f = np.array([10.0, 20.0, 30.0])
    predicted = np.ones(3, dtype=complex)
    measured = predicted * 10 ** (np.array([0.5, 3.0, 0.0]) / 20)  # the second line 3 dB off
    tight = closed_loop.compare_closed_loop(f, measured, predicted, (1, 100), 2.0, 10.0)
    assert not tight.within_tolerance and tight.outside.tolist() == [False, True, False]
    scatter = closed_loop.line_scatter(np.array([0.999, 0.5, 0.999]), 4, pooled=1)
    assert scatter[1] > 0.5 > scatter[0]
    many = closed_loop.line_scatter(np.full(300, 0.99), 4)
    assert np.all(many > closed_loop.line_scatter(np.full(3, 0.99), 4)[0])  # more lines, a wider family-wise bound
    widened = closed_loop.compare_closed_loop(f, measured, predicted, (1, 100), 2.0, 10.0, scatter)
    assert widened.within_tolerance
    dropped = closed_loop.compare_closed_loop(f, measured, predicted, (1, 100), 2.0, 10.0, usable=[1, 0, 1])
    assert dropped.within_tolerance and dropped.left_out == 1 and dropped.to_dict()["lines"] == 2


def test_removing_friction_undoes_its_part_of_the_response():
    cfg = load_config(CONFIG)
    seen, c = _truth(cfg), _cascade()
    f = np.linspace(2.0, 80.0, 20)
    t = c.closed_loop(f, seen.at(f)[0], "velocity")
    to_friction = closed_loop.friction_response(c, seen, f)
    friction_over_setpoint = 0.3 * np.exp(1j * f)  # any friction spectrum
    with_friction = t + to_friction * friction_over_setpoint
    assert np.allclose(closed_loop.remove_friction(with_friction, friction_over_setpoint, to_friction), t)


class _Drive:
    """A drive's loop parameters as a host sees them: what was written reads back (float32), a write is logged."""

    def __init__(self, values):
        self.values, self.writes = dict(values), []

    def read_loop(self):
        return dict(self.values)

    def stored_loop(self, values):
        return {k: float(np.float32(v)) for k, v in values.items()}

    def write_loop(self, values):
        self.writes.append(dict(values))
        self.values.update(self.stored_loop(values))


def _step(drive, cfg, proposal_gains, notches=()):
    seen = _truth(cfg)
    analysis = LoopAnalysis({}, (1, 1), (1, 1), "lines", {}, tuning={"without_notch": {"gains": proposal_gains}})
    analysis.seen, analysis.cascade = seen, _cascade()
    warnings: list[str] = []
    progress = SimpleNamespace(step=lambda *a, **k: None)
    return GainStep(drive, cfg, analysis, notches, None, None, None, warnings, progress), warnings


def test_an_unstable_proposal_never_reaches_the_drive():
    cfg = load_config(CONFIG)
    drive = _Drive({"kv_nm_per_mps": 100.0, "ti_s": 0.05, "kp_pos_per_s": 20.0})
    step, warnings = _step(drive, cfg, {"kv_nm_per_mps": 20000.0, "ti_s": 0.05, "kp_pos_per_s": 20.0})
    part = step.run()
    assert drive.writes == [] and not part["uploaded"] and not part["check"]["stable"]
    assert "refused before upload" in part["reason"] and "margin" in warnings[-1]


def test_gains_written_but_not_proven_go_back_when_the_run_ends():
    cfg = load_config(CONFIG)
    old = {"kv_nm_per_mps": 100.0, "ti_s": 0.0625, "kp_pos_per_s": 20.0}  # as a float32 holds them
    drive = _Drive(old)
    step, warnings = _step(drive, cfg, {"kv_nm_per_mps": 150.0, "ti_s": 0.04, "kp_pos_per_s": 22.0})
    step._prove = lambda cascade: (_ for _ in ()).throw(KeyboardInterrupt())  # a signal during the proof
    with pytest.raises(KeyboardInterrupt):
        step.run()
    assert drive.values["kv_nm_per_mps"] == np.float32(150.0)
    step.restore()  # what the run's ending does
    assert drive.read_loop() == old and step.part["restored"] and not step.part["kept"]
    assert "put back" in warnings[-1]
    step.restore()  # only once
    assert len(drive.writes) == 2


@pytest.fixture(scope="module")
def uploaded(tmp_path_factory):
    from hilident.session.run import Session

    cfg = load_config(CONFIG)
    # the notch's own proof (a second identification) is the other tests'; the gains have theirs
    # in simulated time twice the shipped config's (the drive plays and captures its tables: buffered runs)
    cfg = replace(
        cfg,
        tuning=replace(cfg.tuning, upload=True),
        notch=replace(cfg.notch, verify=False),
        emulator=replace(cfg.emulator, time_scale=2 * cfg.emulator.time_scale),
    )
    session = Session(cfg, out_dir=tmp_path_factory.mktemp("gains"))
    summary = session.run()
    return cfg, session, summary


def test_the_gains_uploaded_are_kept_and_the_measured_closed_loop_matches_the_prediction(uploaded):
    cfg, session, summary = uploaded
    part = summary["loop"]["upload"]
    assert part["uploaded"] and part["matches"] and part["kept"], part.get("reason")
    assert part["readback"] == part["expected"] != part["before"]
    check = part["closed_loop"]
    assert check["within_tolerance"] and check["lines"] > 100 and check["lines_left_out"] < check["lines"] / 10, check
    # the feed-forward puts a deep dip at the mode into the set-point response: its lines are the noisiest
    assert abs(check["rms_gain_error_db"]) < 1.0 and abs(check["rms_phase_error_deg"]) < 10.0, check
    assert (Path(session.out) / check["recording"]).is_file()


def test_the_feedforward_proposed_is_the_twins_inertia_and_friction_and_is_uploaded(uploaded):
    cfg, session, summary = uploaded
    proposed = summary["loop"]["tuning"]["feedforward"]
    assert proposed["left_out"] == {}
    terms = proposed["terms"]
    em = cfg.emulator
    assert terms["accel_feedforward_nm_per_mps2"] == pytest.approx((em.plant.m1 + em.plant.m2) / em.plant.c, rel=0.05)
    assert terms["friction_feedforward_nm"] == pytest.approx(em.friction.Fc, rel=0.25)
    assert terms["viscous_feedforward_nm_per_mps"] == pytest.approx(em.friction.Fv, rel=0.25)
    assert terms["velocity_feedforward"] == 1.0
    part = summary["loop"]["upload"]
    assert set(terms) <= set(part["asked"]) and part["kept"]
    # read back from the objects, which answer what the drive's loop runs
    assert part["readback"]["accel_feedforward_nm_per_mps2"] == pytest.approx(terms["accel_feedforward_nm_per_mps2"])


def test_the_velocity_steps_after_the_upload_match_the_prediction(uploaded):
    cfg, session, summary = uploaded
    step = summary["loop"]["upload"]["step"]
    assert step["within_tolerance"] and step["rms_error_percent"] < 5.0 and step["periods"] == 4
    assert step["measured"]["overshoot_percent"] == pytest.approx(step["predicted"]["overshoot_percent"], abs=10)
    assert (Path(session.out) / step["recording"]).is_file()
    assert (Path(session.out) / "closed-loop.png").is_file()


def test_the_closed_loop_measured_lies_within_2_db_and_10_deg_of_the_twins_own(uploaded):
    cfg, session, summary = uploaded
    measured = session.gains.check
    as_read = {**summary["loop"]["parameters"], **session.gains.part["readback"]}
    truth = Cascade.from_parameters(as_read, RATE, session.gains.notches)
    (true_t,) = closed_loop.predicted_setpoint_response(
        truth, _truth(cfg), measured.frequency_hz, cfg.run.sample_rate_hz
    )
    against_truth = closed_loop.compare_closed_loop(
        measured.frequency_hz, measured.measured, true_t, (0, math.inf), 2.0, 10.0, measured.scatter
    )
    assert against_truth.within_tolerance, against_truth.worst()


def test_the_proposal_uploaded_keeps_its_targets_on_the_twins_own_plant(uploaded):
    cfg, session, summary = uploaded
    values = SimpleNamespace(loop_rate_hz=RATE, **summary["loop"]["parameters"])
    assert_proposal_keeps_targets_on_the_truth(summary["loop"], cfg.emulator, values, session.gains.notches)


def _command(uploaded, tmp_path, **kw):
    from hilident.session.gain_upload import GainUploadCommand

    _, session, _ = uploaded
    return GainUploadCommand(load_config(CONFIG), session.out, tmp_path / "up", **kw)


def test_upload_gains_dry_run_checks_and_shows_the_plan_and_writes_nothing(uploaded, tmp_path):
    command = _command(uploaded, tmp_path, dry_run=True)
    result = command.run()
    plan = result["plan"]
    assert result["dry_run"] and plan["check"]["stable"] and plan["before"]["kv_nm_per_mps"] == 100.0
    assert plan["expected"] != plan["before"] and "will hold" in command.describe()
    assert not (tmp_path / "up").exists()


def test_upload_gains_refuses_gains_the_loop_cannot_take_before_writing(uploaded, tmp_path):
    from hilident.errors import UsageError

    command = _command(uploaded, tmp_path, gains={"kv_nm_per_mps": 20000.0})
    with pytest.raises(UsageError, match="refused before upload.*margin.*nothing written"):
        command.run()
    assert not (tmp_path / "up").exists()


def test_upload_gains_writes_reads_back_and_puts_back_on_a_mismatch(uploaded, tmp_path, monkeypatch):
    from hilident.adapters.canopen.drive import CanopenDriveAdapter
    from hilident.errors import DeviceError

    summary = _command(uploaded, tmp_path / "a").run()
    g = summary["gains"]
    assert g["written"] and g["kept"] and g["readback"] == g["expected"] and g["restored"] is None

    stored = CanopenDriveAdapter._stored_loop
    monkeypatch.setattr(  # a drive that keeps other values than its description says
        CanopenDriveAdapter, "_stored_loop", lambda self, v: {k: x * 1.01 for k, x in stored(self, v).items()}
    )
    command = _command(uploaded, tmp_path / "b")
    with pytest.raises(DeviceError, match="read back"):
        command.run()
    g = command.summary["gains"]
    assert g["written"] and not g["kept"] and g["restored"] and command.summary["failed_step"] == "upload"


def test_a_gain_given_on_the_command_line_is_checked_by_name_and_value():
    from hilident.errors import UsageError
    from hilident.session.gain_upload import parse_gain_overrides

    assert parse_gain_overrides(["kv_nm_per_mps=150", "ti_s=inf"]) == {"kv_nm_per_mps": 150.0, "ti_s": math.inf}
    for bad in (["kv=1"], ["current_loop_hz=900"], ["ti_s=fast"], ["kp_pos_per_s=-1"]):
        with pytest.raises(UsageError, match="--gain"):
            parse_gain_overrides(bad)


def test_a_limit_trip_in_the_proof_ends_the_session_with_the_gains_put_back_and_said_so(tmp_path, monkeypatch):
    import json

    from hilident.errors import LimitTrip
    from hilident.session.gain_step import GainStep
    from hilident.session.run import Session

    cfg = load_config(CONFIG)
    cfg = replace(
        cfg,
        tuning=replace(cfg.tuning, upload=True),
        friction_test=replace(cfg.friction_test, enabled=False),
        emulator=replace(cfg.emulator, link="pipe", time_scale=8.0),
    )

    def trip(self, cascade):
        raise LimitTrip("torque_limit: axis stopped, torque zero (the proof's first sample)")

    monkeypatch.setattr(GainStep, "_prove", trip)
    session = Session(cfg, tmp_path, plots=False)
    with pytest.raises(LimitTrip):
        session.run()
    written = json.loads((tmp_path / "summary.json").read_text())
    upload = written["loop"]["upload"]
    assert written["failed_step"] == "gain upload" and upload["uploaded"] and upload["restored"] is True
    assert upload["kept"] is False and "gain upload step ended: torque_limit" in upload["reason"]
    assert session.emulator.drive.tuning.kv_nm_per_mps == upload["before"]["kv_nm_per_mps"]
