"""`hilident emulate fleet` then `hilident batch` on it: the issue's acceptance, on a small fleet.

Every drifting axis is flagged with its rate within 10 % of the twin's truth (``fleet.json``), every healthy
axis is not, every damaged file is a failure row with its error, and the table reads back in pandas.
"""

from __future__ import annotations

import json

import pandas as pd
import pytest

from hilident.batch.fleet import write_fleet
from hilident.cli.main import main


@pytest.fixture(scope="module")
def judged(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    write_fleet(root / "fleet", 5, 10, seed=5, duration_s=8.0, drifting_share=0.4, damaged=6)
    truth = json.loads((root / "fleet" / "fleet.json").read_text())
    code = main(["batch", str(root / "fleet"), "--out", str(root / "table"), "--scheduler", "synchronous", "-q"])
    assert code == 0
    return root, truth


def test_drifting_axes_are_flagged_at_their_true_rate_and_healthy_ones_are_not(judged):
    root, truth = judged
    drift = json.loads((root / "table" / "drift.json").read_text())
    verdicts = drift["axes"]
    assert sorted(verdicts) == [a["axis"] for a in truth["axes"]]
    assert sum(a["drifting"] for a in truth["axes"]) == 2
    for axis in truth["axes"]:
        v = verdicts[axis["axis"]]
        assert v["flagged"] is axis["drifting"], (axis["axis"], v["verdict"])
        assert (axis["axis"] in drift["flagged"]) is axis["drifting"]
        if axis["drifting"]:
            want = axis["frequency_percent_per_day"]
            assert abs(v["rate_percent_per_day"] - want) <= 0.1 * abs(want), (v, want)


def test_every_damaged_file_is_a_failure_row_with_its_error_and_the_table_reads_in_pandas(judged, capsys):
    root, truth = judged
    parquet = pd.read_parquet(root / "table" / "batch.parquet")
    csv = pd.read_csv(root / "table" / "batch.csv")
    assert len(parquet) == len(csv) == 5 * 10  # every recording a row, the empty ones too
    failed = parquet[parquet["status"] == "failed"]
    damaged = {str(root / "fleet" / d["path"]) for d in truth["damaged"]}
    assert {d["damage"] for d in truth["damaged"]} >= {"empty", "truncated", "header", "running"}
    assert set(failed["path"]) == damaged
    assert failed["error"].str.len().gt(0).all() and failed["error_type"].eq("DataError").all()
    assert (parquet.loc[parquet["status"] == "ok", "frequency_hz"] > 0).all()
    page = (root / "table" / "report.html").read_text()
    assert "Drift verdicts" in page and "FLAGGED" in page.upper()
    # a second night with nothing new identifies nothing again, the empty files included
    assert main(["batch", str(root / "fleet"), "--out", str(root / "table"), "--scheduler", "synchronous", "-q"]) == 0
    assert "0 identified, 0 failed, 50 skipped" in capsys.readouterr().out
    assert len(pd.read_parquet(root / "table" / "batch.parquet")) == 50
