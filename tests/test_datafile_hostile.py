"""Hostile and damaged data files: every one is read or refused with one typed error, in bounded memory."""

from __future__ import annotations

import io
import struct
import tracemalloc
import zlib

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from scipy.io import savemat

from hilident import datafile
from hilident.cli.main import main
from hilident.config.tables import DataConfig
from hilident.datafile import load_dataset
from hilident.errors import ConfigError, DataError, HilidentError
from hilident.io.recording import RunWriter

RATE = 1000.0
N = 400
T = np.arange(N) / RATE
TAU = np.sin(2 * np.pi * 7 * T) + 0.3 * np.sin(2 * np.pi * 31 * T)
V = np.cos(2 * np.pi * 7 * T)
MAPPING = DataConfig(time="t", torque="tau", velocity="v")


def csv_text(names=("t", "tau", "v")) -> str:
    rows = "".join(f"{a:.6f},{b:.9g},{c:.9g}\n" for a, b, c in zip(T, TAU, V, strict=False))
    return ",".join(names) + "\n" + rows


def mat73(path, arrays):
    """A MATLAB v7.3 file: HDF5 behind MATLAB's 128-byte header, vectors stored 1 x n."""
    with h5py.File(path, "w", userblock_size=512) as f:
        for name, values in arrays.items():
            f[name] = np.asarray(values)[None, :]
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 .".ljust(116) + bytes(8)
    with open(path, "r+b") as fh:
        fh.write(header + struct.pack("<H", 0x0200) + b"IM")


def hilident_h5(path, rate=RATE, rows=None):
    with RunWriter(path, ["torque_nm", "velocity_mps"], ["N*m", "m/s"], 1.0) as w:
        w.append(np.column_stack([TAU, V]))
    with h5py.File(path, "a") as f:
        f.attrs["sample_rate_hz"] = rate
        if rows is not None:  # a damaged or foreign file: no flushed_samples to say which rows are good
            f["samples"].resize((rows, 2))
            del f.attrs["flushed_samples"]


H5_MAPPING = DataConfig(torque="torque_nm", velocity="velocity_mps")


# ------------------------------------------------------------------ encodings


def test_latin1_csv_is_read_and_its_header_named(tmp_path):
    path = tmp_path / "latin1.csv"
    path.write_bytes(csv_text(("t", "Moment µNm", "v")).encode("latin-1"))
    ds = load_dataset(path, DataConfig(time="t", torque="Moment µNm", velocity="v"))
    assert len(ds) == N and np.allclose(ds.signals["torque"], TAU)
    assert any("not UTF-8" in n and "Latin-1" in n for n in ds.notes)


def test_a_byte_order_mark_does_not_stick_to_the_first_column(tmp_path):
    path = tmp_path / "bom.csv"
    text = csv_text(("tau", "t", "v")).replace("\n", "\r\n")  # as Excel writes it
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    ds = load_dataset(path, DataConfig(time="tau", torque="t", velocity="v"))  # columns named in order
    assert np.allclose(ds.signals["torque"], TAU)


def test_utf16_csv_with_its_mark_is_read(tmp_path):
    path = tmp_path / "u16.csv"
    path.write_bytes(csv_text(("t", "τ", "v")).encode("utf-16"))
    ds = load_dataset(path, DataConfig(time="t", torque="τ", velocity="v"))
    assert np.allclose(ds.signals["velocity"], V)


def test_utf16_without_mark_and_binary_files_are_one_error(tmp_path):
    path = tmp_path / "u16.csv"
    path.write_bytes(csv_text().encode("utf-16-le"))
    with pytest.raises(DataError, match="NUL bytes"):
        load_dataset(path, MAPPING)


