"""``hilident batch`` on many recordings: a local Dask cluster against a plain loop, and a scheduler of its own.

It writes a fleet of ``--recordings`` recordings (``hilident emulate fleet``,
every axis at 1 kHz, ``--duration-s`` analysed seconds each, none damaged),
then identifies all of them three times, each time into a fresh table:

1. a plain loop in this one process (``--scheduler synchronous``): the reference;
2. a local cluster of ``--workers`` worker processes (the default of ``hilident batch``);
3. a Dask scheduler started as a separate process (``dask scheduler``) on
   127.0.0.1 with ``--workers`` workers of its own (``dask worker``, configured
   by the YAML file of the cluster recipe in docs/batch.md), given to the batch by
   address, as a cluster on other machines would be.

It prints for each the wall time, the cost per recording (wall time / recordings
and the mean time one task took in its worker), the speed-up against the loop
(target at least 1.8 on 2 cores) of the whole batch and of its identification
phase alone (from the cluster being up to the last result: the serial parts, hashing the
files, starting the cluster and drawing the drift report, are left out), the
peak resident memory of each worker process and the size of one recording, and checks that the three tables hold the
same resonances.

Usage::

    python bench/batch.py [--recordings 500] [--duration-s 60] [--workers 2] [--keep DIR]

Defaults are the issue's: 500 recordings of 60 s at 1 kHz (about 1.6 GB of
recordings written to a temporary folder; --keep keeps them and the tables).
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _isolate  # noqa: F401  (bench/ last on sys.path)

TARGET_SPEEDUP = 1.8
SAMPLE_RATE_HZ = 1000.0


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_recordings(folder: Path, recordings: int, duration_s: float) -> list[Path]:
    """A fleet of ``recordings`` recordings, 1 kHz, none damaged: 25 axes (or fewer) over enough days."""
    from hilident.batch.fleet import write_fleet

    axes = min(25, recordings)
    days = math.ceil(recordings / axes)
    write_fleet(folder, axes, days, duration_s=duration_s, damaged=0, sample_rates_hz=(SAMPLE_RATE_HZ,))
    files = sorted(folder.glob("axis-*/*.h5"))[:recordings]
    for extra in sorted(folder.glob("axis-*/*.h5"))[recordings:]:
        extra.unlink()
    return files


def run(label: str, inputs: list[str], out: Path, scheduler: str | None, workers: int | None):
    from hilident.batch.runner import run_batch
    from hilident.batch.table import read_rows

    started = time.perf_counter()
    outcome = run_batch(inputs, None, out, scheduler=scheduler, workers=workers)
    wall = time.perf_counter() - started
    rows = read_rows(out)
    if outcome.failed:
        raise SystemExit(f"{label}: {outcome.failed} recordings failed, e.g. {outcome.failures[0]}")
    return wall, outcome, rows


#: The worker settings hilident's local cluster uses (hilident.batch.runner.WORKER_SETTINGS), as the YAML file
#: the cluster recipe of docs/batch.md puts in a worker machine's Dask configuration folder.
WORKER_YAML = """\
distributed:
  nanny:
    pre-spawn-environ:
      MALLOC_TRIM_THRESHOLD_: null
  worker:
    profile:
      enabled: false
