"""The moves figure: two lines with units, the dwell shaded, the band drawn, the figures in legend and title."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest
from matplotlib.patches import Polygon, Rectangle

from hilident.errors import DataError
from hilident.motion.residual import compare_moves
from hilident.plots.moves import moves_figure, plot_moves, signal_scale

FS = 2000.0
WHEN = dt.datetime(2026, 11, 23, 22, 10, tzinfo=dt.UTC)


def _move(amplitude, end_s):
    t = np.arange(0.0, end_s + 1.5, 1.0 / FS)
    tau = t - end_s
    ring = np.where(tau >= 0, amplitude * np.exp(-6.0 * tau) * np.sin(2 * np.pi * 21.8 * tau + 1.0), 0.0)
    return t, 0.2 + ring


@pytest.fixture
def figure():
    ta, ya = _move(40e-6, 0.8)
    tb, yb = _move(4e-6, 1.05)
    c = compare_moves((ta, ya, 0.8), (tb, yb, 1.05), 1.0)
    fig = moves_figure(
        c,
        ta,
        ya,
        tb,
        yb,
        signal_name="load deflection (laser)",
        subject="configs/gantry.toml",
        when=WHEN,
        added_delay_s=0.25,
    )
    fig.canvas.draw()
    return fig, c


def test_two_moves_with_units_and_the_reduction_in_the_title(figure):
    fig, c = figure
    ax = fig.axes[0]
    assert ax.get_xlabel() == "time after the set-point's end [s]"
    assert ax.get_ylabel() == "load deflection (laser), deviation from its final value [µm]"
    title = ax.get_title()
    assert title.startswith("Move: gantry.toml, 2026-11-23 22:10 UTC")
    assert f"{c.rms_reduction_db:.1f} dB (RMS)" in title and "20.0 dB" in title
    moves = [ln for ln in ax.get_lines() if ln.get_label().startswith(("without notch", "with notch"))]
    assert [ln.get_label().split(":")[0] for ln in moves] == ["without notch", "with notch"]
    # drawn in µm around the final value: the first swing of the loud move is about 40 µm
    assert np.nanmax(np.abs(moves[0].get_ydata())) == pytest.approx(c.without.first_peak * 1e6, rel=1e-6)
    assert "RMS" in moves[0].get_label() and "settles in" in moves[0].get_label()
    assert "ends 0.25 s later" in moves[1].get_label()


def test_the_dwell_is_shaded_and_the_band_drawn(figure):
    fig, c = figure
    ax = fig.axes[0]
    dwell = [p for p in ax.patches if isinstance(p, (Polygon, Rectangle)) and p.get_label() == "dwell (measured)"]
    assert len(dwell) == 1
    xs = dwell[0].get_xy()[:, 0] if isinstance(dwell[0], Polygon) else [dwell[0].get_x(), dwell[0].get_width()]
    assert min(xs) == pytest.approx(0.0) and max(xs) == pytest.approx(1.0)
    band = c.without.band * 1e6
    levels = sorted(ln.get_ydata()[0] for ln in ax.get_lines() if ln.get_color() == "tab:green")
    assert levels == pytest.approx([-band, band])
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any(t.startswith("settling band ±") and t.endswith("µm") for t in legend)
    # the legend sits outside the axes, to the right of the data
    box = ax.get_legend().get_window_extent()
    assert box.x0 >= ax.get_window_extent().x1


def test_a_png_is_written(tmp_path, figure):
    _, c = figure
    ta, ya = _move(40e-6, 0.8)
    tb, yb = _move(4e-6, 1.05)
    path = plot_moves(tmp_path / "moves.png", c, ta, ya, tb, yb, when=WHEN)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_units_of_other_signals_and_bad_arrays():
    assert signal_scale("m", 2e-3) == ("mm", 1e-3)
    assert signal_scale("mps2", 5.0) == ("m/s²", 1.0)
    ta, ya = _move(40e-6, 0.8)
    c = compare_moves((ta, ya, 0.8), (ta, 0.5 * ya, 0.8), 1.0)
    with pytest.raises(DataError, match="with notch signal"):
        moves_figure(c, ta, ya, ta, ya[:-3])


def test_the_shaped_moves_are_drawn_beside_the_two_with_their_reduction_on_a_line_of_its_own():
    from hilident.motion.residual import residual_vibration

    ta, ya = _move(40e-6, 0.8)
    tb, yb = _move(4e-6, 1.05)
    tc, yc = _move(2e-6, 0.85)
    c = compare_moves((ta, ya, 0.8), (tb, yb, 1.05), 1.0)
    r = residual_vibration(tc, yc, 0.85, 1.0, band=c.without.band)
    fig = moves_figure(c, ta, ya, tb, yb, when=WHEN, shaped=(("scheduled shaper", tc, yc, r, 0.05),))
    ax = fig.axes[0]
    labels = [ln.get_label() for ln in ax.get_lines()]
    (shaped,) = [label for label in labels if label.startswith("scheduled shaper:")]
    assert "ends 0.05 s later" in shaped
    title_lines = ax.get_title().splitlines()
    expected = f"{20 * np.log10(c.without.rms / r.rms):.1f} dB (RMS) with the scheduled shaper"
    assert title_lines[-1] == expected and "with the notch" in title_lines[-2]
