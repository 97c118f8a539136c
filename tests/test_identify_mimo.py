"""`hilident identify` with several inputs and outputs ([data] inputs, outputs): every output against every input
at once, the modes every output sees from the mode indicator, correlated inputs named, bad lists refused."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from hilident.errors import DataError
from hilident.pipeline.mimo_identify import MODAL_ORDERS, welch_segment
from support.schema_check import schema_errors
from test_identify_data_keys import identify

FS = 500.0
MODES = ((37.0, 0.01), (81.0, 0.01))  # Hz, damping ratio
SHAPES = np.array([[1.0, 0.6], [0.4, -1.0], [-0.8, 0.5]])  # three outputs' participation in each mode
DRIVES = np.array([[1.0, 0.3], [0.5, -1.0]])  # two inputs' drive of each mode
KEYS = '[data]\ninputs = ["f1", "f2"]\noutputs = ["a1", "a2", "a3"]\noutput_units = ["m/s^2", "m/s^2", "m/s^2"]\n'


def structure(correlated: bool = False, seconds: float = 80.0, seed: int = 2) -> np.ndarray:
    """Two force columns of white noise through two lightly damped modes to three outputs, and a little noise."""
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    u = rng.standard_normal((n, 2))
    if correlated:
        u[:, 1] = u[:, 0] + 0.02 * rng.standard_normal(n)  # the second shaker follows the first
    y = np.zeros((n, 3))
    for r, (f, z) in enumerate(MODES):
        w = 2 * np.pi * f
        b, a, _ = signal.cont2discrete(([w * w], [1, 2 * z * w, w * w]), 1 / FS, method="zoh")
        modal = signal.lfilter(b.ravel(), a, u @ DRIVES[:, r])
        y += np.outer(modal, SHAPES[:, r])
    y += 0.01 * np.std(y) * rng.standard_normal(y.shape)
    return np.column_stack([u, y])


def _write(tmp_path, table: np.ndarray):
    data = tmp_path / "structure.csv"
    header = "f1,f2,a1,a2,a3"
    np.savetxt(data, table, delimiter=",", header=header, comments="", fmt="%.9g")
    return data


def test_every_output_against_both_inputs_finds_the_modes_all_outputs_see(tmp_path):
    data = _write(tmp_path, structure())
    code, summary = identify(tmp_path, data, KEYS + f"sample_rate_hz = {FS}\n")
    assert code == 0, summary and summary.get("error")
    assert schema_errors(summary) == []
    mimo = summary["mimo"]
    assert [o["unit"] for o in mimo["outputs"]] == ["m/s^2"] * 3 and len(mimo["inputs"]) == 2
    assert min(mimo["multiple_coherence_median"]) > 0.95  # both inputs together explain every output
    assert mimo["input_condition_median"] < 1.5 and mimo["warnings"] == []
    found = sorted(p["frequency_hz"] for p in mimo["indicator_peaks"])
    for f, _ in MODES:
        assert any(abs(g - f) / f < 0.01 for g in found), found  # within a 0.5 Hz line
    assert len(found) == len(MODES), found  # nothing where there is no mode
    # the modes from all outputs and inputs at once: frequency, damping and shape over the outputs
    modes = mimo["modes"]
    assert len(modes) == len(MODES), [m["frequency_hz"] for m in modes]
    for m, (f, z), r in zip(modes, MODES, range(len(MODES)), strict=True):
        assert abs(m["frequency_hz"] - f) / f < 0.005 and abs(m["damping_ratio"] - z) / z < 0.15, m
        shape = np.array(m["shape_magnitude"]) * np.exp(1j * np.radians(m["shape_phase_deg"]))
        truth = SHAPES[:, r]
        assert abs(np.vdot(shape, truth)) ** 2 / (np.vdot(shape, shape).real * truth @ truth) > 0.95  # MAC
    assert np.allclose(np.diag(mimo["mode_mac"]), 1.0) and mimo["mode_mac"][0][1] < 0.5
    assert summary["data"]["mapping"] == {
        "inputs[0]": "f1", "inputs[1]": "f2", "outputs[0]": "a1", "outputs[1]": "a2", "outputs[2]": "a3"
    }  # fmt: skip
    assert summary["resonances"] == [] and "several inputs" in summary["notch_skipped_reason"]
    page = (tmp_path / "o" / "report.html").read_text()
    section = page.split('<section id="mimo">')[1].split("</section>")[0]
    assert "a3 [m/s^2]" in section and f"{modes[1]['frequency_hz']:.5g} Hz" in section and "MAC" in section
    check_intervals_and_diagram(tmp_path / "o", mimo, groups=8)


def check_intervals_and_diagram(out, mimo: dict, groups: int) -> None:
    """Each mode's 95 % intervals hold the true frequency and damping; the stabilisation diagram is in the summary,
    drawn, and in the report with the mode-shape table."""
    for m, (f, z) in zip(mimo["modes"], MODES, strict=True):
        assert m["interval_groups"] == groups and m["frequency_std_hz"] > 0 and m["damping_std"] > 0, m
        assert abs(m["frequency_hz"] - f) <= m["frequency_ci95_hz"] < 0.5 * z * f, m  # within the half-power band
        assert abs(m["damping_ratio"] - z) <= m["damping_ci95"] < 0.5 * z, m
    assert any("95 % intervals of the modes" in n for n in mimo["modal_notes"])
    diagram = mimo["stabilisation"]
    n = len(diagram["order"])
    assert n > 0 and all(len(diagram[k]) == n for k in ("frequency_hz", "damping_ratio", "label"))
    assert set(diagram["label"]) <= {"new", "unstable", "frequency", "damping", "vector", "stable"}
    assert "stable" in diagram["label"] and diagram["orders_used"] == list(MODAL_ORDERS)[-6:]
    png = out / "stabilisation.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    page = (out / "report.html").read_text()
    assert 'alt="stabilisation.png"' in page  # the figure, embedded under Plots
    section = page.split('<section id="mimo">')[1].split("</section>")[0]
    assert "stabilisation.png" in section and "Mode shapes over the outputs" in section
    shapes = section.split("Mode shapes over the outputs")[1].split("</table>")[0]
    assert shapes.count("<tr>") == 1 + len(mimo["outputs"]) and shapes.count("∠") == len(mimo["outputs"]) * len(MODES)
    first = mimo["modes"][0]
    assert f"± {first['frequency_ci95_hz']:.2g} Hz" in section


def test_inputs_that_move_together_are_named(tmp_path):
    data = _write(tmp_path, structure(correlated=True))
    code, summary = identify(tmp_path, data, KEYS + f"sample_rate_hz = {FS}\n")
    assert code == 0
    (warning,) = summary["mimo"]["warnings"]
    assert "input 0 and input 1" in warning and warning in summary["warnings"]
    assert summary["mimo"]["input_condition_median"] > 100


def test_lists_that_do_not_fit_are_refused_naming_the_key(tmp_path):
    data = _write(tmp_path, structure(seconds=10.0))
    code, _ = identify(tmp_path, data, '[data]\ninputs = ["f1", "f2"]\n')
    assert code != 0
    for keys, key in (
        ('[data]\ninputs = ["f1"]\n', "data.outputs"),
        (KEYS + "input_scales = [1.0]\n", "data.input_scales"),
        (KEYS + "output_scales = [1.0, -2.0, 1.0]\n", "data.output_scales"),
        ('[data]\ninputs = ["f1"]\noutputs = ["f1"]\n', "data.outputs"),
    ):
        cfg = tmp_path / "bad.toml"
        cfg.write_text(keys)
        from hilident.config.tables import load_config
        from hilident.errors import ConfigError

        try:
            load_config(cfg)
        except ConfigError as exc:
            assert exc.key == key, (keys, exc)
        else:
            raise AssertionError(f"{keys!r} was accepted")


def zippered_structure(periods: int = 6, seed: int = 4) -> np.ndarray:
    """The same structure driven by a zippered multisine (each shaker its own lines), in periodic steady state."""
    from hilident.ident.mimo import zippered_multisine

    period = int(4 * FS)  # 0.25 Hz lines, each input every other one
    u, _ = zippered_multisine(2, period, FS, (5.0, 150.0), seed=seed)
    played = np.tile(u, (periods + 4, 1))
    y = np.zeros((len(played), 3))
    for r, (f, z) in enumerate(MODES):
        w = 2 * np.pi * f
        b, a, _ = signal.cont2discrete(([w * w], [1, 2 * z * w, w * w]), 1 / FS, method="zoh")
        y += np.outer(signal.lfilter(b.ravel(), a, played @ DRIVES[:, r]), SHAPES[:, r])
    keep = slice(4 * period, None)  # the transient has died out
    y = y[keep] + 0.01 * np.std(y) * np.random.default_rng(seed).standard_normal(y[keep].shape)
    return np.column_stack([played[keep], y])


def test_a_zippered_multisine_is_read_at_each_inputs_own_lines_and_gives_the_same_modes(tmp_path):
    data = _write(tmp_path, zippered_structure())
    code, summary = identify(tmp_path, data, KEYS + f"sample_rate_hz = {FS}\nperiod_samples = {int(4 * FS)}\n")
    assert code == 0, summary and summary.get("error")
    mimo = summary["mimo"]
    assert mimo["method"] == "periodic" and mimo["resolution_hz"] == 0.25
    modes = mimo["modes"]
    assert len(modes) == len(MODES), [m["frequency_hz"] for m in modes]
    for m, (f, z) in zip(modes, MODES, strict=True):
        assert abs(m["frequency_hz"] - f) / f < 0.005 and abs(m["damping_ratio"] - z) / z < 0.15, m
    assert schema_errors(summary) == []
    check_intervals_and_diagram(tmp_path / "o", mimo, groups=5)  # the five periods after the first, one a group


def test_a_record_too_short_for_independent_groups_has_jackknife_intervals_that_hold_the_truth(tmp_path):
    data = _write(tmp_path, structure(seconds=20.0))
    code, summary = identify(tmp_path, data, KEYS + f"sample_rate_hz = {FS}\n")
    assert code == 0, summary and summary.get("error")
    assert schema_errors(summary) == []
    mimo = summary["mimo"]
    assert len(mimo["modes"]) == len(MODES)
    assert any("jackknife of" in n for n in mimo["modal_notes"]), mimo["modal_notes"]
    for m, (f, z) in zip(mimo["modes"], MODES, strict=True):
        assert m["interval_groups"] >= 4, m
        assert abs(m["frequency_hz"] - f) <= m["frequency_ci95_hz"] < 0.5 * z * f, m  # within the half-power band
        assert abs(m["damping_ratio"] - z) <= m["damping_ci95"] < 0.5 * z, m
    section = (tmp_path / "o" / "report.html").read_text().split('<section id="mimo">')[1].split("</section>")[0]
    assert "jackknife" in section


def test_the_welch_segment_fits_the_record_and_says_so_when_it_is_not_the_configured_one():
    assert welch_segment(100_000, 2, 1024.0, 2.0) == (2048, "")
    segment, note = welch_segment(8523, 2, 1024.0, 2.0)  # 4 segments per input need 9216 samples of 2 s
    assert segment == 1894 and "needs 9216 samples" in note and "1.85 s used" in note
    segment, note = welch_segment(2048, 2, 1.0, 2.0)  # a rate never published, given as 1 Hz: 2 s is 2 samples
    assert segment == 455 and "is 2 samples at 1 Hz, fewer than 64" in note
    with pytest.raises(DataError, match="record longer"):
        welch_segment(200, 2, 1.0, 2.0)