def test_junk_cell_names_its_line_and_column(tmp_path):
    lines = csv_text().splitlines()
    lines[123] = lines[123].replace(",", ",1.2.3x,", 1).rsplit(",", 1)[0]
    (tmp_path / "junk.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"line 124, column 'tau': '1.2.3x' is not a number"):
        load_dataset(tmp_path / "junk.csv", MAPPING)


def test_empty_and_missing_cells_are_nan_and_reported_as_such(tmp_path):
    lines = csv_text().splitlines()
    lines[50] = lines[50].rsplit(",", 1)[0]  # the last cell is missing
    (tmp_path / "short.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"'v' \(data.velocity\) has 1 NaN or infinite values, the first at row 49"):
        load_dataset(tmp_path / "short.csv", MAPPING)


def test_a_header_of_many_columns_is_listed_briefly(tmp_path):
    names = [f"c{i}" for i in range(5000)]
    (tmp_path / "wide.csv").write_text(",".join(names) + "\n" + ",".join("1" for _ in names) + "\n")
    with pytest.raises(DataError) as err:
        load_dataset(tmp_path / "wide.csv", MAPPING)
    assert "and 4980 more" in str(err.value) and len(str(err.value)) < 400


# ------------------------------------------------------------------ MATLAB files


@pytest.mark.parametrize("compressed", [False, True])
def test_truncated_mat_v5_is_one_error(tmp_path, compressed):
    savemat(tmp_path / "ok.mat", {"t": T, "tau": TAU, "v": V}, do_compression=compressed)
    raw = (tmp_path / "ok.mat").read_bytes()
    for cut in (10, 130, len(raw) // 2, len(raw) - 9):
        (tmp_path / "cut.mat").write_bytes(raw[:cut])
        with pytest.raises(DataError, match="cut.mat"):
            load_dataset(tmp_path / "cut.mat", MAPPING)


def test_mat_v4_header_declaring_a_long_name_is_refused_unread(tmp_path):
    # found by the property test below: 20 bytes whose name length says 50 MB
    (tmp_path / "v4.mat").write_bytes(bytes(19) + b"\x03")
    tracemalloc.start()
    try:
        with pytest.raises(DataError, match="damaged v4 header"):
            load_dataset(tmp_path / "v4.mat", MAPPING)
        assert tracemalloc.get_traced_memory()[1] < 1_000_000
    finally:
        tracemalloc.stop()


def test_truncated_mat_v73_is_one_error(tmp_path):
    mat73(tmp_path / "ok.mat", {"t": T, "tau": TAU, "v": V})
    assert len(load_dataset(tmp_path / "ok.mat", MAPPING)) == N
    raw = (tmp_path / "ok.mat").read_bytes()
    (tmp_path / "cut.mat").write_bytes(raw[: len(raw) - 2000])
    with pytest.raises(DataError, match="cut.mat"):
        load_dataset(tmp_path / "cut.mat", MAPPING)


def test_mat_whose_variable_inflates_past_the_bound_is_refused_unread(tmp_path, monkeypatch):
    # 12 MB of zeros compress to a few kB; the bound is lowered so the test stays small
    savemat(tmp_path / "bomb.mat", {"t": T, "tau": np.zeros(1_500_000), "v": V}, do_compression=True)
    assert (tmp_path / "bomb.mat").stat().st_size < 100_000
    monkeypatch.setattr(datafile.raw, "MAX_DATA_BYTES", 4_000_000)
    tracemalloc.start()
    try:
        with pytest.raises(DataError, match=r"variable 'tau'.*declares 1500000 rows"):
            load_dataset(tmp_path / "bomb.mat", MAPPING)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000  # headers only: the data were never inflated


def mat5_matrix(name: bytes, dims, data_tag_bytes: int) -> bytes:
    """A double matrix element whose data tag declares ``data_tag_bytes`` (but carries none)."""
    flags = struct.pack("<II", 6, 8) + struct.pack("<II", 6, 0)
    dim = struct.pack("<II", 5, 4 * len(dims)) + struct.pack(f"<{len(dims)}i", *dims)
    dim += bytes(-len(dim) % 8)
    nm = struct.pack("<II", 1, len(name)) + name + bytes(-len(name) % 8)
    body = flags + dim + nm + struct.pack("<II", 9, data_tag_bytes)
    return struct.pack("<II", 14, len(body)) + body


def test_mat_whose_data_tag_disagrees_with_its_shape_is_refused(tmp_path):
    header = b"MATLAB 5.0 MAT-file".ljust(116) + bytes(8) + struct.pack("<H", 0x0100) + b"IM"
    element = mat5_matrix(b"tau", (1, 10), 1 << 31)
    packed = zlib.compress(element)
    (tmp_path / "lie.mat").write_bytes(header + struct.pack("<II", 15, len(packed)) + packed)
    with pytest.raises(DataError, match=r"variable 'tau' declares 2147483648 bytes of data for shape \(1, 10\)"):
        load_dataset(tmp_path / "lie.mat", DataConfig(torque="tau", velocity="tau", sample_rate_hz=RATE))


def test_mat_variables_that_are_not_real_vectors_are_named(tmp_path):
    savemat(tmp_path / "odd.mat", {"t": T, "tau": TAU + 1j * V, "v": np.ones((N, 2)), "s": "text"})
    with pytest.raises(DataError, match="'tau' is complex"):
        load_dataset(tmp_path / "odd.mat", MAPPING)
    with pytest.raises(DataError, match=r"'v' has shape \(400, 2\)"):
        load_dataset(tmp_path / "odd.mat", DataConfig(time="t", torque="t", velocity="v"))
    with pytest.raises(DataError, match="'s' is a MATLAB char"):
        load_dataset(tmp_path / "odd.mat", DataConfig(time="t", torque="s", velocity="t"))


# ------------------------------------------------------------------ HDF5


def test_h5_declaring_two_billion_rows_is_refused_before_reading(tmp_path):
    hilident_h5(tmp_path / "huge.h5", rows=2_000_000_000)
    with pytest.raises(DataError, match=r"declares 2000000000 rows of 2 column\(s\)"):
        load_dataset(tmp_path / "huge.h5", H5_MAPPING)


def test_h5_rows_its_file_does_not_hold_are_not_read_as_zeros(tmp_path):
    hilident_h5(tmp_path / "hollow.h5", rows=1_000_000)  # 16 MB declared, a few kB stored
    with pytest.raises(DataError, match="declares 1000000 rows .* holds only"):
        load_dataset(tmp_path / "hollow.h5", H5_MAPPING)


def test_mat73_declaring_a_huge_vector_is_refused(tmp_path):
    with h5py.File(tmp_path / "big.h5", "w") as f:
        f.create_dataset("tau", shape=(1, 3_000_000_000), chunks=(1, 4096), dtype="<f8")
        f["v"] = V[None, :]
    with pytest.raises(DataError, match="declares 3000000000 rows"):
        datafile.mat_reader._read_mat73(tmp_path / "big.h5", ["tau", "v"])


@pytest.mark.parametrize("rate", [float("nan"), float("inf"), -5.0, 0.0])
def test_a_bad_recorded_sample_rate_is_one_error(tmp_path, rate):
    hilident_h5(tmp_path / "rate.h5", rate=rate)
    with pytest.raises(DataError, match="sample_rate_hz attribute"):
        load_dataset(tmp_path / "rate.h5", H5_MAPPING)


def test_a_nan_configured_sample_rate_is_a_config_error(tmp_path):
    (tmp_path / "d.csv").write_text(csv_text())
    with pytest.raises(ConfigError, match="data.sample_rate_hz"):
        load_dataset(tmp_path / "d.csv", DataConfig(torque="tau", velocity="v", sample_rate_hz=float("nan")))


def test_hostile_files_are_one_line_on_the_command_line(tmp_path, capsys):
    config = tmp_path / "c.toml"
    config.write_text('[data]\ntime = "t"\ntorque = "tau"\nvelocity = "v"\n')
    savemat(tmp_path / "ok.mat", {"t": T, "tau": TAU, "v": V})
    (tmp_path / "cut.mat").write_bytes((tmp_path / "ok.mat").read_bytes()[:700])
    (tmp_path / "bin.csv").write_bytes(bytes(range(256)) * 10)
    (tmp_path / "x.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(600))
    for name in ("cut.mat", "bin.csv", "x.h5"):
        assert (
            main(["identify", str(tmp_path / name), "--config", str(config), "--out", str(tmp_path / "o"), "-q"]) == 3
        )
        (line,) = capsys.readouterr().err.strip().splitlines()
        assert name in line


# ------------------------------------------------------------------ properties

FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def outcome(path, cfg=MAPPING, limit=40_000_000):
    """Load ``path``: a Dataset or a typed hilident error, and never much memory."""
    tracemalloc.start()
    try:
        try:
            ds = load_dataset(path, cfg)
            assert len(ds) >= datafile.MIN_SAMPLES
            assert all(np.all(np.isfinite(v)) for v in ds.signals.values())
            result = ds
        except HilidentError as exc:
            assert str(exc) and "\n" not in str(exc)
            result = exc
        assert tracemalloc.get_traced_memory()[1] < limit
        event(type(result).__name__)
    finally:
        tracemalloc.stop()
    return result


cell = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-(10**30), 10**30).map(str),
    st.sampled_from(["", " ", "nan", "-", "1e400", "1,5", "0x10", "1_0", '"2.5"', "µ", "\x00", "é"]),
    st.text(max_size=6),
)


@FAST
@given(
    names=st.one_of(
        st.permutations(["t", "tau", "v", "x"]),
        st.lists(st.sampled_from(["t", "tau", "v", "τ", "x", "", " t", "Tau", "\ufefft"]), max_size=5),
    ),
    body=st.one_of(st.just([]), st.lists(st.lists(cell, min_size=0, max_size=5), max_size=30)),
    good_rows=st.integers(0, 150),
    delimiter=st.sampled_from([",", ";", "\t", " "]),
    encoding=st.sampled_from(["utf-8", "utf-8-sig", "latin-1", "utf-16", "cp1252"]),
    newline=st.sampled_from(["\n", "\r\n", "\r"]),
)
def test_any_csv_is_read_or_refused_with_a_typed_error(tmp_path, names, body, good_rows, delimiter, encoding, newline):
    good = {"t": T, "tau": TAU, "v": V, "x": V}
    rows = [[f"{good[n][i]:.6g}" if n in good else "1" for n in names] for i in range(good_rows)] + body
    text = newline.join(delimiter.join(r) for r in [names, *rows]) + newline
    path = tmp_path / "h.csv"
    path.write_bytes(text.encode(encoding, errors="replace"))
    outcome(path)


@FAST
@given(data=st.binary(max_size=3000))
def test_any_bytes_as_csv_mat_or_h5_are_read_or_refused(tmp_path, data):
    for name in ("b.csv", "b.mat", "b.h5"):
        (tmp_path / name).write_bytes(data)
        outcome(tmp_path / name, H5_MAPPING if name.endswith(".h5") else MAPPING)


@pytest.fixture(scope="module")
def good_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("good")
    savemat(folder / "v5.mat", {"t": T, "tau": TAU, "v": V})
    savemat(folder / "v5z.mat", {"t": T, "tau": TAU, "v": V}, do_compression=True)
    savemat(folder / "v4.mat", {"t": T, "tau": TAU, "v": V}, format="4")
    mat73(folder / "v73.mat", {"t": T, "tau": TAU, "v": V})
    hilident_h5(folder / "run.h5")
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@FAST
@given(
    name=st.sampled_from(["v4.mat", "v5.mat", "v5z.mat", "v73.mat", "run.h5"]),
    cut=st.one_of(st.just(1.0), st.floats(0, 1)),
    flips=st.lists(st.tuples(st.floats(0, 1), st.integers(1, 255)), max_size=4),
)
def test_truncated_or_corrupted_mat_and_h5_are_read_or_refused(tmp_path, good_files, name, cut, flips):
    raw = bytearray(good_files[name])
    for where, xor in flips:
        i = min(int(where * len(raw)), len(raw) - 1)
        raw[i] ^= xor
    raw = raw[: max(1, int(cut * len(raw))) if cut < 1 else len(raw)]
    path = tmp_path / name
    path.write_bytes(bytes(raw))
    outcome(path, H5_MAPPING if name.endswith(".h5") else MAPPING)


@FAST
@given(rows=st.integers(0, 2**50), cols=st.integers(1, 4), chunk=st.integers(1, 10**6))
def test_h5_with_absurd_declared_shapes_is_refused_without_reading(tmp_path, rows, cols, chunk):
    path = tmp_path / "absurd.h5"
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "hilident-run"
        f.attrs["format_version"] = np.int64(1)
        f.attrs["sample_rate_hz"] = RATE
        f.attrs.create(
            "channel_names",
            np.array(["torque_nm", "velocity_mps", "a", "b"][:cols], dtype=object),
            dtype=h5py.string_dtype(),
        )
        f.create_dataset(
            "samples", shape=(rows, cols), maxshape=(None, cols), chunks=(min(chunk, 2**20), cols), dtype="<f8"
        )
    result = outcome(path, DataConfig(torque="torque_nm", sample_rate_hz=RATE, velocity="torque_nm"), 5_000_000)
    assert isinstance(result, DataError)


def test_csv_larger_than_the_bound_is_refused_before_parsing(tmp_path, monkeypatch):
    rows = 400_000  # 9.6 MB as three float64 columns
    t = np.arange(rows) / RATE
    np.savetxt(
        tmp_path / "d.csv",
        np.column_stack([t, np.sin(t), np.cos(t)]),
        delimiter=",",
        header="t,tau,v",
        comments="",
        fmt="%.4f",
    )
    monkeypatch.setattr(datafile.raw, "MAX_DATA_BYTES", 1_000_000)
    tracemalloc.start()
    try:
        with pytest.raises(DataError, match=r"has up to 400002 rows of 3 column\(s\)"):
            load_dataset(tmp_path / "d.csv", MAPPING)
        assert tracemalloc.get_traced_memory()[1] < 3_000_000  # read buffers only: no column allocated
    finally:
        tracemalloc.stop()


def test_a_mat_variable_whose_data_type_is_unknown_is_refused_before_scipy_reads_it(tmp_path):
    # scipy's reader indexes a table with the data element's type unchecked: type 243 crashed the process
    buffer = io.BytesIO()
    savemat(buffer, {"t": T, "tau": TAU, "v": V})
    raw = bytearray(buffer.getvalue())
    data_tag = 128 + 8 + 16 + 16 + 8  # file header, matrix tag, array flags, dimensions, the name "t" (small)
    assert raw[data_tag] == 9  # miDOUBLE
    raw[data_tag] = 243
    path = tmp_path / "bad.mat"
    path.write_bytes(bytes(raw))
    with pytest.raises(DataError, match=r"'t'.*element type 243"):
        load_dataset(path, MAPPING)