"""


def start_scheduler(workers: int, config_dir: Path) -> tuple[str, list[subprocess.Popen]]:
    """A ``dask scheduler`` process and a ``dask worker`` process of ``workers`` workers, all on 127.0.0.1,
    the workers configured from ``config_dir`` (:data:`WORKER_YAML`)."""
    config_dir.mkdir(parents=True, exist_ok=True)
    (config_dir / "hilident-workers.yaml").write_text(WORKER_YAML)
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    bindir = Path(sys.executable).parent
    dask = str(bindir / "dask") if (bindir / "dask").exists() else "dask"
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
    procs = [
        subprocess.Popen(
            [dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", "127.0.0.1:0"],
            **quiet,
        )
    ]
    time.sleep(1.0)
    procs.append(
        subprocess.Popen(
            [
                dask,
                "worker",
                address,
                "--nworkers",
                str(workers),
                "--nthreads",
                "1",
                "--host",
                "127.0.0.1",
                "--dashboard-address",
                "127.0.0.1:0",
            ],
            env={**os.environ, "DASK_CONFIG": str(config_dir)},
            **quiet,
        )
    )
    return address, procs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recordings", type=int, default=500)
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keep", type=Path, help="keep the recordings and tables in this folder")
    args = ap.parse_args(argv)

    root = args.keep or Path(tempfile.mkdtemp(prefix="hilident-bench-batch-"))
    try:
        t0 = time.perf_counter()
        files = write_recordings(root / "fleet", args.recordings, args.duration_s)
        size = files[0].stat().st_size
        print(
            f"{len(files)} recordings of {args.duration_s:g} s at {SAMPLE_RATE_HZ:g} Hz, {size / 1e6:.2f} MB each, "
            f"written in {time.perf_counter() - t0:.1f} s; {os.cpu_count()} cores"
        )
        inputs = [str(root / "fleet")]
        results = {}
        results["loop"] = run("loop", inputs, root / "loop", "synchronous", None)
        results["local"] = run("local", inputs, root / "local", None, args.workers)
        address, procs = start_scheduler(args.workers, root / "dask-config")
        try:
            results["scheduler"] = run("scheduler", inputs, root / "scheduler", address, None)
        finally:
            for p in reversed(procs):
                p.terminate()
            for p in procs:
                p.wait(timeout=30)
        report(results, len(files), size, args.workers)
    finally:
        if args.keep is None:
            shutil.rmtree(root, ignore_errors=True)
    return 0


def report(results: dict, n: int, size: int, workers: int) -> None:
    loop_wall, loop_identify = results["loop"][0], results["loop"][1].identify_wall_s
    print()
    print(
        f"{'run':<34} {'wall s':>8} {'s/rec':>7} {'task s':>7} {'speed-up':>9} {'identify s':>11} "
        f"{'speed-up':>9} {'peak RSS/worker MiB':>20}"
    )
    names = {
        "loop": "plain loop, one process",
        "local": f"local cluster, {workers} workers",
        "scheduler": f"dask scheduler process, {workers} workers",
    }
    for key, (wall, outcome, rows) in results.items():
        by_worker: dict[str, float] = {}
        for r in rows:
            w = str(r.get("worker", ""))
            by_worker[w] = max(by_worker.get(w, 0.0), float(r.get("worker_peak_rss_mib", float("nan"))))
        peaks = ", ".join(f"{v:.0f}" for _, v in sorted(by_worker.items()))
        print(
            f"{names[key]:<34} {wall:8.1f} {wall / n:7.3f} {outcome.mean_task_s:7.3f} "
            f"{loop_wall / wall:9.2f} {outcome.identify_wall_s:11.1f} "
            f"{loop_identify / outcome.identify_wall_s:9.2f} {peaks:>20}"
        )
    print(
        "\nwall: the whole batch (hashing, cluster start, identification, table, drift report);"
        "\nidentify: from the cluster being up to the last recording identified (the part the workers share)"
    )
    for what, loop_s, local_s in (
        ("whole batch", loop_wall, results["local"][0]),
        ("identification", loop_identify, results["local"][1].identify_wall_s),
    ):
        speedup = loop_s / local_s
        print(
            f"speed-up of the local cluster, {what}: {speedup:.2f} (target {TARGET_SPEEDUP}, "
            f"ratio {speedup / TARGET_SPEEDUP:.2f})"
        )
    print(f"one recording is {size / 2**20:.1f} MiB")
    ref = {r["content_sha256"]: r["frequency_hz"] for r in results["loop"][2]}
    for key in ("local", "scheduler"):
        other = {r["content_sha256"]: r["frequency_hz"] for r in results[key][2]}
        same = other.keys() == ref.keys() and all(
            other[k] == ref[k] or (math.isnan(other[k]) and math.isnan(ref[k])) for k in ref
        )
        print(f"{names[key]}: resonances identical to the plain loop's: {'yes' if same else 'NO'}")


if __name__ == "__main__":
    sys.exit(main())
