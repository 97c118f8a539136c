"""`hilident export`: the plant model, grey-box parameters and notches as JSON, MATLAB .mat and python-control.

The acceptance: each exported form of the model (transfer function and state space) reproduces the frequency
response of summary.json's model to 1e-9 relative.
"""

from __future__ import annotations

import json
import re
import runpy
import sys

import numpy as np
import pytest
from scipy import signal
from scipy.io import loadmat

from hilident.cli.main import main
from hilident.io import export
from support.exported_summaries import load, summaries

RTOL = 1e-9
MATLAB_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,62}$")


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    return summaries(tmp_path_factory.mktemp("summaries"))


def grid(summary: dict) -> np.ndarray:
    """Frequencies to compare on, Hz: the fitted band, log-spaced, and a decade either side."""
    lo, hi = summary["plant_model"]["band_hz"]
    return np.geomspace(lo / 10, hi * 10, 400)


def ss_response(a, b, c, d, s: np.ndarray) -> np.ndarray:
    """``C (sI - A)^-1 B + D`` at each complex ``s`` (or ``z``)."""
    a, b, c, d = (np.atleast_2d(np.asarray(m, dtype=float)) for m in (a, b, c, d))
    eye = np.eye(a.shape[0])
    return np.array([(c @ np.linalg.solve(x * eye - a, b) + d)[0, 0] for x in s])


def tf_response(num, den, s: np.ndarray) -> np.ndarray:
    return np.polyval(np.ravel(num), s) / np.polyval(np.ravel(den), s)


def rel_error(got: np.ndarray, want: np.ndarray) -> float:
    return float(np.max(np.abs(got - want) / np.abs(want)))


def cli_export(folder, fmt: str, *extra: str) -> int:
    return main(["export", str(folder), "--format", fmt, *extra])


@pytest.mark.parametrize("kind", ["run", "identify", "upload"])
def test_json_tf_and_state_space_reproduce_the_summary_response(made, kind, capsys):
    out = made[kind] / "exported.json"
    assert cli_export(made[kind], "json", "--out", str(out)) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    doc = json.loads(out.read_text())
    # an upload's summary has no model of its own: the export takes it from the source summary it names
    source = load(made["identify"]) if kind == "upload" else load(made[kind])
    f = grid(source)
    want = export.model_response(source, f)
    s = 2j * np.pi * f
    cont = doc["plant"]["continuous"]
    assert rel_error(tf_response(cont["tf"]["num"], cont["tf"]["den"], s), want) < RTOL
    assert rel_error(ss_response(*(cont["ss"][m] for m in "ABCD"), s), want) < RTOL
    assert doc["plant"]["input_unit"] == "N*m" and doc["plant"]["output_unit"] == "m/s"
    assert doc["plant"]["units"]["response"] == "(m/s)/(N*m)"
    assert doc["source_kind"] == kind


def test_the_reference_response_is_the_summarys_own_polynomials(made):
    summary = load(made["identify"])
    f = grid(summary)
    pm = summary["plant_model"]
    # the fitted model's zero-pole form (summary.json's roots) gives the same response as num/den
    zeros = np.array([complex(*z) for z in pm["zeros_rad_s"]])
    poles = np.array([complex(*p) for p in pm["poles_rad_s"]])
    s = 2j * np.pi * f
    lead = pm["num"][next(i for i, c in enumerate(pm["num"]) if c != 0)] / pm["den"][0]
    zpk = lead * np.prod(s[:, None] - zeros, axis=1) / np.prod(s[:, None] - poles, axis=1)
    assert rel_error(export.model_response(summary, f), zpk) < 1e-6


def test_discretised_at_the_drives_loop_rate_with_a_zero_order_hold(made):
    summary = load(made["run"])
    doc = export.export_document(summary, path=made["run"] / "summary.json")
    disc = doc["plant"]["discrete"]
    rate = summary["notch_filters"][0]["sample_rate_hz"]
    assert disc["sample_rate_hz"] == rate == 4000.0 and disc["dt_s"] == 1 / rate and disc["method"] == "zoh"
    assert "notch_filters" in disc["rate_source"]
    # zero-order hold maps every pole p to exp(p dt)
    poles = np.array([complex(*p) for p in summary["plant_model"]["poles_rad_s"]])
    got = np.sort_complex(np.linalg.eigvals(np.asarray(disc["ss"]["A"])))
    assert np.allclose(got, np.sort_complex(np.exp(poles * disc["dt_s"])), rtol=1e-9, atol=1e-12)
    # the discrete TF and SS are one system; its polynomial loses digits near z = 1 (module docstring)
    f = np.geomspace(2.0, 400.0, 200)
    z = np.exp(2j * np.pi * f / rate)
    ss = ss_response(*(disc["ss"][m] for m in "ABCD"), z)
    assert rel_error(tf_response(disc["tf"]["num"], disc["tf"]["den"], z), ss) < 1e-4
    # and well below the loop rate it is the continuous model (ZOH: a half-sample delay)
    low = f < 100.0
    cont = export.model_response(summary, f[low])
    assert rel_error(ss[low] * np.exp(1j * np.pi * f[low] / rate), cont) < 0.01
    # --rate-hz discretises elsewhere
    at_1k = export.export_document(summary, rate_hz=1000.0)["plant"]["discrete"]
    assert at_1k["sample_rate_hz"] == 1000.0 and at_1k["rate_source"] == "given (--rate-hz)"


