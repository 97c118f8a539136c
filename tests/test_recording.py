"""Tests of hilident.io.recording: HDF5 run files written while streaming."""

from __future__ import annotations

import gc
import json
import math
import os
import subprocess
import sys
import textwrap
import tracemalloc

import h5py
import numpy as np
import pytest

from hilident.errors import DataError
from hilident.io.recording import FORMAT, RunData, RunWriter, read_run

CHANNELS = ["position", "velocity", "torque"]
UNITS = ["m", "m/s", "N*m"]
RATE_HZ = 2000.0


def _blocks(rng: np.random.Generator, sizes: list[int]) -> list[np.ndarray]:
    return [rng.normal(size=(n, len(CHANNELS))) for n in sizes]


def test_round_trip_samples_units_attrs(tmp_path):
    rng = np.random.default_rng(1)
    blocks = _blocks(rng, [100, 1, 257, 0, 4096])
    versions = {"numpy": np.__version__, "h5py": h5py.__version__}
    config_toml = 'name = "gantry"\n[emulator.plant]\nm1 = 3.2\n' + "# " + "x" * 100_000  # > 64 KiB
    path = tmp_path / "run.h5"
    with RunWriter(
        path,
        CHANNELS,
        UNITS,
        RATE_HZ,
        attrs={
            "experiment": "chirp",
            "seed": 7,
            "config_toml": config_toml,
            "versions": versions,
            "gain": np.float32(0.5),
        },
    ) as rec:
        for b in blocks:
            rec.append(b)
        rec.set_attrs(device={"vendor": "emu", "serial": 12}, notch_hz=[41.5, 118.0])
        assert rec.n_samples == sum(len(b) for b in blocks)

    run = read_run(path, require_complete=True)
    expected = np.concatenate(blocks)
    assert run.channel_names == CHANNELS
    for i, name in enumerate(CHANNELS):
        np.testing.assert_array_equal(run.channel(name), expected[:, i])
        assert run.channel(name).dtype == np.float64
    assert run.units == dict(zip(CHANNELS, UNITS, strict=False))
    assert run.sample_rate_hz == RATE_HZ
    assert run.status == "complete" and run.complete and run.reason == ""
    assert run.n_samples == len(expected)
    np.testing.assert_allclose(run.time_s[[0, -1]], [0.0, (len(expected) - 1) / RATE_HZ])
    a = run.attrs
    assert a["format"] == FORMAT and a["format_version"] == 1
    assert a["experiment"] == "chirp" and a["seed"] == 7 and a["gain"] == 0.5
    assert a["config_toml"] == config_toml
    assert a["versions"] == versions
    assert a["device"] == {"vendor": "emu", "serial": 12}
    assert a["notch_hz"] == [41.5, 118.0]
    assert a["channel_names"] == CHANNELS and a["n_samples"] == len(expected)
    assert a["created_utc"].endswith("+00:00")


def test_layout_is_readable_with_plain_h5py(tmp_path):
    path = tmp_path / "run.h5"
    with RunWriter(path, CHANNELS, UNITS, RATE_HZ, attrs={"versions": {"numpy": "2"}}, chunk_rows=64) as rec:
        rec.append(np.ones((10, 3)))
    with h5py.File(path, "r") as f:
        ds = f["samples"]
        assert ds.shape == (10, 3) and ds.maxshape == (None, 3) and ds.chunks == (64, 3)
        assert ds.dtype == np.float64 and ds.compression is None
        assert list(f.attrs["channel_names"]) == CHANNELS
        assert json.loads(f.attrs["versions_json"]) == {"numpy": "2"}
        assert f.attrs["status"] == "complete" and f.attrs["n_samples"] == 10
        assert set(f["events"].dtype.names) == {"sample_index", "time_s", "kind", "message", "data"}


def test_lzf_compression_round_trips(tmp_path):
    data = np.round(np.random.default_rng(2).normal(size=(5000, 3)), 3)
    path = tmp_path / "lzf.h5"
    with RunWriter(path, CHANNELS, UNITS, RATE_HZ, compression="lzf") as rec:
        for block in np.array_split(data, 7):
            rec.append(block)
    with h5py.File(path, "r") as f:
        assert f["samples"].compression == "lzf"
    np.testing.assert_array_equal(read_run(path).channel("torque"), data[:, 2])


def test_many_appends_keep_memory_bounded(tmp_path):
    block = np.random.default_rng(3).normal(size=(500, 3))
    path = tmp_path / "long.h5"
    with RunWriter(path, CHANNELS, UNITS, RATE_HZ, chunk_rows=1024) as rec:
        for _ in range(20):  # warm up caches and h5py internals
            rec.append(block)
        gc.collect()
        tracemalloc.start()
        try:
            for _ in range(200):
                rec.append(block)
            gc.collect()
            after_200 = tracemalloc.get_traced_memory()[0]
            for _ in range(400):
                rec.append(block)
            gc.collect()
            after_600, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
    # Keeping the blocks would cost 12 kB per append (7.2 MB in all).
    assert after_200 < 3 * block.nbytes
    assert after_600 - after_200 < block.nbytes
    assert peak < 20 * block.nbytes
    run = read_run(path)
    assert run.n_samples == 620 * 500
    np.testing.assert_array_equal(run.channel("velocity")[-500:], block[:, 1])


