"""Drift verdicts of a fleet's axes: the fleet's definition exactly, intervals that hold, no false flags,
and the drift view and batch report that show them."""

from __future__ import annotations

import datetime as dt
import json
import math
from html.parser import HTMLParser

import numpy as np
import pytest
from matplotlib.colors import to_hex

from hilident.errors import DataError
from hilident.html_report.batch import BATCH_SECTIONS, write_batch_report
from hilident.ident.drift import axis_drifts, drift_trend
from hilident.io.drift_json import write_drift_json
from hilident.plots.drift import FLAGGED_COLOUR, PANELS_PER_FIGURE, drift_figures
from support.report_page import Page, check_self_contained

T0 = dt.datetime(2026, 10, 1, 2, 0, tzinfo=dt.UTC)


def row(axis, day, f_hz, *, status="ok", ci95=0.05, zeta=0.02, path=None, error=""):
    when = T0 + dt.timedelta(days=float(day))
    return {
        "axis": axis,
        "time_utc": when.isoformat().replace("+00:00", "Z"),
        "status": status,
        "frequency_hz": f_hz,
        "frequency_ci95_hz": ci95,
        "damping_ratio": zeta,
        "damping_ci95": 0.002,
        "path": path or f"/fleet/{axis}/{when:%Y%m%d}.h5",
        "error": error,
    }


def series(rng, rate_percent_per_day, days, f0=40.0, noise_hz=0.1):
    return f0 * (1 + rate_percent_per_day / 100 * days) + rng.normal(0.0, noise_hz, days.size)


# --------------------------------------------------------------------------- the definition


def test_rate_is_exactly_the_ols_slope_over_the_intercept_at_the_first_recording():
    rng = np.random.default_rng(7)
    days = np.sort(rng.uniform(0, 30, 25))
    days -= days[0]
    f = series(rng, -0.4, days)
    rows = [row("x", d, v) for d, v in zip(days, f, strict=True)]
    rng.shuffle(rows)  # the order of rows does not matter
    trend = axis_drifts(rows, drift_percent_per_day=0.2)["x"]
    b, a = np.polyfit(days, f, 1)
    assert trend.reference_hz == pytest.approx(a, rel=1e-9)
    assert trend.rate_percent_per_day == pytest.approx(100 * b / a, rel=1e-9)
    assert trend.span_days == pytest.approx(days[-1], abs=1e-6)
    assert trend.n == 25 and trend.flagged


def test_slope_interval_is_the_student_t_interval_of_ordinary_least_squares():
    from scipy import stats

    rng = np.random.default_rng(3)
    days = np.arange(12.0)
    f = series(rng, 0.3, days)
    fit = stats.linregress(days, f)
    t = drift_trend(days, f)
    assert t.slope_stderr_per_day == pytest.approx(fit.stderr, rel=1e-9)
    assert t.p_value == pytest.approx(fit.pvalue, rel=1e-6)
    q = stats.t.ppf(0.975, days.size - 2)
    assert t.rate_ci95_percent_per_day == pytest.approx(100 * q * fit.stderr / fit.intercept, rel=1e-9)


def test_the_rate_recovers_the_truth_within_its_interval_about_95_percent_of_the_time():
    days = np.arange(30.0)
    inside = []
    for seed in range(200):
        t = drift_trend(days, series(np.random.default_rng(seed), -0.5, days))
        inside.append(abs(t.rate_percent_per_day - (-0.5)) <= t.rate_ci95_percent_per_day)
    assert 0.9 <= np.mean(inside) <= 0.99


def test_healthy_axes_are_rarely_flagged_over_many_seeds():
    days = np.arange(30.0)
    # threshold 0: significance alone decides, the worst case for false flags
    flags = [
        drift_trend(days, series(np.random.default_rng(seed), 0.0, days), drift_percent_per_day=0.0).flagged
        for seed in range(200)
    ]
    assert np.mean(flags) < 0.10
    # with a lab's threshold none of them is
    assert not any(
        drift_trend(days, series(np.random.default_rng(s), 0.0, days), drift_percent_per_day=0.1).flagged
        for s in range(200)
    )


def test_tiny_reported_intervals_do_not_make_a_trend_significant():
    rng = np.random.default_rng(11)
    days = np.arange(20.0)
    f = series(rng, 0.0, days, noise_hz=0.3)
    loose = drift_trend(days, f, drift_percent_per_day=0.0, ci95=np.full(days.size, 1.0))
    tight = drift_trend(days, f, drift_percent_per_day=0.0, ci95=np.full(days.size, 1e-6))
    assert tight.p_value == loose.p_value and tight.rate_ci95_percent_per_day == loose.rate_ci95_percent_per_day


