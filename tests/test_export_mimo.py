"""`hilident export` of a multi-input identify: the modal model of every channel as one real state space.

(a) The realisation is exact: ``C (sI - A)^-1 B + D`` equals the residue sum to 1e-9 relative at any frequency.
(b) End to end: a two-input, three-output structure with two known modes is identified, exported as JSON, MATLAB
and python-control, and the exported model reproduces the true response near each mode.
"""

from __future__ import annotations

import json
import runpy
from pathlib import Path

import numpy as np
import pytest
from scipy import signal
from scipy.io import loadmat

from hilident.cli.main import main
from hilident.errors import DataError
from hilident.io import export
from hilident.io.mimo_export import modal_response, modal_state_space
from support.schema_check import schema_errors
from test_identify_data_keys import identify
from test_identify_mimo import DRIVES, FS, KEYS, MODES, SHAPES, _write, structure

RTOL = 1e-9
#: Relative error (Frobenius over the 3 x 2 matrix) allowed between the exported model and the true response
#: inside each mode's half-power band. The error is the estimate's, not the export's (the state space is the
#: summary's model to 1e-9, checked too): the modes' half-power half-widths (0.37 and 0.81 Hz) are about one Welch
#: line (0.5 Hz), so the Hann-windowed H1 the modes are fitted to is itself 25-30 % off the truth at the 37 Hz peak;
#: the modal fit, weighting the peak's scattered lines less, lands within 7.6 % (measured, this seed). 12 % leaves
#: room for the last digits of another BLAS, not for swapped inputs or outputs or a transposed A (170-200 % off).
MODEL_RTOL = 0.12


def ss_response(ss: dict, s: np.ndarray) -> np.ndarray:
    """``C (sI - A)^-1 B + D`` of ``ss`` (``A, B, C, D`` lists) at each complex ``s`` (or ``z``): (F, n_out, n_in)."""
    a, b, c, d = (np.atleast_2d(np.asarray(ss[m], dtype=float)) for m in "ABCD")
    eye = np.eye(a.shape[0])
    return np.array([c @ np.linalg.solve(x * eye - a, b) + d for x in s])


def rel_error(got: np.ndarray, want: np.ndarray) -> float:
    """Largest over the frequencies of ``|got - want| / |want|`` (Frobenius norms of each matrix)."""
    return float(np.max(np.linalg.norm(got - want, axis=(1, 2)) / np.linalg.norm(want, axis=(1, 2))))


# --- (a) the realisation ---------------------------------------------------------------------------------------


def random_modes(rng, n_modes: int, n_out: int, n_in: int, rank_one: bool = False):
    fn = np.sort(rng.uniform(5.0, 400.0, n_modes))
    zeta = rng.uniform(0.002, 0.2, n_modes)
    wn = 2 * np.pi * fn
    poles = -zeta * wn + 1j * wn * np.sqrt(1 - zeta**2)
    if rank_one:
        shape = rng.standard_normal((n_modes, n_out)) + 1j * rng.standard_normal((n_modes, n_out))
        part = rng.standard_normal((n_modes, n_in)) + 1j * rng.standard_normal((n_modes, n_in))
        residues = shape[:, :, None] * part[:, None, :] * wn[:, None, None]
    else:
        residues = (rng.standard_normal((n_modes, n_out, n_in)) + 1j * rng.standard_normal((n_modes, n_out, n_in))) * (
            wn[:, None, None]
        )
    return poles, residues