def test_an_upload_takes_its_rate_from_the_device_it_reported(made):
    doc = export.export_document(load(made["upload"]), path=made["upload"] / "summary.json")
    assert doc["plant"]["discrete"]["rate_source"].startswith("device.loop_rate_hz")


def test_notches_as_designed_and_as_stored(made):
    run = load(made["run"])
    notches = export.export_document(run)["notches"]
    (designed,) = notches["designed"]
    (design,) = run["notch_filters"]
    assert designed["b"] == design["b"] and designed["a"] == design["a"]
    assert designed["sample_rate_hz"] == 4000.0 and designed["center_hz"] == design["center_hz"]
    (stored,) = notches["stored"]
    (slot,) = run["upload"]["slots"]
    assert stored["b"] == slot["readback_b"] and stored["a"] == slot["readback_a"]
    assert stored["b"] != designed["b"]  # the board stores REAL32: what it holds is not the float64 design
    assert stored["sample_rate_hz"] == 4000.0 and stored["slot"] == slot["slot"]
    assert notches["units"]["sample_rate_hz"] == "Hz"
    assert export.export_document(load(made["identify"]))["notches"]["stored"] == []  # identify uploads nothing


def test_greybox_parameters_with_standard_deviations_and_units(made):
    summary = load(made["identify"])
    greybox = export.export_document(summary)["greybox"]
    assert greybox["kind"] == "rigid_axis"
    assert greybox["params"] == summary["model"]["params"] and greybox["stderr"] == summary["model"]["stderr"]
    assert greybox["units"]["M"] == "kg" and greybox["units"]["Fv"] == "N/(m/s)" and greybox["units"]["Fc"] == "N"


def walk_struct(value, path="", names=None):
    """Every field name of a loadmat struct (``squeeze_me``, ``struct_as_record=False``), with its path."""
    names = [] if names is None else names
    if hasattr(value, "_fieldnames"):
        for name in value._fieldnames:
            names.append(f"{path}.{name}")
            walk_struct(getattr(value, name), f"{path}.{name}", names)
    return names


def test_mat_loads_with_scipy_as_matlab_structs_that_reproduce_the_response(made, tmp_path):
    out = tmp_path / "model.mat"
    assert cli_export(made["run"], "mat", "--out", str(out)) == 0
    mat = loadmat(out, squeeze_me=True, struct_as_record=False)
    assert {"plant", "greybox", "notches_designed", "notches_stored", "info"} <= set(mat)
    plant = mat["plant"]
    summary = load(made["run"])
    f = grid(summary)
    want = export.model_response(summary, f)
    s = 2j * np.pi * f
    tf, ss = plant.continuous.tf, plant.continuous.ss
    assert tf.num.dtype == np.float64 and ss.A.dtype == np.float64
    assert rel_error(tf_response(tf.num, tf.den, s), want) < RTOL
    n = len(tf.den) - 1  # squeeze_me flattened B (n x 1) and C (1 x n)
    assert ss.A.shape == (n, n)
    assert rel_error(ss_response(ss.A, ss.B.reshape(n, 1), ss.C.reshape(1, n), ss.D, s), want) < RTOL
    assert plant.discrete.sample_rate_hz == 4000.0 and plant.output_unit == "m/s"
    raw = loadmat(out)["plant"]["continuous"][0, 0]["ss"][0, 0]  # as MATLAB sees it: B a column, C a row
    assert [raw[m][0, 0].shape for m in "ABCD"] == [(n, n), (n, 1), (1, n), (1, 1)]
    designed = mat["notches_designed"]
    assert np.array_equal(np.atleast_2d(designed.b)[0], summary["notch_filters"][0]["b"])
    assert np.array_equal(np.atleast_2d(mat["notches_stored"].a)[0], summary["upload"]["slots"][0]["readback_a"])
    assert mat["greybox"].units.M == "kg"
    names = [
        n
        for var in ("plant", "greybox", "notches_designed", "notches_stored", "info")
        for n in walk_struct(mat[var], var)
    ]
    assert len(names) > 30
    assert all(MATLAB_NAME.match(n.rsplit(".", 1)[-1]) for n in names), [
        n for n in names if not MATLAB_NAME.match(n.rsplit(".")[-1])
    ]


