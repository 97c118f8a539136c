"""`hilident batch` on Dask: a local cluster and a scheduler by address give the rows the plain loop gives."""

from __future__ import annotations

import shutil

import pandas as pd
import pytest

from hilident.batch import runner
from test_batch import batch, fleet  # noqa: F401  (the fixture, shared)

distributed = pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")

#: columns that differ between two runs of the same recordings: the time each task took, where, and its memory
TIMINGS = ["elapsed_s", "worker", "worker_peak_rss_mib"]


def _worker_settings():
    import os

    import dask

    return os.environ.get("MALLOC_TRIM_THRESHOLD_"), dask.config.get("distributed.worker.profile.enabled")


@pytest.fixture(scope="module")
def cluster():
    """One cluster of two worker processes on 127.0.0.1 for the module (a start costs seconds)."""
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0"
    ) as c:
        yield c


@pytest.fixture(scope="module")
def reference(tmp_path_factory, fleet):  # noqa: F811
    """The fleet's table from the plain loop in this process."""
    root, _ = fleet
    out = tmp_path_factory.mktemp("sync")
    assert batch(str(root), "--out", str(out), "--scheduler", "synchronous") == 0
    return pd.read_parquet(out / "batch.parquet").drop(columns=TIMINGS)


def test_a_local_cluster_of_two_workers_gives_the_rows_of_the_plain_loop(
    tmp_path,
    fleet,  # noqa: F811
    reference,  # noqa: F811
    monkeypatch,
    capsys,
):
    root, _ = fleet
    seen = {}
    local = runner._local_cluster

    def spied(workers):
        cluster, client = local(workers)
        info = client.scheduler_info()
        me = psutil.Process()
        listening = [
            c.laddr
            for p in (me, *me.children(recursive=True))
            for c in p.net_connections("inet")
            if c.status == psutil.CONN_LISTEN
        ]
        seen.update(
            scheduler=cluster.scheduler_address,
            workers=list(info["workers"]),
            listening=listening,
            settings=client.run(_worker_settings),
        )
        return cluster, client

    monkeypatch.setattr(runner, "_local_cluster", spied)
    assert main_quiet(str(root), "--out", str(tmp_path), "--workers", "2") == 0
    assert "(2 workers; one task took" in capsys.readouterr().out
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "batch.parquet").drop(columns=TIMINGS), reference)
    assert seen["scheduler"].startswith("tcp://127.0.0.1:")
    assert len(seen["workers"]) == 2 and all(w.startswith("tcp://127.0.0.1:") for w in seen["workers"])
    # scheduler, workers and their HTTP endpoints: nothing listens beyond loopback, on no fixed port
    assert len(seen["listening"]) >= 3 and {a.ip for a in seen["listening"]} == {"127.0.0.1"}
    assert 8787 not in {a.port for a in seen["listening"]}
    # the workers run with glibc's own malloc thresholds and without Dask's stack sampler
    assert list(seen["settings"].values()) == [(None, False)] * 2


def test_a_scheduler_by_address_gives_the_same_rows_and_a_rerun_skips_them(
    tmp_path,
    fleet,  # noqa: F811
    reference,  # noqa: F811
    cluster,
    capsys,
):
    root, _ = fleet
    folder = tmp_path / "fleet"
    shutil.copytree(root, folder)
    address = cluster.scheduler_address
    assert address.startswith("tcp://127.0.0.1:")
    assert main_quiet(str(folder), "--out", str(tmp_path / "out"), "--scheduler", address) == 0
    got = pd.read_parquet(tmp_path / "out" / "batch.parquet").drop(columns=TIMINGS)
    # the same recordings under another folder: only the paths differ (in the path and the errors naming it)
    for column in ("path", "error"):
        got[column] = got[column].str.replace(str(folder), str(root), regex=False)
    pd.testing.assert_frame_equal(got, reference)
    capsys.readouterr()
    assert main_quiet(str(folder), "--out", str(tmp_path / "out"), "--scheduler", address) == 0
    assert "0 identified, 0 failed, 5 skipped" in capsys.readouterr().out


def test_a_scheduler_that_does_not_answer_is_a_usage_error(tmp_path, fleet, monkeypatch, capsys):  # noqa: F811
    root, _ = fleet
    monkeypatch.setattr(runner, "CONNECT_TIMEOUT_S", 1.0)
    assert main_quiet(str(root), "--out", str(tmp_path), "--scheduler", "tcp://127.0.0.1:9") == 2
    stderr = capsys.readouterr().err
    assert "--scheduler tcp://127.0.0.1:9: no Dask scheduler answers there" in stderr and "Traceback" not in stderr


def test_a_scheduler_without_workers_is_a_usage_error(tmp_path, fleet, monkeypatch, capsys):  # noqa: F811
    root, _ = fleet
    monkeypatch.setattr(runner, "CONNECT_TIMEOUT_S", 1.0)
    with distributed.LocalCluster(n_workers=0, host="127.0.0.1", dashboard_address="127.0.0.1:0") as empty:
        assert main_quiet(str(root), "--out", str(tmp_path), "--scheduler", empty.scheduler_address) == 2
    stderr = capsys.readouterr().err
    assert "the scheduler has no worker" in stderr and "Traceback" not in stderr
    assert not (tmp_path / "batch.parquet").exists()


def main_quiet(*args: str) -> int:
    return batch(*args)
