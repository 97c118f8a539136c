"""``hilident batch``: the recordings not yet in the table identified on Dask (or in a plain loop), the table kept.

Three ways to run the tasks (``--scheduler``):

- none given: a ``distributed.LocalCluster`` of worker processes on
  127.0.0.1 (one per core, or ``--workers N``; one thread each, no
  dashboard);
- ``synchronous``: a plain loop in this process (debugging; the reference
  the benchmark compares with);
- an address (``tcp://HOST:8786``): a ``distributed.Client`` on a running
  ``dask scheduler``, whose workers have hilident installed and see the
  recordings under the same paths.

Only paths are submitted, never data: a worker reads one recording at a time.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import logging
import os
import time
from collections.abc import Callable, Generator
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hilident.batch.inputs import content_sha256, expand_inputs
from hilident.batch.table import CSV_NAME, TABLE_NAME, read_rows, write_rows
from hilident.batch.task import blank_row, fail, identify_task
from hilident.batch.verdicts import judge_fleet
from hilident.config.tables import BatchConfig
from hilident.errors import DataError, HilidentError, UsageError

#: ``--scheduler`` value that runs the tasks in this process, one after the other.
SYNCHRONOUS = "synchronous"
#: Folder of the table's folder holding each recording's ``summary.json``.
SUMMARIES = "summaries"
#: SHA-256 of no bytes: an empty file's content hash.
EMPTY_SHA256 = hashlib.sha256(b"").hexdigest()
#: Seconds to wait for a scheduler given by address before giving up.
CONNECT_TIMEOUT_S = 10.0


@dataclass
class BatchOutcome:
    """What a batch did: counts, times and where the table is."""

    table: Path
    csv: Path
    recordings: int
    done: int = 0
    failed: int = 0
    skipped: int = 0
    wall_s: float = 0.0
    workers: int = 0
    interrupted: bool = False
    task_s: float = 0.0
    #: Wall time from the cluster being up to the last recording identified, s: the part the workers share.
    identify_wall_s: float = 0.0
    failures: list[dict] = field(default_factory=list)
    #: The drift verdict of every axis in the table (:func:`hilident.batch.verdicts.judge_fleet`).
    drifts: dict = field(default_factory=dict)
    report: Path | None = None

    @property
    def per_recording_s(self) -> float:
        """Wall time per recording identified in this batch (the cluster's start included), s; NaN: none."""
        return self.wall_s / self.done if self.done else float("nan")

    @property
    def mean_task_s(self) -> float:
        """Mean time one task took in its worker, s (NaN when none ran)."""
        return self.task_s / self.done if self.done else float("nan")


def config_key(cfg) -> str:
    """SHA-256 of what in the configuration can change a row: every table but ``[batch]`` ("" text: no config).

    ``[batch]`` sets the drift verdict only, so changing it redoes no
    identification.
    """
    if cfg is None:
        return hashlib.sha256(b"").hexdigest()
    from hilident.config.tables import parse_toml

    tables = {k: v for k, v in parse_toml(cfg.text, cfg.source).items() if k != "batch"}
    return hashlib.sha256(json.dumps(tables, sort_keys=True, default=str).encode()).hexdigest()


class _Tally:
    """Progress of the batch on stderr: counts done, failed and skipped, and the rate, a line now and then."""

    def __init__(self, progress, total: int, skipped: int):
        self.progress, self.total, self.skipped = progress, total, skipped
        self.done = self.failed = 0
        self.started = self.last = time.monotonic()
        self.bar = progress.fraction(f"identifying {total} recordings") if progress and total else None

    def add(self, row: dict) -> None:
        self.done += 1
        self.failed += row["status"] != "ok"
        if self.bar is not None:
            self.bar(self.done / self.total)
        now = time.monotonic()
        if self.progress and not self.progress.tty and (now - self.last >= 10.0 or self.done == self.total):
            self.last = now
            rate = self.done / max(now - self.started, 1e-9)
            self.progress.step(
                f"  {self.done}/{self.total} done ({self.failed} failed, {self.skipped} skipped), "
                f"{rate:.2f} recordings/s"
            )


#: Dask settings of the local cluster's workers (see :func:`_local_cluster`); ``dask worker`` takes the same
#: from a YAML file in its configuration folder (the cluster recipe of docs/batch.md).
WORKER_SETTINGS = {
    # Dask's default sets glibc's trim threshold, which also pins its mmap threshold: every array of a
    # recording is then mapped and unmapped afresh, and one identification took 0.30 s instead of 0.22 s
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    # the statistical profiler walks every thread's stack each 10 ms: time a one-thread worker loses
    "distributed.worker.profile.enabled": False,
}


def _local_cluster(workers: int):
    import dask
    from distributed import Client, LocalCluster

    # silence_logs: the workers' notes (a task cancelled by Ctrl-C) are not the user's concern
    with dask.config.set(WORKER_SETTINGS):  # read when the nannies are made: they hand it to their workers
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
            scheduler_kwargs={"dashboard": False},
            silence_logs=logging.ERROR,
        )
    return cluster, Client(cluster)