def test_a_significant_slope_below_the_threshold_is_not_flagged():
    rng = np.random.default_rng(5)
    days = np.arange(30.0)
    t = drift_trend(days, series(rng, -0.05, days, noise_hz=0.01), drift_percent_per_day=0.2)
    assert t.p_value < 1e-6 and not t.flagged
    assert t.verdict.startswith("significant trend") and "below the 0.2 %/day threshold" in t.verdict
    steep = drift_trend(days, series(rng, -0.3, days, noise_hz=0.01), drift_percent_per_day=0.2)
    assert steep.flagged and steep.verdict.startswith("flagged")


def test_a_rising_resonance_is_flagged_too():
    days = np.arange(15.0)
    t = drift_trend(days, series(np.random.default_rng(2), 0.6, days), drift_percent_per_day=0.2)
    assert t.flagged and t.rate_percent_per_day > 0


def test_too_few_recordings_is_insufficient_data_not_a_flag():
    rows = [row("x", d, 40.0 - 2.0 * d) for d in range(4)]
    x = axis_drifts(rows, drift_percent_per_day=0.2, min_recordings=5)["x"]
    assert not x.flagged and x.verdict == "insufficient data: 4 recordings, 5 needed" and x.insufficient
    two = axis_drifts(rows[:2], drift_percent_per_day=0.2)["x"]
    assert two.verdict.startswith("insufficient data") and two.insufficient
    assert not axis_drifts(rows, drift_percent_per_day=0.2, min_recordings=4)["x"].insufficient
    same_time = [row("y", 0.0, 40.0 + i) for i in range(6)]
    assert "same time" in axis_drifts(same_time, drift_percent_per_day=0.2)["y"].verdict


def test_failed_and_unusable_rows_are_counted_and_left_out_of_the_fit():
    rng = np.random.default_rng(1)
    days = np.arange(10.0)
    f = series(rng, -1.0, days)
    rows = [row("x", d, v) for d, v in zip(days, f, strict=True)]
    rows += [
        row("x", 3.5, math.nan, status="failed", error="truncated file"),
        row("x", 4.5, math.nan),  # ok, but no resonance found
        {**row("x", 5.5, 99.0), "time_utc": "not a time"},  # ok, but no readable time
        row("z", 1.0, math.nan, status="failed", error="unreadable"),
    ]
    drifts = axis_drifts(rows, drift_percent_per_day=0.2)
    assert list(drifts) == ["x", "z"]
    x, z = drifts["x"], drifts["z"]
    assert (x.n, x.n_failed, x.n_unusable) == (10, 1, 2)
    b, a = np.polyfit(days, f, 1)
    assert x.rate_percent_per_day == pytest.approx(100 * b / a, rel=1e-9)
    assert (z.n, z.n_failed) == (0, 1) and not z.flagged and z.verdict.startswith("insufficient data")


def test_an_outlier_is_listed_with_its_file_and_kept_in_the_fit():
    rng = np.random.default_rng(4)
    days = np.arange(20.0)
    f = series(rng, 0.0, days, noise_hz=0.05)
    f[7] += 2.0
    rows = [row("x", d, v, path=f"/fleet/x/{i}.h5") for i, (d, v) in enumerate(zip(days, f, strict=True))]
    x = axis_drifts(rows, drift_percent_per_day=0.2)["x"]
    assert x.n == 20
    (out,) = [o for o in x.outliers if o.quantity == "frequency"]
    assert out.path == "/fleet/x/7.h5" and out.value == pytest.approx(f[7]) and out.robust_sigmas > 4


def test_damping_trend_is_reported_and_never_flags():
    rng = np.random.default_rng(8)
    days = np.arange(20.0)
    zeta = 0.02 * (1 + 0.02 * days) + rng.normal(0, 1e-5, days.size)  # +2 %/day
    rows = [row("x", d, 40.0 + rng.normal(0, 0.05), zeta=z) for d, z in zip(days, zeta, strict=True)]
    x = axis_drifts(rows, drift_percent_per_day=0.2)["x"]
    assert x.damping_rate_percent_per_day == pytest.approx(2.0, rel=0.05)
    assert x.damping_p_value < 1e-6 and not x.flagged


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(drift_percent_per_day=-1.0),
        dict(drift_percent_per_day=0.2, confidence=1.0),
        dict(drift_percent_per_day=0.2, min_recordings=2),
    ],
)
def test_settings_out_of_range_are_refused(kwargs):
    with pytest.raises(DataError):
        axis_drifts([row("x", 0, 40.0)], **kwargs)


