"""The typed summary: each command's documented keys, in order, from one builder; the run-event log."""

from __future__ import annotations

import json

from hilident.events import Kind, RunEvent, StreamStats
from hilident.io.recording import RunWriter, read_run
from hilident.io.serialise import write_json
from hilident.io.summary import (
    LAYOUTS,
    DevicePart,
    ExcitationPart,
    Summary,
    UploadOutcome,
    VerificationPart,
)


class _Excitation:
    kind, mode, amplitude, closed_loop = "multisine", "torque", 2.0, False


#: Keys only a [map] or [verification] move run has.
WORKSPACE_KEYS = ("map", "workspace", "move_test")
#: Keys a run leaves out without their feature: those, and the drive's loop ([loop] in its driver).
OPTIONAL_KEYS = (*WORKSPACE_KEYS, "loop", "mimo", "input_shaper")  # input_shaper: with resonances only


def _run(**extra) -> Summary:
    return Summary.of_run(
        config="a.toml",
        device=DevicePart("myrio-board", "emulator", True),
        sample_rate_hz=1000.0,
        excitation=ExcitationPart.of(_Excitation(), None),
        plant=None,
        friction=None,
        designs=[],
        upload=UploadOutcome(),
        verification=None,
        stream=StreamStats(),
        connect=None,
        filters_found=[],
        recordings=[],
        elapsed_s=1.0,
        warnings=["w"],
        **extra,
    )


def test_a_run_that_failed_before_its_model_has_no_model_key_and_names_the_step_last():
    out = _run().failed("identification", "boom").to_dict()
    assert list(out) == [k for k in LAYOUTS["run"] if k not in ("model", *OPTIONAL_KEYS)] + ["failed_step", "error"]
    assert out["upload"] == {"written": False, "verified_readback": False, "slots": []}
    assert out["verification"] == {"band_reduction_db": None, "peak_reduction_db": None, "resonances": []}
    assert out["excitation"] == {
        "kind": "multisine",
        "mode": "torque",
        "amplitude": 2.0,
        "unit": "N*m",
        "closed_loop": False,
    }
    assert out["measurement"] is None and out["friction"] is None


def test_a_finished_run_ends_with_its_model_and_a_verification_in_its_documented_order():
    verification = VerificationPart(21.0, 30.0, 2.0, [{"frequency_hz": 20.0}])
    s = _run(model=None)
    s.verification = verification
    out = s.to_dict()
    assert list(out) == [k for k in LAYOUTS["run"] if k not in OPTIONAL_KEYS] and out["model"] is None
    assert list(out["verification"]) == ["band_reduction_db", "peak_reduction_db", "band_bandwidths", "resonances"]


def test_an_identify_has_an_empty_measurement_and_the_data_rows_as_its_stream():
    out = Summary.of_identify(
        config="c",
        data={"samples": 10, "missing_samples": 2},
        plant=None,
        friction=None,
        model=None,
        designs=[],
        notch_skipped_reason=None,
        elapsed_s=0.1,
        warnings=[],
    ).to_dict()
    # mimo: several inputs and outputs only; input_shaper: with resonances only
    assert list(out) == [k for k in LAYOUTS["identify"] if k not in ("mimo", "input_shaper")]
    assert out["measurement"] == {} and out["stream"]["samples"] == 10 and out["stream"]["lost_samples"] == 2


def test_an_upload_keeps_the_optional_upload_keys_in_their_order(tmp_path):
    upload = UploadOutcome(True, True, [], rolled_back=[], saved=True, saved_with="0x1010:1")
    s = Summary.of_upload(
        config="c",
        source={"summary": "s", "kind": "run", "notch_filters": []},
        device=DevicePart.reported("d", "p", False, None),
        filters_before=[],
        designs=[],
        upload=upload,
        elapsed_s=0.2,
        warnings=[],
    )
    out = json.loads(write_json(tmp_path / "summary.json", s.to_dict()).read_text())
    assert list(out) == list(LAYOUTS["upload"])
    assert list(out["upload"]) == ["written", "verified_readback", "slots", "rolled_back", "saved", "saved_with"]
    assert out["device"] == {
        "driver": "d",
        "port": "p",
        "emulated": False,
        "name": None,
        "firmware": None,
        "loop_rate_hz": None,
        "filter_slots": None,
    }


def test_the_recording_logs_typed_events_with_their_fields_in_the_data_column(tmp_path):
    path = tmp_path / "run.h5"
    with RunWriter(path, ["x"], ["m"], 100.0) as writer:
        writer.log(RunEvent(Kind.LIMIT_TRIP, "speed", 5, value=1.5, host_check=True))
        writer.log(RunEvent.from_dict({"kind": "underrun", "message": "3", "sample_index": -1, "value": 3.0}))
    (trip, underrun) = read_run(path).events
    assert (trip["kind"], trip["sample_index"], trip["data"]) == ("limit_trip", 5, {"value": 1.5, "host_check": True})
    assert (underrun["kind"], underrun["sample_index"], underrun["data"]) == ("underrun", 0, {"value": 3.0})


def test_a_map_run_carries_its_map_workspace_and_move_test_last():
    from hilident.session.map_positions import MapPoint

    point = MapPoint(0.1, 0.1004, 21.3, 0.018, 0.03, 0.99, "map_0.h5")
    out = _run(model=None, workspace_map=[point], workspace={"joint_fit": None}, move_test=[]).to_dict()
    assert list(out)[-3:] == list(WORKSPACE_KEYS)
    assert out["map"] == [point.to_dict()] and out["workspace"] == {"joint_fit": None}
    assert out["move_test"] == {"moves": [], "worst_rms_reduction_db": None, "worst_start_m": None}


def test_a_move_test_whose_worst_place_gained_nothing_reports_zero_not_the_best_place():
    from types import SimpleNamespace

    from hilident.io.summary import move_test_summary

    def result(start_m, reduction_db):
        return SimpleNamespace(to_dict=lambda: {"start_m": start_m, "rms_reduction_db": reduction_db})

    summary = move_test_summary([result(-0.5, None), result(0.0, 0.0), result(0.5, 12.0)])
    assert summary["worst_rms_reduction_db"] == 0.0 and summary["worst_start_m"] == 0.0