def test_mat_renames_parameters_that_are_not_matlab_names(tmp_path):
    summary = {
        "notch_filters": [],
        "upload": {"slots": []},
        "model": {
            "kind": "rigid_axis",
            "params": {"M": 2.0, "Fv+": 3.0, "Fv-": 5.0, "Fc+": 1.0, "Fc-": 1.5},
            "stderr": {"M": 0.1, "Fv+": 0.2, "Fv-": 0.3, "Fc+": 0.1, "Fc-": 0.1},
        },
    }
    export.write_mat(export.export_document(summary), tmp_path / "m.mat")
    greybox = loadmat(tmp_path / "m.mat", squeeze_me=True, struct_as_record=False)["greybox"]
    assert greybox.params.Fv_pos == 3.0 and greybox.params.Fc_neg == 1.5 and greybox.stderr.Fv_neg == 0.3
    assert greybox.units.Fv_pos == "N/(m/s)"


def test_python_control_objects_round_trip(made):
    control = pytest.importorskip("control")
    summary = load(made["identify"])
    models = export.to_control(summary)
    assert isinstance(models["tf"], control.TransferFunction) and isinstance(models["ss"], control.StateSpace)
    f = grid(summary)
    want = export.model_response(summary, f)
    s = 2j * np.pi * f
    assert rel_error(np.ravel(models["tf"](s)), want) < RTOL
    assert rel_error(np.ravel(models["ss"](s)), want) < RTOL
    assert models["ss_discrete"].dt == 1 / 4000.0 and models["tf_discrete"].dt == 1 / 4000.0
    z = np.exp(s / 4000.0)
    assert (
        rel_error(
            np.ravel(models["ss_discrete"](z)),
            ss_response(
                *signal.cont2discrete(
                    signal.tf2ss(summary["plant_model"]["num"], summary["plant_model"]["den"]), 1 / 4000.0, "zoh"
                )[:4],
                z,
            ),
        )
        < RTOL
    )


def test_python_control_script_rebuilds_the_same_objects(made, tmp_path):
    pytest.importorskip("control")
    out = tmp_path / "plant.py"
    assert cli_export(made["run"], "python-control", "--out", str(out)) == 0
    built = runpy.run_path(str(out))
    summary = load(made["run"])
    f = grid(summary)
    want = export.model_response(summary, f)
    assert rel_error(np.ravel(built["tf"](2j * np.pi * f)), want) < RTOL
    assert rel_error(np.ravel(built["ss"](2j * np.pi * f)), want) < RTOL
    direct = export.to_control(summary)
    assert np.array_equal(built["ss_discrete"].A, direct["ss_discrete"].A) and built["dt"] == 1 / 4000.0


def test_default_file_lands_beside_the_summary(made):
    assert cli_export(made["identify"], "json") == 0
    assert json.loads((made["identify"] / "model.json").read_text())["format"] == "hilident-model-export"


def test_python_control_missing_is_a_usage_error_naming_the_extra(made, monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "control", None)  # import control raises ImportError
    assert cli_export(made["run"], "python-control", "--out", str(tmp_path / "p.py")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'hilident[control]'" in err[0]
    assert not (tmp_path / "p.py").exists()


def test_bad_sources_are_one_clear_line(tmp_path, capsys, made):
    assert cli_export(tmp_path / "nowhere", "json") == 3
    assert "nowhere: no summary.json there" in capsys.readouterr().err
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "summary.json").write_text("{not json")
    assert cli_export(tmp_path / "broken", "json") == 3
    assert "cannot be read as a summary.json" in capsys.readouterr().err
    (tmp_path / "nomodel").mkdir()
    (tmp_path / "nomodel" / "summary.json").write_text(json.dumps({"notch_filters": [], "upload": {"slots": []}}))
    assert cli_export(tmp_path / "nomodel", "python-control") == 3
    assert "no plant_model" in capsys.readouterr().err
    assert cli_export(made["run"], "json", "--rate-hz", "-5") == 2
    assert "--rate-hz -5" in capsys.readouterr().err
    assert cli_export(made["run"], "json", "--out", str(tmp_path)) == 2
    assert "is a folder" in capsys.readouterr().err


def test_the_documented_export_commands_run(made, tmp_path, monkeypatch):
    import shlex
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "export.md").read_text()
    block = page.split("```sh", 1)[1].split("```", 1)[0]
    commands = [shlex.split(line, comments=True) for line in block.splitlines() if line.startswith("hilident export")]
    assert [c[4] for c in commands] == ["mat", "json", "python-control"]
    monkeypatch.chdir(tmp_path)  # runs/gantry and plant.json relative to here
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "gantry").symlink_to(made["run"], target_is_directory=True)
    for argv in commands:
        assert main(argv[1:]) == 0, argv
    assert loadmat(tmp_path / "runs" / "gantry" / "model.mat")["plant"].dtype.names
    assert json.loads((tmp_path / "plant.json").read_text())["plant"]["discrete"]["sample_rate_hz"] == 4000.0
    assert "ss_discrete = control.ss(" in (made["run"] / "model_control.py").read_text()