def test_an_identified_row_without_an_axis_is_refused_naming_its_file():
    with pytest.raises(DataError, match="/fleet/lost.h5"):
        axis_drifts([{**row("x", 0, 40.0), "axis": "", "path": "/fleet/lost.h5"}], drift_percent_per_day=0.2)


@pytest.mark.parametrize("axis", [None, "", math.nan])
def test_a_failed_row_without_an_axis_belongs_to_no_axis(axis):
    rows = [row("x", d, 40.0) for d in range(5)] + [{**row("x", 0, math.nan, status="failed"), "axis": axis}]
    drifts = axis_drifts(rows, drift_percent_per_day=0.2)
    assert list(drifts) == ["x"] and drifts["x"].n_failed == 0


# --------------------------------------------------------------------------- the fleet, its view and report


def fleet_rows(axes=14, days=20, drifting=(1, 6, 11)):
    rng = np.random.default_rng(21)
    rows = []
    for a in range(axes):
        rate = -0.8 if a in drifting else 0.0
        d = np.arange(float(days))
        for day, f in zip(d, series(rng, rate, d), strict=True):
            rows.append(row(f"axis{a:02d}", day, f))
    rows.append(
        row(
            "axis03",
            2.5,
            math.nan,
            status="failed",
            path="/fleet/axis03/broken.h5",
            error="DataError: /fleet/axis03/broken.h5: truncated HDF5 file",
        )
    )
    return rows


@pytest.fixture(scope="module")
def fleet():
    rows = fleet_rows()
    return rows, axis_drifts(rows, drift_percent_per_day=0.2)


def test_the_fleet_flags_exactly_its_drifting_axes(fleet):
    _, drifts = fleet
    assert [a for a, t in drifts.items() if t.flagged] == ["axis01", "axis06", "axis11"]
    for axis in ("axis01", "axis06", "axis11"):
        assert drifts[axis].rate_percent_per_day == pytest.approx(-0.8, rel=0.1)


def _visible_panels(fig):
    return [ax for ax in fig.axes if ax.get_visible() and ax.get_ylabel() == "resonance [Hz]"]


def test_drift_view_has_one_panel_per_axis_flagged_first_and_marked(fleet):
    _, drifts = fleet
    figures = drift_figures(drifts, title="fleet.toml")
    assert len(figures) == 2
    panels = [_visible_panels(f) for f in figures]
    assert [len(p) for p in panels] == [PANELS_PER_FIGURE, 14 - PANELS_PER_FIGURE]
    titles = [ax.get_title() for p in panels for ax in p]
    assert [t.split(":")[0] for t in titles[:3]] == ["axis01", "axis06", "axis11"]
    for ax in panels[0][:3]:
        assert "FLAGGED" in ax.get_title() and "%/day" in ax.get_title()
        assert to_hex(ax.title.get_color()) == FLAGGED_COLOUR
    for ax in panels[0][3:]:
        assert "FLAGGED" not in ax.get_title() and to_hex(ax.title.get_color()) != FLAGGED_COLOUR
    first = panels[0][0]
    assert first.get_xlabel() == "days since first recording [d]"
    assert {ln.get_label() for ln in first.get_lines()} >= {"trend (least squares)"}
    assert len(first.collections) >= 1  # the trend's band (and the error bars)
    twins = [ax for ax in figures[0].axes if ax.get_ylabel() == "damping ratio [1]"]
    assert len(twins) == PANELS_PER_FIGURE
    assert "3 of 14 flagged" in figures[0].get_suptitle() and "figure 1 of 2" in figures[0].get_suptitle()


