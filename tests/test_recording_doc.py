"""Every Python snippet of ``docs/recording.md`` runs, as written, on a recording a run on the twin just made."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from hilident.io.recording import read_run
from support.fresh_recording import TRANSPORT_CONFIGS, record

DOC = Path(__file__).resolve().parents[1] / "docs" / "recording.md"
SNIPPETS = re.findall(r"^```python\n(.*?)^```", DOC.read_text(encoding="utf-8"), flags=re.S | re.M)


@pytest.fixture(scope="module")
def doc_run(tmp_path_factory) -> Path:
    """The folder holding ``out/run.h5``, the path the snippets read: a torque run on the serial board's twin."""
    folder = tmp_path_factory.mktemp("doc")
    made = record(folder / "made", TRANSPORT_CONFIGS["serial"], ["torque"])["torque"]
    (folder / "out").mkdir()
    shutil.copy(made, folder / "out" / "run.h5")
    return folder


def _run_snippet(number: int, folder: Path, monkeypatch) -> dict:
    monkeypatch.chdir(folder)
    namespace: dict = {"__name__": f"recording_md_snippet_{number}"}
    exec(compile(SNIPPETS[number], f"{DOC}: python snippet {number + 1}", "exec"), namespace)
    return namespace


def test_the_doc_has_its_snippets():
    assert len(SNIPPETS) == 2  # reading with hilident, reading with h5py alone


def test_reading_with_hilident(doc_run, monkeypatch, capsys):
    ns = _run_snippet(0, doc_run, monkeypatch)
    run = read_run(doc_run / "out" / "run.h5")
    np.testing.assert_array_equal(ns["torque"], run.samples["torque_nm"])
    np.testing.assert_array_equal(ns["t"], run.samples["sample_index"] / run.sample_rate_hz)
    assert ns["excitation_unit"] == "N*m"  # a torque run
    printed = capsys.readouterr().out
    assert printed.startswith("complete  torque_run torque myrio-board\n")
    assert " s  finished: " in printed  # the run's events, one line each


def test_reading_with_h5py_alone(doc_run, monkeypatch):
    ns = _run_snippet(1, doc_run, monkeypatch)
    run = read_run(doc_run / "out" / "run.h5")
    np.testing.assert_array_equal(ns["torque"], run.samples["torque_nm"])
    np.testing.assert_allclose(ns["t"], run.samples["time_s"])
    assert ns["units"] == run.units and ns["units"]["excitation"] == "N*m"
    assert ns["status"] == "complete" and ns["mode"] == "torque"
    assert ns["versions"]["hilident"] and ns["device"]["name"] == "myrio-board"
    assert [e[1] for e in ns["events"]] == [e["kind"] for e in run.events]
    assert ns["events"][-1][3] == run.events[-1]["data"]


def test_the_layout_and_the_matlab_lines_name_what_a_recording_holds(doc_run):
    """The doc's layout tree, its root-attribute table and its MATLAB lines (no MATLAB here: the paths,
    attributes and event fields they read are checked in a recording instead)."""
    import h5py

    text = DOC.read_text(encoding="utf-8")
    (tree,) = re.findall(r"^## Layout.*?^```\n(.*?)^```", text, flags=re.S | re.M)
    (matlab,) = re.findall(r"^```matlab\n(.*?)^```", text, flags=re.S | re.M)
    table = text.split("### Root attributes", 1)[1].split("\n\n", 2)[1]
    attributes = [a for a in re.findall(r"^\| `(\w+)`", table, flags=re.M)]
    with h5py.File(doc_run / "out" / "run.h5", "r") as f:
        required = [line.split()[0] for line in tree.splitlines() if "optional" not in line]
        assert [p for p in required if p != "/" and p not in f] == []
        assert len(attributes) >= 10 and [a for a in attributes if a not in f.attrs] == []
        datasets = re.findall(r'h5read\("run\.h5", "([^"]+)"\)', matlab)
        read_attributes = re.findall(r'h5readatt\("run\.h5", "/", "(\w+)"\)', matlab)
        fields = re.findall(r"ev\.(\w+)", matlab)
        assert datasets and read_attributes and fields
        assert [d for d in datasets if d not in f] == []
        assert [a for a in read_attributes if a not in f.attrs] == []
        assert [n for n in fields if n not in f["events"].dtype.names] == []
