"""Tests of hilident.plots.figures: plots and summary.json."""

from __future__ import annotations

import datetime as dt
import enum
import json
import math
from collections import namedtuple
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from hilident.errors import DataError
from hilident.io.serialise import to_jsonable
from hilident.io.serialise import write_json as write_summary
from hilident.plots.bode import plot_bode
from hilident.plots.figures import plot_timeseries
from hilident.plots.friction import plot_friction

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _assert_png(path: Path) -> None:
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE
    assert len(data) > 10_000  # a drawn figure, not an empty canvas
    # IHDR: width and height of a multi-inch figure at ~100 dpi
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert width > 400 and height > 300
    assert not list(path.parent.glob(f".{path.name}.*.tmp"))  # no temp file left behind


def _two_mass_frf(f_hz: np.ndarray, f_res_hz: float, zeta: float) -> np.ndarray:
    w = 2 * np.pi * f_hz
    wr = 2 * np.pi * f_res_hz
    s = 1j * w
    return (s**2 + 2 * 0.02 * 0.7 * wr * s + (0.7 * wr) ** 2) / (s**2 * (s**2 + 2 * zeta * wr * s + wr**2))


def test_plot_bode_writes_png(tmp_path):
    f = np.linspace(0.0, 500.0, 2001)  # includes the DC bin, dropped on the log axis
    before = SimpleNamespace(
        frequency_hz=f,
        response=_two_mass_frf(np.maximum(f, 1e-3), 80.0, 0.02),
        coherence=np.clip(1 - np.exp(-f / 20), 0, 1),
    )
    b, a = signal.iirnotch(80.0, 5.0, fs=4000.0)
    _, notch = signal.freqz(b, a, worN=f[1:], fs=4000.0)
    after = SimpleNamespace(frequency_hz=f[1:], response=before.response[1:] * notch, coherence=None)
    out = plot_bode(
        tmp_path / "plots" / "bode.png",
        [("before notch", before), ("after notch", after)],
        resonances=[SimpleNamespace(frequency_hz=80.0)],
        notch_response=(f[1:], notch),
        coherence_threshold=0.8,
    )
    assert out == tmp_path / "plots" / "bode.png"
    _assert_png(out)


def test_plot_bode_without_coherence_or_extras(tmp_path):
    f = np.geomspace(1, 100, 50)
    frf = SimpleNamespace(frequency_hz=f, response=1 / (1j * f + 1), coherence=None)
    _assert_png(plot_bode(tmp_path / "b.png", [("plant", frf)]))


@pytest.mark.parametrize(
    "frf, match",
    [
        (SimpleNamespace(frequency_hz=np.arange(1, 11.0), response=np.ones(9, complex), coherence=None), "response"),
        (
            SimpleNamespace(frequency_hz=np.arange(1, 11.0), response=np.ones(10, complex), coherence=np.ones(3)),
            "coherence",
        ),
        (
            SimpleNamespace(frequency_hz=np.zeros(4), response=np.ones(4, complex), coherence=None),
            "no positive frequency",
        ),
    ],
)
def test_plot_bode_rejects_bad_frf(tmp_path, frf, match):
    with pytest.raises(DataError, match=match):
        plot_bode(tmp_path / "x.png", [("plant", frf)])
    assert not (tmp_path / "x.png").exists()


def test_plot_bode_rejects_mismatched_notch_and_empty(tmp_path):
    frf = SimpleNamespace(frequency_hz=np.arange(1, 11.0), response=np.ones(10, complex), coherence=None)
    with pytest.raises(DataError, match="notch_response"):
        plot_bode(tmp_path / "x.png", [("plant", frf)], notch_response=(np.arange(1, 6.0), np.ones(4)))
    with pytest.raises(DataError, match="empty"):
        plot_bode(tmp_path / "x.png", [])


def _stribeck(v, Fc=0.2, Fs=0.35, vs=0.01, delta_s=2.0, Fv=1.5, delta_v=1.0):
    # Thesis eq. 2.13 shape, odd in v.
    return np.sign(v) * (Fc + (Fs - Fc) * np.exp(-(np.abs(v / vs) ** delta_s)) + Fv * np.abs(v) ** delta_v)


def test_plot_friction_writes_png(tmp_path):
    rng = np.random.default_rng(0)
    v = np.concatenate([-np.geomspace(1e-3, 0.3, 15), np.geomspace(1e-3, 0.3, 15)])
    tau = _stribeck(v) + rng.normal(0, 0.01, v.size)
    fit_v = np.linspace(-0.3, 0.3, 601)  # includes v = 0, dropped from the line
    _assert_png(plot_friction(tmp_path / "friction.png", v, tau, fit_v, _stribeck(fit_v), label="axis x"))
    _assert_png(plot_friction(tmp_path / "points_only.png", v, tau))