def test_event_log_round_trip(tmp_path):
    path = tmp_path / "ev.h5"
    with RunWriter(path, CHANNELS, UNITS, RATE_HZ) as rec:
        rec.event("connected", "link up")  # before any sample: index 0
        rec.append(np.zeros((300, 3)))
        rec.event(
            "excitation_start",
            "chirp 1-200 Hz",
            sample_index=100,
            f0_hz=1.0,
            f1_hz=np.float64(200.0),
            amplitude=np.array([0.1, 0.2]),
            pole=1 - 2j,
            bad=math.nan,
        )
        rec.event("limit_trip", "torque above 2 N·m – stopped")  # "now": after 300 rows
    events = read_run(path).events
    assert [e["kind"] for e in events] == ["connected", "excitation_start", "limit_trip"]
    assert [e["sample_index"] for e in events] == [0, 100, 300]
    assert [e["time_s"] for e in events] == pytest.approx([0.0, 100 / RATE_HZ, 300 / RATE_HZ])
    assert events[1]["message"] == "chirp 1-200 Hz"
    assert events[1]["data"] == {
        "f0_hz": 1.0,
        "f1_hz": 200.0,
        "amplitude": [0.1, 0.2],
        "pole": {"re": 1.0, "im": -2.0},
        "bad": None,
    }
    assert events[2]["message"] == "torque above 2 N·m – stopped" and events[2]["data"] == {}


def test_tables_round_trip_and_replace(tmp_path):
    path = tmp_path / "tab.h5"
    v = np.linspace(-0.2, 0.2, 9)
    with RunWriter(path, CHANNELS, UNITS, RATE_HZ) as rec:
        rec.write_table("friction_points", velocity_mps=v, torque_nm=0.3 * np.sign(v), ok=v != 0)
        rec.write_table("windows", start_s=[0.0, 1.0], stop_s=[0.9, 1.9], label=["fwd", "rev"])
        rec.write_table("windows", start_s=[5.0], stop_s=[6.0], label=["again"])
    tables = read_run(path).tables
    assert set(tables) == {"friction_points", "windows"}
    fp = tables["friction_points"]
    assert list(fp) == ["velocity_mps", "torque_nm", "ok"]  # column order kept
    np.testing.assert_array_equal(fp["velocity_mps"], v)
    np.testing.assert_array_equal(fp["ok"], v != 0)
    np.testing.assert_array_equal(tables["windows"]["start_s"], [5.0])
    assert list(tables["windows"]["label"]) == ["again"]


def test_table_errors(tmp_path):
    with RunWriter(tmp_path / "t.h5", CHANNELS, UNITS, RATE_HZ) as rec:
        with pytest.raises(DataError, match="differ in length"):
            rec.write_table("w", a=[1, 2], b=[1, 2, 3])
        with pytest.raises(DataError, match="'a' must be 1-D"):
            rec.write_table("w", a=np.zeros((2, 2)))
        with pytest.raises(DataError, match="table name"):
            rec.write_table("a/b", a=[1])
        with pytest.raises(DataError, match="no columns"):
            rec.write_table("w")