def _client_at(address: str):
    from distributed import Client

    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise UsageError(
            f"--scheduler {address}: no Dask scheduler answers there ({exc}); start one with "
            "`dask scheduler` and workers with `dask worker ADDRESS`"
        ) from None
    except ValueError as exc:
        raise UsageError(
            f"--scheduler {address}: not a scheduler address ({exc}); give tcp://HOST:PORT or {SYNCHRONOUS}"
        ) from None
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
    except TimeoutError:
        client.close()
        raise UsageError(
            f"--scheduler {address}: the scheduler has no worker (none joined within "
            f"{CONNECT_TIMEOUT_S:g} s); start them with `dask worker {address}`"
        ) from None
    return client


def summary_path(folder: Path, row: dict) -> Path:
    """Where the ``summary.json`` of ``row``'s analysis is kept: ``summaries/<content hash>-<config hash>.json``."""
    return folder / SUMMARIES / f"{row['content_sha256']}-{row['config_sha256'][:12]}.json"


def _run_tasks(
    jobs: list[tuple[str, str]],
    args: tuple,
    scheduler: str | None,
    workers: int | None,
    on_cluster: Callable[[int], None],
) -> Generator[tuple[dict, dict | None], None, None]:
    """(row, summary) of ``jobs`` ((path, hash) each) as they finish; the cluster is closed whatever ends the
    iteration."""
    if scheduler == SYNCHRONOUS:
        on_cluster(1)
        for path, sha in jobs:
            yield identify_task(path, sha, *args)
        return
    from distributed import as_completed

    cluster = None
    if scheduler:
        client = _client_at(scheduler)
    else:
        cluster, client = _local_cluster(workers or os.cpu_count() or 1)
    try:
        on_cluster(len(client.scheduler_info().get("workers", {})))
        futures = {
            client.submit(identify_task, path, sha, *args, key=f"hilident-batch-{i}-{sha[:16]}", pure=False): (
                path,
                sha,
            )
            for i, (path, sha) in enumerate(jobs)
        }
        try:
            for future in as_completed(futures):
                try:
                    yield future.result()
                except Exception as exc:  # a worker lost (killed, out of memory): that recording's row says so
                    path, sha = futures[future]
                    yield fail(blank_row(path, sha, args[2]), exc), None
        finally:
            client.cancel(list(futures))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_batch(
    inputs: list[str],
    cfg,
    out: str | Path,
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    retry_failed: bool = False,
    progress=None,
) -> BatchOutcome:
    """Identify the recordings ``inputs`` name into ``out/batch.parquet`` (and ``batch.csv``), incrementally.

    Each analysis's ``summary.json`` is kept as :func:`summary_path` names it.

    Recordings whose (content hash, configuration hash) the table holds are
    skipped (failed ones too, unless ``retry_failed``); so is a second file of
    the same content, except an empty one (:func:`_row_key`). The rows of the others are appended. A Ctrl-C (or any
    ``KeyboardInterrupt``) stops the batch: the cluster is closed, the rows
    finished so far are written, and the interrupt is raised again with
    the :class:`BatchOutcome` as its ``outcome`` attribute.

    Parameters
    ----------
    inputs : list of str
        Files, folders and globs (:func:`hilident.batch.inputs.expand_inputs`).
    cfg : Config or None
        ``--config`` (None: each hilident recording's own configuration).
    out : path
        Folder of the table.
    scheduler : str, optional
        None: a local cluster; ``"synchronous"``: this process; else a Dask scheduler address.
    workers : int, optional
        Worker processes of the local cluster (default: one per core).

    Raises
    ------
    UsageError
        An input that names no recording, ``--workers`` with a scheduler, no scheduler at the address or
        no worker on it.
    DataError
        The table in ``out`` is there but cannot be read.
    """
    _check_workers(workers, scheduler)
    started = time.monotonic()
    started_utc = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    out = _table_folder(Path(out))
    paths = _input_recordings(inputs, out)
    old = read_rows(out)
    cfg_key = config_key(cfg)
    kept = _kept_rows(old, cfg_key, retry_failed)
    rows, jobs, skipped = _sort_inputs(paths, kept, cfg_key)
    outcome = BatchOutcome(out / TABLE_NAME, out / CSV_NAME, len(paths), skipped=skipped)
    if progress and outcome.skipped:
        progress.step(f"{outcome.skipped} of {len(paths)} recordings already in {out / TABLE_NAME}: skipped")
    args = _task_args(cfg, cfg_key)
    try:
        if jobs:
            _identify_jobs(jobs, args, scheduler, workers, outcome, rows, progress)
    except KeyboardInterrupt as exc:
        outcome.interrupted = True
        _finish(outcome, kept, rows, started)
        exc.outcome = outcome  # type: ignore[attr-defined]
        raise
    except HilidentError:
        if rows:  # what was finished stays
            _finish(outcome, kept, rows, started)
        raise
    _finish(outcome, kept, rows, started)
    meta = _table_meta(inputs, cfg, out, scheduler, started_utc, outcome)
    settings = cfg.batch if cfg is not None else BatchConfig()
    outcome.drifts = judge_fleet(out, kept + rows, settings, meta)
    outcome.report = out / "report.html"
    return outcome