@pytest.mark.parametrize(("n_out", "n_in", "rank_one"), [(3, 2, False), (2, 4, False), (3, 2, True), (1, 1, False)])
def test_state_space_equals_the_residue_sum(n_out, n_in, rank_one):
    rng = np.random.default_rng(n_out * 10 + n_in + rank_one)
    poles, residues = random_modes(rng, 4, n_out, n_in, rank_one)
    upper = rng.standard_normal((n_out, n_in))
    a, b, c, d, modes = modal_state_space(poles, residues, upper)
    # every frequency: log-spaced over three decades, and at each mode's peak and half-power edges
    f = np.concatenate(
        [np.geomspace(0.5, 5000.0, 300), *(np.abs(p) / (2 * np.pi) * np.array([0.99, 1, 1.01]) for p in poles)]
    )
    s = 2j * np.pi * f
    want = modal_response(poles, residues, s, upper=upper)
    assert rel_error(ss_response({"A": a, "B": b, "C": c, "D": d}, s), want) < RTOL
    # real, block diagonal with [[sigma, omega], [-omega, sigma]] per direction of each residue
    per_mode = 2 if rank_one else 2 * min(n_out, n_in)
    assert a.shape == (4 * per_mode, 4 * per_mode) and b.shape == (a.shape[0], n_in) and c.shape == (n_out, a.shape[0])
    assert [m["n_states"] for m in modes] == [per_mode] * 4
    for m, p in zip(modes, poles, strict=True):
        k = m["first_state"]
        assert np.array_equal(a[k : k + 2, k : k + 2], [[p.real, p.imag], [-p.imag, p.real]])
    assert np.allclose(
        np.sort_complex(np.linalg.eigvals(a)), np.sort_complex(np.repeat(np.r_[poles, poles.conj()], per_mode // 2))
    )
    assert np.array_equal(d, upper)


def test_the_residue_sum_without_feedthrough_and_bad_input():
    poles, residues = random_modes(np.random.default_rng(1), 2, 2, 2)
    a, b, c, d, _ = modal_state_space(poles, residues)
    s = 2j * np.pi * np.geomspace(1.0, 1000.0, 50)
    assert (
        not d.any()
        and rel_error(ss_response({"A": a, "B": b, "C": c, "D": d}, s), modal_response(poles, residues, s)) < RTOL
    )
    for bad in ((poles.conj(), residues), (poles, residues[:1]), (poles[:0], residues[:0]), (poles * np.nan, residues)):
        with pytest.raises(DataError):
            modal_state_space(*bad)


# --- (b) identify, then export ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def identified(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("mimo_export")
    code, summary = identify(tmp, _write(tmp, structure()), KEYS + f"sample_rate_hz = {FS}\n")
    assert code == 0, summary and summary.get("error")
    assert schema_errors(summary) == []
    return tmp / "o"


def true_response(f: np.ndarray) -> np.ndarray:
    """The simulated structure's response (F, 3, 2): each mode a zero-order-hold discretised second-order system."""
    h = np.zeros((f.size, 3, 2), dtype=complex)
    for r, (fn, z) in enumerate(MODES):
        w = 2 * np.pi * fn
        b, a, _ = signal.cont2discrete(([w * w], [1, 2 * z * w, w * w]), 1 / FS, method="zoh")
        _, g = signal.freqz(b.ravel(), a, worN=f, fs=FS)
        h += g[:, None, None] * np.outer(SHAPES[:, r], DRIVES[:, r])[None]
    return h


def near_modes() -> np.ndarray:
    """Frequencies inside each true mode's half-power band, Hz."""
    return np.concatenate([fn * np.linspace(1 - z, 1 + z, 21) for fn, z in MODES])


def test_summary_holds_poles_residues_and_residuals(identified):
    mimo = json.loads((identified / "summary.json").read_text())["mimo"]
    assert np.shape(mimo["lower_residual"]) == (3, 2) and np.shape(mimo["upper_residual"]) == (3, 2)
    for mode in mimo["modes"]:
        re, im = mode["pole_rad_per_s"]
        wn = 2 * np.pi * mode["frequency_hz"]
        assert np.isclose(np.hypot(re, im), wn, rtol=1e-12) and np.isclose(-re / wn, mode["damping_ratio"], rtol=1e-12)
        assert np.shape(mode["residue_real"]) == (3, 2) and np.shape(mode["residue_imag"]) == (3, 2)


def test_json_model_reproduces_the_true_response_near_each_mode(identified):
    out = identified / "mimo.json"
    assert main(["export", str(identified), "--format", "json", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    model = doc["mimo_model"]
    assert doc["plant"] is None and model["inputs"] == ["f1", "f2"] and model["outputs"] == ["a1", "a2", "a3"]
    assert model["output_units"] == ["m/s^2"] * 3 and len(model["input_units"]) == 2
    assert len(model["modes"]) == len(MODES) and len(model["state_names"]) == model["n_states"]
    cont = model["continuous"]["ss"]
    assert np.shape(cont["B"]) == (model["n_states"], 2) and np.shape(cont["C"]) == (3, model["n_states"])
    f = near_modes()
    got = ss_response(cont, 2j * np.pi * f)
    assert rel_error(got, true_response(f)) < MODEL_RTOL
    # the state space is the summary's residue sum plus its upper residual, exactly
    mimo = json.loads((identified / "summary.json").read_text())["mimo"]
    poles = [complex(*m["pole_rad_per_s"]) for m in mimo["modes"]]
    residues = [np.array(m["residue_real"]) + 1j * np.array(m["residue_imag"]) for m in mimo["modes"]]
    want = modal_response(poles, residues, 2j * np.pi * f, upper=mimo["upper_residual"])
    assert rel_error(got, want) < RTOL
    # discretised with a zero-order hold at the recording's rate: poles exp(lambda dt)
    disc = model["discrete"]
    assert disc["sample_rate_hz"] == FS and disc["dt_s"] == 1 / FS and disc["method"] == "zoh"
    z = np.sort_complex(np.linalg.eigvals(disc["ss"]["A"]))
    lam = np.linalg.eigvals(cont["A"])
    assert np.allclose(z, np.sort_complex(np.exp(lam / FS)), rtol=1e-12)


def test_rate_hz_sets_the_discretisation_and_single_input_keys_are_untouched(identified, tmp_path):
    out = tmp_path / "m.json"
    assert main(["export", str(identified), "--format", "json", "--out", str(out), "--rate-hz", "2000"]) == 0
    doc = json.loads(out.read_text())
    assert doc["mimo_model"]["discrete"]["dt_s"] == 1 / 2000 and "given" in doc["mimo_model"]["discrete"]["rate_source"]
    assert list(doc)[:8] == [
        "format",
        "format_version",
        "hilident_version",
        "source",
        "source_kind",
        "plant",
        "greybox",
        "notches",
    ]
    siso = {"plant_model": {"num": [2.0], "den": [1.0, 3.0]}, "notch_filters": [], "upload": {"slots": []}}
    assert "mimo_model" not in export.export_document(siso, 1000.0)


def test_a_summary_without_modes_or_residues_exports_no_model_and_says_why(identified):
    summary, path = export.load_summary(identified)
    old = json.loads(json.dumps(summary))
    for mode in old["mimo"]["modes"]:
        del mode["residue_real"]  # as an identify of an older hilident wrote it
    doc = export.export_document(old, None, path)
    assert doc["mimo_model"] is None and "run identify again" in doc["mimo_model_reason"]
    with pytest.raises(DataError, match="run identify again"):
        export.control_script(doc)
    old["mimo"]["modes"] = []
    doc = export.export_document(old, None, path)
    assert doc["mimo_model"] is None and "found no mode" in doc["mimo_model_reason"]


def test_mat_file_loads_with_the_model_names_and_units(identified, tmp_path):
    out = tmp_path / "m.mat"
    assert main(["export", str(identified), "--format", "mat", "--out", str(out)]) == 0
    model = loadmat(out, simplify_cells=True)["mimo_model"]
    assert list(model["inputs"]) == ["f1", "f2"] and list(model["outputs"]) == ["a1", "a2", "a3"]
    assert list(model["output_units"]) == ["m/s^2"] * 3
    cont = model["continuous"]["ss"]
    assert cont["A"].shape == (model["n_states"], model["n_states"]) and cont["D"].shape == (3, 2)
    f = near_modes()
    assert rel_error(ss_response(cont, 2j * np.pi * f), true_response(f)) < MODEL_RTOL
    assert model["discrete"]["ss"]["B"].shape == (model["n_states"], 2)


def test_python_control_script_builds_a_named_mimo_state_space(identified, tmp_path):
    summary, path = export.load_summary(identified)
    doc = export.export_document(summary, None, path)
    script = export.control_script(doc)
    compile(script, "model_control.py", "exec")  # valid Python whether or not python-control is installed
    assert "inputs=['f1', 'f2'], outputs=['a1', 'a2', 'a3']" in script and "mimo_ss_discrete" in script
    control = pytest.importorskip("control")
    out = tmp_path / "model_control.py"
    assert main(["export", str(identified), "--format", "python-control", "--out", str(out)]) == 0
    built = runpy.run_path(str(out))
    sys = built["mimo_ss"]
    assert isinstance(sys, control.StateSpace) and sys.input_labels == ["f1", "f2"]
    assert sys.output_labels == ["a1", "a2", "a3"] and built["mimo_ss_discrete"].dt == 1 / FS
    f = near_modes()
    got = np.moveaxis(sys(2j * np.pi * f), -1, 0)
    assert rel_error(got, true_response(f)) < MODEL_RTOL
    direct = export.to_control(summary, None, path)  # the same objects without the script
    assert direct["mimo_ss"].state_labels == sys.state_labels
    assert rel_error(np.moveaxis(direct["mimo_ss"](2j * np.pi * f), -1, 0), got) < RTOL