def test_crash_mid_run_leaves_readable_file(tmp_path):
    path = tmp_path / "crash.h5"
    script = textwrap.dedent(f"""
        import os, numpy as np
        from hilident.io.recording import RunWriter
        rec = RunWriter({str(path)!r}, {CHANNELS!r}, {UNITS!r}, {RATE_HZ!r}, attrs={{"seed": 5}})
        rng = np.random.default_rng(0)
        for i in range(5):
            rec.append(rng.normal(size=(1000 + i, 3)))
        rec.event("excitation_start", "sine", sample_index=10, amplitude=0.1)
        os._exit(1)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1, proc.stderr

    rng = np.random.default_rng(0)
    expected = np.concatenate([rng.normal(size=(1000 + i, 3)) for i in range(5)])
    run = read_run(path)
    assert run.status == "running" and not run.complete
    assert run.n_samples == len(expected)
    np.testing.assert_array_equal(run.channel("torque"), expected[:, 2])
    assert run.events[0]["kind"] == "excitation_start" and run.attrs["seed"] == 5
    with pytest.raises(DataError, match="did not complete.*running"):
        read_run(path, require_complete=True)


def test_context_manager_on_exception_aborts_with_reason(tmp_path):
    path = tmp_path / "abort.h5"
    with pytest.raises(RuntimeError, match="axis tripped"):
        with RunWriter(path, CHANNELS, UNITS, RATE_HZ) as rec:
            rec.append(np.ones((5, 3)))
            raise RuntimeError("axis tripped at 2.1 N·m")
    assert rec.closed
    run = read_run(path)
    assert run.status == "aborted" and run.reason == "axis tripped at 2.1 N·m"
    assert run.n_samples == 5 and run.attrs["n_samples"] == 5
    with pytest.raises(DataError, match="axis tripped"):
        read_run(path, require_complete=True)


def test_status_is_running_while_streaming(tmp_path):
    path = tmp_path / "live.h5"
    rec = RunWriter(path, CHANNELS, UNITS, RATE_HZ)
    try:
        rec.append(np.ones((7, 3)))
        live = read_run(path)  # reads without taking the writer's lock
        assert live.status == "running" and live.n_samples == 7
    finally:
        rec.close("aborted", reason="operator stop")
    rec.close()  # second close is a no-op
    run = read_run(path)
    assert (run.status, run.reason) == ("aborted", "operator stop")


@pytest.mark.parametrize(
    "block",
    [
        np.zeros((4, 2)),
        np.zeros((4, 4)),
        np.zeros(3),
        np.zeros((2, 3, 1)),
        np.array([["a", "b", "c"]]),
        np.zeros((2, 3), dtype=complex),
    ],
)
def test_bad_block_shapes_raise(tmp_path, block):
    with RunWriter(tmp_path / "bad.h5", CHANNELS, UNITS, RATE_HZ) as rec:
        with pytest.raises(DataError, match="block must"):
            rec.append(block)
        assert rec.n_samples == 0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(channels=[], units=[]), "channels"),
        (dict(channels=["a", "a"], units=["m", "m"]), "unique"),
        (dict(units=["m"]), "units must be 3"),
        (dict(sample_rate_hz=0.0), "sample_rate_hz"),
        (dict(sample_rate_hz=math.inf), "sample_rate_hz"),
        (dict(chunk_rows=0), "chunk_rows"),
        (dict(compression="gzip"), "compression"),
        (dict(attrs={"status": "x"}), "'status' is set by the writer"),
        (dict(attrs={"versions_json": "{}"}), "_json"),
    ],
)
def test_bad_writer_arguments(tmp_path, kwargs, match):
    args = dict(channels=CHANNELS, units=UNITS, sample_rate_hz=RATE_HZ)
    args.update(kwargs)
    with pytest.raises(DataError, match=match):
        RunWriter(tmp_path / "w.h5", **args)


def test_existing_file_needs_overwrite(tmp_path):
    path = tmp_path / "run.h5"
    with RunWriter(path, CHANNELS, UNITS, RATE_HZ) as rec:
        rec.append(np.ones((3, 3)))
    with pytest.raises(DataError, match="exists"):
        RunWriter(path, CHANNELS, UNITS, RATE_HZ)
    assert read_run(path).n_samples == 3
    with RunWriter(path, CHANNELS, UNITS, RATE_HZ, overwrite=True) as rec:
        rec.append(np.ones((2, 3)))
    assert read_run(path).n_samples == 2


def test_writes_after_close_raise(tmp_path):
    rec = RunWriter(tmp_path / "c.h5", CHANNELS, UNITS, RATE_HZ)
    rec.close()
    for call in (
        lambda: rec.append(np.ones((1, 3))),
        lambda: rec.event("k", "m"),
        lambda: rec.set_attrs(a=1),
        lambda: rec.write_table("t", a=[1]),
    ):
        with pytest.raises(DataError, match="closed"):
            call()
    with pytest.raises(DataError, match="status"):
        RunWriter(tmp_path / "d.h5", CHANNELS, UNITS, RATE_HZ).close("weird")


def test_event_argument_errors(tmp_path):
    with RunWriter(tmp_path / "e.h5", CHANNELS, UNITS, RATE_HZ) as rec:
        with pytest.raises(DataError, match="kind"):
            rec.event("", "m")
        with pytest.raises(DataError, match="sample_index"):
            rec.event("k", "m", sample_index=-2)
        with pytest.raises(DataError, match="JSON"):
            rec.event("k", "m", thing=object())


def test_set_attrs_switches_between_plain_and_json(tmp_path):
    path = tmp_path / "a.h5"
    with RunWriter(path, CHANNELS, UNITS, RATE_HZ, attrs={"device": "emu-1"}) as rec:
        rec.set_attrs(device={"name": "emu-1", "fw": [1, 2]}, note=None)
    run = read_run(path)
    assert run.attrs["device"] == {"name": "emu-1", "fw": [1, 2]} and run.attrs["note"] is None
    with h5py.File(path, "r") as f:
        assert "device" not in f.attrs and "device_json" in f.attrs


def test_read_errors_name_the_file(tmp_path):
    missing = tmp_path / "missing.h5"
    with pytest.raises(DataError, match="missing.h5.*not found"):
        read_run(missing)
    text = tmp_path / "notes.h5"
    text.write_text("not hdf5")
    with pytest.raises(DataError, match="notes.h5.*not an HDF5"):
        read_run(text)
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["samples"] = np.zeros((3, 3))
    with pytest.raises(DataError, match="foreign.h5.*not a hilident run"):
        read_run(foreign)


def test_unknown_channel_lists_available(tmp_path):
    run = RunData(
        path=tmp_path / "x.h5",
        samples={"a": np.zeros(2), "b": np.ones(2)},
        units={"a": "m", "b": "m"},
        sample_rate_hz=10.0,
    )
    with pytest.raises(DataError, match=r"'torque'.*available channels: a, b"):
        run.channel("torque")


# ---------------------------------------------------------------------- full disk, crashed writers


def _fill_until_refused(path, rows_per_block=2000):
    rec = RunWriter(path, CHANNELS, UNITS, RATE_HZ, overwrite=True)
    rng = np.random.default_rng(3)
    with pytest.raises(DataError, match="disk full|cannot write"):
        for _ in range(100_000):
            rec.append(rng.normal(size=(rows_per_block, len(CHANNELS))) + 5.0)  # never 0.0
    rec.close("aborted", "the disk filled")
    return read_run(path)


def test_disk_full_is_refused_before_writing_and_leaves_no_zero_rows(tmp_path, monkeypatch):
    """A nearly full disk (reported by statvfs) stops the writer before HDF5 half-writes anything."""
    real = os.statvfs
    budget = {"left": 40}

    class Tight:
        def __init__(self, st, free_blocks):
            self.f_frsize, self.f_bavail = st.f_frsize, free_blocks

    def statvfs(path):
        budget["left"] -= 1
        st = real(path)
        return Tight(st, st.f_bavail if budget["left"] > 0 else 0)

    monkeypatch.setattr(os, "statvfs", statvfs)
    run = _fill_until_refused(tmp_path / "run.h5")
    assert run.status == "aborted"
    assert 0 < run.n_samples < 40 * 2000
    assert not np.any(run.samples["torque"] == 0.0)
    assert oct(os.stat(tmp_path / "run.h5").st_mode & 0o777) == oct(0o666 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@pytest.fixture
def small_filesystem(tmp_path):
    """A 4 MiB tmpfs, where the kernel allows mounting one (root in a container); skipped elsewhere."""
    mount = tmp_path / "small"
    mount.mkdir()
    if (
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(mount)], capture_output=True).returncode
        != 0
    ):
        pytest.skip("cannot mount a small tmpfs here")
    yield mount
    subprocess.run(["umount", str(mount)], capture_output=True)


@pytest.mark.parametrize("margin", [True, False], ids=["refused-early", "write-failed"])
def test_a_really_full_disk_keeps_the_good_rows_and_never_crashes(small_filesystem, margin):
    """Also when HDF5's own write fails (no margin check): good rows kept, no zeros, and no crash at exit."""
    script = textwrap.dedent(f"""
        import numpy as np
        from hilident.errors import DataError
        from hilident.io.recording import RunWriter, read_run
        if not {margin}:
            RunWriter._check_space = lambda self, nbytes: None
        rec = RunWriter({str(small_filesystem / "run.h5")!r}, ["a", "b", "c"], ["1", "1", "1"], 1000.0)
        try:
            while True:
                rec.append(np.random.default_rng(1).normal(size=(777, 3)) + 5.0)
        except DataError as exc:
            print("refused:", exc)
        rec.close("aborted", "disk full")
        run = read_run(rec.path)
        print(run.status, run.n_samples, int(np.sum(run.samples["a"] == 0.0)))
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    status, rows, zeros = done.stdout.strip().splitlines()[-1].split()
    assert status == "aborted" and int(rows) > 0 and int(zeros) == 0


def test_a_crashed_writer_leaves_the_flushed_rows_and_says_running(tmp_path):
    """SIGKILL mid-run: the reader sees status 'running' and exactly the rows of the last flush."""
    path = tmp_path / "run.h5"
    script = textwrap.dedent(f"""
        import os, signal, numpy as np
        from hilident.io.recording import RunWriter
        rec = RunWriter({str(path)!r}, ["a"], ["1"], 1000.0)
        for i in range(5):
            rec.append(np.full((1000, 1), 1.0 + i))
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == -9
    run = read_run(path)
    assert run.status == "running"
    assert run.attrs["flushed_samples"] == 5000 == run.n_samples
    np.testing.assert_array_equal(np.unique(run.samples["a"]), [1.0, 2.0, 3.0, 4.0, 5.0])