def _check_workers(workers: int | None, scheduler: str | None) -> None:
    """Refuse ``--workers`` under 1, or given with a ``--scheduler`` (whose workers are its own)."""
    if workers is not None and (workers < 1 or scheduler):
        raise UsageError(
            "--workers: "
            + ("must be at least 1" if workers < 1 else "sizes the local cluster; a --scheduler's workers are its own")
        )


def _table_folder(out: Path) -> Path:
    """``out``, refused when it is a file: the table's folder."""
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {out}: is a file; give a folder for {TABLE_NAME} and {CSV_NAME}")
    return out


def _input_recordings(inputs: list[str], out: Path) -> list[Path]:
    """The recordings ``inputs`` name, but for the files in the table's folder ``out``."""
    own = out.resolve()
    return [p for p in expand_inputs(inputs) if not p.is_relative_to(own)]  # batch.csv is no recording


def _kept_rows(old: list[dict], cfg_key: str, retry_failed: bool) -> list[dict]:
    """The table's rows kept: all but, with ``retry_failed``, the failed ones of this configuration."""
    return [r for r in old if not (retry_failed and r["status"] != "ok" and r["config_sha256"] == cfg_key)]


def _sort_inputs(paths: list[Path], kept: list[dict], cfg_key: str) -> tuple[list[dict], list[tuple[str, str]], int]:
    """The recordings to identify, apart from those done already.

    Returns
    -------
    rows : list of dict
        A failed row for each file that cannot be read.
    jobs : list of (str, str)
        Path and content hash of each recording to identify.
    skipped : int
        Recordings the kept rows (or an earlier file of the same content) hold already.
    """
    known = {_row_key(r["path"], r["content_sha256"], r["config_sha256"]) for r in kept}
    rows: list[dict[str, Any]] = []
    jobs: list[tuple[str, str]] = []
    skipped = 0
    for path in paths:
        try:
            sha = content_sha256(path)
        except OSError as exc:
            rows.append(fail(blank_row(str(path), "", cfg_key), exc))
            continue
        key = _row_key(str(path), sha, cfg_key)
        if key in known:
            skipped += 1
            continue
        known.add(key)
        jobs.append((str(path), sha))
    return rows, jobs, skipped