def test_plot_friction_rejects_mismatch(tmp_path):
    with pytest.raises(DataError, match="torque_nm has 3 values but velocity_mps has 4"):
        plot_friction(tmp_path / "f.png", np.zeros(4), np.zeros(3))
    with pytest.raises(DataError, match="fit_torque_nm"):
        plot_friction(tmp_path / "f.png", np.zeros(4), np.zeros(4), np.zeros(5), np.zeros(6))
    with pytest.raises(DataError, match="both"):
        plot_friction(tmp_path / "f.png", np.zeros(4), np.zeros(4), fit_velocity_mps=np.zeros(5))
    with pytest.raises(DataError, match="empty"):
        plot_friction(tmp_path / "f.png", [], [])


def test_plot_timeseries_writes_png_with_events(tmp_path):
    t = np.arange(50_000) / 1000.0  # long enough to be drawn as an envelope
    channels = {"position": np.sin(t), "torque": np.where(t > 20, np.nan, np.cos(3 * t))}
    events = [{"time_s": 5.0, "kind": "excitation_start"}, SimpleNamespace(time_s=30.0, kind="stop"), 40.0]
    out = plot_timeseries(tmp_path / "ts.png", t, channels, {"position": "m", "torque": "N·m"}, events)
    _assert_png(out)


def test_plot_timeseries_rejects_mismatch(tmp_path):
    t = np.arange(10) / 100.0
    with pytest.raises(DataError, match="channels\\['torque'\\] has 9 values but time_s has 10"):
        plot_timeseries(tmp_path / "t.png", t, {"position": np.zeros(10), "torque": np.zeros(9)}, {})
    with pytest.raises(DataError, match="channels is empty"):
        plot_timeseries(tmp_path / "t.png", t, {}, {})


class Mode(enum.Enum):
    SINE = "sine"


Point = namedtuple("Point", "v_mps tau_nm")


@dataclass
class Notch:
    center_hz: float
    b: np.ndarray
    poles: np.ndarray


def test_to_jsonable_nested_numpy_nan_complex():
    obj = {
        "notches": [Notch(np.float32(80.5), np.array([1.0, -1.9, 1.0]), np.array([0.9 + 0.1j]))],
        "fit": {"Fc": np.float64(0.2), "n": np.int32(7), "ok": np.bool_(True), "bad": np.nan},
        "grid": np.array([[1.0, np.inf], [-np.inf, 2.0]]),
        "point": Point(0.1, 0.3),
        "file": Path("/tmp/run.h5"),
        "mode": Mode.SINE,
        "when": dt.datetime(2024, 5, 1, 12, 0, tzinfo=dt.UTC),
        "tags": {"b", "a"},
        5: (1, 2),
        np.int64(6): None,
    }
    out = to_jsonable(obj)
    assert out == {
        "notches": [{"center_hz": 80.5, "b": [1.0, -1.9, 1.0], "poles": [{"re": 0.9, "im": 0.1}]}],
        "fit": {"Fc": 0.2, "n": 7, "ok": True, "bad": None},
        "grid": [[1.0, None], [None, 2.0]],
        "point": {"v_mps": 0.1, "tau_nm": 0.3},
        "file": "/tmp/run.h5",
        "mode": "sine",
        "when": "2024-05-01T12:00:00+00:00",
        "tags": ["a", "b"],
        "5": [1, 2],
        "6": None,
    }
    # every leaf is a plain Python type: strict JSON accepts it
    json.dumps(out, allow_nan=False)
    assert type(out["fit"]["n"]) is int and type(out["fit"]["ok"]) is bool
    assert type(out["fit"]["Fc"]) is float and type(out["notches"][0]["center_hz"]) is float
    assert to_jsonable(complex(math.nan, 1.0)) == {"re": None, "im": 1.0}


def test_to_jsonable_rejects_unknown_objects():
    with pytest.raises(TypeError, match="object"):
        to_jsonable({"x": object()})


def test_write_summary_round_trip(tmp_path):
    summary = {
        "experiment": "chirp",
        "resonances_hz": np.array([81.2, 240.0]),
        "friction": {"Fc": 0.2, "Fs": np.float64(0.35), "vs": 1e-2},
        "coherence_min": np.nan,
        "zero": 0j + 1,
        "notes": "Δ 3 dB – ok",
    }
    path = write_summary(tmp_path / "out" / "summary.json", summary)
    with open(path, encoding="utf-8") as fh:
        back = json.load(fh)
    assert back == {
        "experiment": "chirp",
        "resonances_hz": [81.2, 240.0],
        "friction": {"Fc": 0.2, "Fs": 0.35, "vs": 0.01},
        "coherence_min": None,
        "zero": {"re": 1.0, "im": 0.0},
        "notes": "Δ 3 dB – ok",
    }
    text = path.read_text(encoding="utf-8")
    assert list(back) == list(summary)  # key order kept, not sorted
    assert '\n  "experiment": "chirp"' in text  # indent 2
    assert list(path.parent.iterdir()) == [path]  # temp file renamed away


def test_write_summary_failure_keeps_previous_file(tmp_path):
    path = write_summary(tmp_path / "summary.json", {"run": 1})
    with pytest.raises(DataError, match="summary.json"):
        write_summary(path, {"run": 2, "bad": object()})
    assert json.loads(path.read_text()) == {"run": 1}
    assert list(tmp_path.iterdir()) == [path]