class Tables(HTMLParser):
    """Rows of the tables of each section (cells as text)."""

    def __init__(self, text):
        super().__init__(convert_charrefs=True)
        self.rows: dict[str, list[list[str]]] = {}
        self._section = None
        self._row: list[str] | None = None
        self._cell: list[str] | None = None
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        if tag == "section":
            self._section = dict(attrs)["id"]
            self.rows[self._section] = []
        elif tag == "tr":
            self._row = []
        elif tag in ("td", "th"):
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._row is not None and self._cell is not None:
            self._row.append("".join(self._cell).strip())
            self._cell = None
        elif tag == "tr" and self._row is not None:
            self.rows[self._section].append(self._row)
            self._row = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def test_batch_report_lists_flagged_axes_first_and_every_failure(fleet, tmp_path):
    rows, drifts = fleet
    meta = {
        "inputs": ["/fleet/**/*.h5"],
        "config": "configs/fleet.toml",
        "scheduler": "local",
        "workers": 2,
        "wall_time_s": 42.0,
    }
    path = write_batch_report(tmp_path, rows, drifts, meta)
    text = path.read_text(encoding="utf-8")
    page = Page(text)
    assert list(page.sections) == [anchor for anchor, _ in BATCH_SECTIONS]
    check_self_contained(page)
    assert "fleet.toml" in page.sections["run"] and "local" in page.sections["run"]
    assert "3 flagged" in page.sections["run"] and "1 failed" in page.sections["run"]
    tables = Tables(text)
    header, *verdicts = tables.rows["drift"]
    assert header[0] == "axis" and "drift rate (95 %)" in header
    assert [r[0] for r in verdicts[:3]] == ["axis01", "axis06", "axis11"]
    assert all(r[-1].startswith("flagged") for r in verdicts[:3])
    assert not any(r[-1].startswith("flagged") for r in verdicts[3:])
    assert len(verdicts) == 14
    _, *failures = tables.rows["failures"]
    error = "DataError: /fleet/axis03/broken.h5: truncated HDF5 file"
    assert failures == [["/fleet/axis03/broken.h5", "axis03", error]]
    _, *recordings = tables.rows["recordings"]
    assert len(recordings) == len(rows)
    (details,) = page.all("details")
    assert "open" not in details  # 281 rows: folded until asked for
    assert [a["alt"] for a in page.all("img")] == ["drift.png", "drift_2.png"]
    assert (tmp_path / "drift.png").exists() and (tmp_path / "drift_2.png").exists()


def test_batch_report_shows_a_failure_without_an_axis_and_its_error_as_text(tmp_path):
    rows = [row("x", d, 40.0) for d in range(5)]
    rows.append(
        {
            **row(
                "x",
                0,
                math.nan,
                status="failed",
                path="/fleet/<junk>.csv",
                error="<script>alert(1)</script> not a recording",
            ),
            "axis": None,
        }
    )
    path = write_batch_report(tmp_path, rows, axis_drifts(rows, 0.2), {"config": "<b>fleet</b>"}, plots=False)
    page = Page(path.read_text())
    check_self_contained(page)
    assert not page.all("script") and not page.all("b")
    _, *failures = Tables(path.read_text()).rows["failures"]
    assert failures == [["/fleet/<junk>.csv", "—", "<script>alert(1)</script> not a recording"]]


def test_batch_report_without_plots_or_failures_says_so(tmp_path):
    rows = [row("x", d, 40.0 + 0.01 * d) for d in range(6)]
    page = Page(write_batch_report(tmp_path, rows, axis_drifts(rows, 0.2), {}, plots=False).read_text())
    assert "No recording failed" in page.sections["failures"]
    assert "open" in page.all("details")[0]  # six rows: shown unfolded
    assert "not drawn" in page.sections["drift-plots"]
    assert "<script>" not in page.text


def test_drift_json_holds_every_axis_and_the_flagged_ones(fleet, tmp_path):
    _, drifts = fleet
    doc = json.loads(write_drift_json(tmp_path, drifts).read_text())
    assert doc["flagged"] == ["axis01", "axis06", "axis11"]
    assert doc["drift_percent_per_day"] == 0.2 and doc["confidence"] == 0.95
    assert set(doc["axes"]) == set(drifts)
    assert doc["axes"]["axis03"]["n_failed"] == 1
    assert doc["axes"]["axis01"]["rate_percent_per_day"] == pytest.approx(drifts["axis01"].rate_percent_per_day)


def test_the_python_example_of_docs_drift_md_runs_and_flags(capsys):
    from support.doc_blocks import ROOT, fenced_blocks

    (snippet,) = [b.text for b in fenced_blocks(ROOT / "docs" / "drift.md") if b.lang == "python"]
    exec(compile(snippet, "docs/drift.md", "exec"), {})
    assert capsys.readouterr().out.startswith("flagged: -1 ± ")