def _task_args(cfg, cfg_key: str) -> tuple[str | None, str, str]:
    """What every task is given besides its recording: the configuration's text and source, and its hash."""
    return (cfg.text if cfg is not None else None, cfg.source if cfg is not None else "", cfg_key)


def _identify_jobs(
    jobs: list[tuple[str, str]],
    args: tuple,
    scheduler: str | None,
    workers: int | None,
    outcome: BatchOutcome,
    rows: list[dict],
    progress,
) -> None:
    """Identify ``jobs`` (path and content hash each), each row appended to ``rows`` as it finishes.

    ``scheduler`` and ``workers`` are :func:`run_batch`'s. Each summary is kept beside the table; ``outcome``
    gets the workers and the wall time from the cluster being up.
    """
    tally: list[_Tally] = []

    def on_cluster(n: int) -> None:
        outcome.workers = n
        if progress and jobs:
            progress.step(f"identifying {len(jobs)} recordings {_where(scheduler)} ({n} worker{'s' * (n != 1)})")
        tally.append(_Tally(progress, len(jobs), outcome.skipped))  # timed from here: the cluster is up

    with closing(_run_tasks(jobs, args, scheduler, workers, on_cluster)) as results:
        for row, summary in results:
            rows.append(row)
            if summary is not None:
                _keep_summary(summary_path(outcome.table.parent, row), summary)
            tally[0].add(row)
    outcome.identify_wall_s = time.monotonic() - tally[0].started


def _where(scheduler: str | None) -> str:
    """Where the tasks run, as the progress line says it."""
    return "in this process" if scheduler == SYNCHRONOUS else f"on {scheduler or 'a local cluster on 127.0.0.1'}"


def _table_meta(
    inputs: list[str], cfg, out: Path, scheduler: str | None, started_utc: str, outcome: BatchOutcome
) -> dict:
    """What the batch was and did, for the drift report beside the table."""
    return {
        "inputs": list(inputs),
        **({"config": cfg.source} if cfg is not None else {}),
        "out": str(out),
        "scheduler": scheduler or "local cluster",
        "workers": outcome.workers,
        "started_utc": started_utc,
        "wall_time_s": outcome.wall_s,
        "identified": outcome.done - outcome.failed,
        "failed": outcome.failed,
        "skipped": outcome.skipped,
    }


def _row_key(path: str, content_sha256: str, config_sha256: str) -> tuple[str, ...]:
    """What makes a recording done: its content and the configuration; an empty file's is its path too.

    Two files of the same content are one recording (a copy, a renamed file), but every empty file is a
    failure of its own: a night whose recorder wrote nothing must show in the table, however many did.
    """
    if content_sha256 == EMPTY_SHA256:
        return (content_sha256, config_sha256, path)
    return (content_sha256, config_sha256)


def _keep_summary(path: Path, summary: dict) -> None:
    from hilident.io.serialise import write_json

    try:
        write_json(path, summary)
    except OSError as exc:
        raise DataError(f"{path}: cannot write the recording's summary ({exc})") from None


def _finish(outcome: BatchOutcome, kept: list[dict], rows: list[dict], started: float) -> BatchOutcome:
    """Write the table (the kept rows, then this batch's in path order) and count what was done."""
    rows.sort(key=lambda r: r["path"])
    write_rows(outcome.table.parent, kept + rows)
    outcome.done = len(rows)
    outcome.failures = [r for r in rows if r["status"] != "ok"]
    outcome.failed = len(outcome.failures)
    outcome.task_s = sum(r["elapsed_s"] for r in rows if r["elapsed_s"] == r["elapsed_s"])  # NaN: no task ran
    outcome.wall_s = time.monotonic() - started
    return outcome
