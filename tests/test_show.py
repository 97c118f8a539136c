"""``hilident show``: what the figure of a recording holds, and the command around it."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from matplotlib.colors import to_rgba

from hilident.cli.main import main
from hilident.errors import UsageError
from hilident.events import Kind, RunEvent
from hilident.io.recording import RunWriter, read_run
from hilident.plots import show
from support.fresh_recording import TRANSPORT_CONFIGS, record

RATE_HZ = 1000.0
NAMES = ["sample_index", "time_s", "excitation", "torque_nm", "velocity_mps", "position_m", "load_position_m"]
#: As recordings stored them before the excitation had its unit.
OLD_UNITS = ["1", "s", "1", "N*m", "m/s", "m", "m"]
LOST = range(400, 450)  # samples the line lost: no rows for them


def _write(path, n=1000, units=OLD_UNITS, lost=LOST, mode="torque", events=True, status="aborted"):
    """A session-like recording: lost samples, a lost-block, an underrun and a limit-trip event, aborted."""
    index = np.array([i for i in range(n) if i not in lost], dtype=float)
    t = index / RATE_HZ
    rows = np.column_stack(
        [
            index,
            t,
            2.0 * np.sin(2 * np.pi * 5 * t),
            1.5 * np.sin(2 * np.pi * 5 * t + 0.3),
            0.1 * np.cos(2 * np.pi * 5 * t),
            0.01 * t,
            0.011 * t,
        ]
    )
    attrs = {
        "experiment": "identification",
        "mode": mode,
        "config_source": "configs/bench-axis.toml",
        "device": {"name": "myrio-board", "firmware": "hilident-board 1.0", "port": "/dev/ttyUSB0"},
        "versions": {"hilident": "9.9.9"},
    }
    w = RunWriter(path, NAMES, list(units), RATE_HZ, attrs)
    w.append(rows)
    if events:
        w.log(RunEvent(Kind.LOST_BLOCKS, "1 sample block(s) lost", lost.start, value=1.0))
        w.log(RunEvent(Kind.UNDERRUN, "3 underrun samples", 700, value=3.0))
        w.log(RunEvent(Kind.LIMIT_TRIP, "velocity limit 1 m/s crossed: 1.2 m/s", 900, value=1.2))
    if status == "aborted":
        w.close("aborted", "limit trip: velocity limit 1 m/s crossed")
    else:
        w.close(status)
    return path


@pytest.fixture
def recording(tmp_path):
    return _write(tmp_path / "identification.h5")


def _figure(path, channels=None):
    return show.recording_figure(show.load_recording(path), channels)


def _data_lines(ax):
    return {line.get_label(): line for line in ax.get_lines()}


def test_one_axis_per_unit_each_labelled_with_its_unit(recording):
    fig = _figure(recording)
    axes = fig.get_axes()
    assert [ax.get_ylabel() for ax in axes] == ["torque [N·m]", "velocity_mps [m/s]", "position [m]"]
    assert set(_data_lines(axes[0])) == {"excitation", "torque_nm"}  # the old "1" read as the mode's N*m
    assert set(_data_lines(axes[2])) == {"position_m", "load_position_m"}
    assert axes[-1].get_xlabel() == "time [s]"
    assert all(ax.get_xlabel() == "" for ax in axes[:-1])  # one shared time axis
    legend = axes[0].get_legend()
    assert [text.get_text() for text in legend.get_texts()] == ["excitation", "torque_nm"]
    assert "sample_index" not in {label for ax in axes for label in _data_lines(ax)}


def test_excitation_in_velocity_mode_shares_the_velocity_axis(tmp_path):
    fig = _figure(_write(tmp_path / "friction.h5", mode="velocity"))
    labels = {ax.get_ylabel(): set(_data_lines(ax)) for ax in fig.get_axes()}
    assert labels["velocity [m/s]"] == {"excitation", "velocity_mps"}
    assert labels["torque_nm [N·m]"] == {"torque_nm"}


def test_events_are_marked_on_every_axis_by_kind(recording):
    fig = _figure(recording)
    axes = fig.get_axes()
    for ax in axes:  # one line per event on every axis, at its time
        assert len(ax.collections) == 3
        times = sorted(float(seg[0][0]) for c in ax.collections for seg in c.get_segments())
        assert times == pytest.approx([0.4, 0.7, 0.9])
    first = {c.get_label(): c for c in axes[0].collections}
    assert set(first) == {"lost_blocks (1)", "underrun (1)", "limit_trip (1)"}
    assert tuple(first["limit_trip (1)"].get_colors()[0][:3]) == pytest.approx(to_rgba("tab:red")[:3])
    assert tuple(first["lost_blocks (1)"].get_colors()[0][:3]) == pytest.approx(to_rgba("tab:orange")[:3])
    assert tuple(first["underrun (1)"].get_colors()[0][:3]) == pytest.approx(to_rgba("tab:orange")[:3])
    assert first["underrun (1)"].get_linestyle() != first["lost_blocks (1)"].get_linestyle()  # told apart
    legend = fig.legends[0]
    assert legend.get_title().get_text() == "events"
    assert {t.get_text() for t in legend.get_texts()} == {"lost_blocks (1)", "underrun (1)", "limit_trip (1)"}


def test_the_title_names_the_run(recording):
    title = _figure(recording).get_suptitle()
    for part in (
        "identification.h5: identification, mode torque",
        "config configs/bench-axis.toml",
        "device myrio-board hilident-board 1.0 on /dev/ttyUSB0",
        "hilident 9.9.9",
        "1000 Hz",
        "950 samples over 1 s (50 not recorded)",
        "recorded 20",
        " UTC",
        "status aborted: limit trip: velocity limit 1 m/s crossed",
        "events: lost_blocks × 1, underrun × 1, limit_trip × 1",
        "limit_trip at 0.9 s: velocity limit 1 m/s crossed: 1.2 m/s",
    ):
        assert part in title, part


def test_a_crashed_recording_says_so(tmp_path):
    path = tmp_path / "crashed.h5"
    w = RunWriter(path, ["torque_nm"], ["N*m"], RATE_HZ)
    w.append(np.zeros((10, 1)))
    w._file.close()  # the writer died: the file still says "running"
    title = _figure(path).get_suptitle()
    assert "status running (the recording process ended without closing the file" in title


def test_lost_samples_leave_a_gap_in_the_trace(recording):
    line = _data_lines(_figure(recording).get_axes()[1])["velocity_mps"]
    t, y = np.asarray(line.get_xdata()), np.asarray(line.get_ydata())
    gap = np.flatnonzero(np.isnan(y))
    assert gap.size == 1  # one break, where the 50 lost samples are
    assert t[gap[0] - 1] == pytest.approx(0.399) and t[gap[0] + 1] == pytest.approx(0.450)
    assert np.all(np.isfinite(y[: gap[0]])) and np.all(np.isfinite(y[gap[0] + 1 :]))


def test_a_long_recording_is_drawn_as_an_envelope_that_keeps_its_peaks(tmp_path):
    n = 200_000
    path = tmp_path / "long.h5"
    y = np.zeros(n)
    y[123_457] = 5.0  # one sample spike
    with RunWriter(path, ["time_s", "torque_nm"], ["s", "N*m"], RATE_HZ) as w:
        w.append(np.column_stack([np.arange(n) / RATE_HZ, y]))
    line = _data_lines(_figure(path).get_axes()[0])["torque_nm"]
    assert len(line.get_ydata()) <= show.MAX_PLOT_POINTS
    assert np.nanmax(line.get_ydata()) == 5.0


def test_channels_choose_what_is_drawn(recording):
    fig = _figure(recording, ["velocity_mps", "excitation", "velocity_mps"])
    assert [ax.get_ylabel() for ax in fig.get_axes()] == ["velocity_mps [m/s]", "excitation [N·m]"]
    with pytest.raises(UsageError, match=r"no channel 'torque'; its channels: sample_index, time_s, excitation"):
        _figure(recording, ["torque"])


def test_cli_writes_the_png_asked_for(recording, tmp_path, capsys):
    out = tmp_path / "plots" / "run.png"
    assert main(["show", str(recording), "--channels", "excitation, torque_nm", "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert capsys.readouterr().out.strip() == f"wrote {out}"


def test_cli_without_a_display_writes_beside_the_recording(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(show.sys, "platform", "linux")
    path = record(tmp_path, TRANSPORT_CONFIGS["serial"], ["torque"])["torque"]  # a real run on the twin
    assert main(["show", str(path)]) == 0
    png = path.with_suffix(".png")
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert capsys.readouterr().out.strip() == f"wrote {png} (no display: no window opened)"
    run = read_run(path)
    fig = show.recording_figure(run)
    assert fig.get_axes()[0].get_ylabel() == "torque [N·m]"  # excitation, torque_cmd_nm, torque_nm
    assert "mode torque" in fig.get_suptitle() and "status complete" in fig.get_suptitle()


def test_a_display_without_an_interactive_backend_falls_back_to_the_file(recording, monkeypatch):
    import matplotlib

    monkeypatch.setitem(matplotlib.rcParams, "backend", "agg")
    shown = show.show_recording(recording, window=True)
    assert shown.png == recording.with_suffix(".png") and shown.png.is_file()
    assert shown.note == "no interactive matplotlib backend"


def test_display_detection():
    assert show.display_available({}, "linux") is False
    assert show.display_available({"DISPLAY": ":0"}, "linux") is True
    assert show.display_available({"WAYLAND_DISPLAY": "wayland-0"}, "linux") is True
    assert show.display_available({}, "win32") is True and show.display_available({}, "darwin") is True


def _hdf5_not_a_recording(path):
    with h5py.File(path, "w") as f:
        f["x"] = np.zeros(3)
    return path


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda tmp: tmp / "missing.h5", "missing.h5: no such file"),
        (
            lambda tmp: (tmp / "notes.txt").write_text("x") and tmp / "notes.txt",
            "not a hilident recording (not an HDF5",
        ),
        (lambda tmp: _hdf5_not_a_recording(tmp / "other.h5"), "not a hilident recording (an HDF5 file without format"),
        (lambda tmp: tmp, "is a folder, not a recording"),
    ],
)
def test_cli_refuses_what_is_not_a_recording_with_exit_2(tmp_path, capsys, make, message):
    assert main(["show", str(make(tmp_path))]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hilident: error: ") and message in err and "Traceback" not in err


def test_cli_refuses_an_unknown_channel_and_an_empty_list(recording, capsys):
    assert main(["show", str(recording), "--channels", "torque"]) == 2
    assert "--channels:" in capsys.readouterr().err
    assert main(["show", str(recording), "--channels", " , "]) == 2
    assert "give channel names separated by commas" in capsys.readouterr().err
    assert not recording.with_suffix(".png").exists()


def test_a_damaged_recording_is_a_data_error(tmp_path, capsys):
    path = _write(tmp_path / "damaged.h5", events=False, status="complete")
    with h5py.File(path, "a") as f:
        f.attrs["channel_names"] = np.array(["a"], dtype=h5py.string_dtype())
    assert main(["show", str(path)]) == 3
    assert "damaged run file" in capsys.readouterr().err


def test_with_a_display_the_figure_goes_to_a_window(recording, monkeypatch):
    from matplotlib.figure import Figure

    class Pyplot:  # stands in for pyplot on a GUI backend
        def __init__(self):
            self.figures, self.shown = [], 0

        def figure(self, **kwargs):
            self.figures.append(Figure(**kwargs))
            return self.figures[-1]

        def show(self):
            self.shown += 1

    plt = Pyplot()
    monkeypatch.setattr(show, "_interactive_pyplot", lambda: plt)
    shown = show.show_recording(recording, ["torque_nm"], window=True)
    assert shown.png is None and plt.shown == 1
    assert [ax.get_ylabel() for ax in plt.figures[0].get_axes()] == ["torque_nm [N·m]"]
    assert not recording.with_suffix(".png").exists()


def test_an_empty_recording_and_the_counter_column_draw(tmp_path):
    path = tmp_path / "empty.h5"
    RunWriter(path, ["sample_index", "torque_nm"], ["1", "N*m"], RATE_HZ).close("aborted", "stopped at once")
    fig = _figure(path, ["sample_index", "torque_nm"])
    assert [ax.get_ylabel() for ax in fig.get_axes()] == ["sample_index [-]", "torque_nm [N·m]"]
    assert "0 samples" in fig.get_suptitle() and "status aborted: stopped at once" in fig.get_suptitle()
