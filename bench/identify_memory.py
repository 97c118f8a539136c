"""Peak memory of ``hilident identify`` on a large CSV recording, against the size of its data.

Writes a CSV of ``--rows`` rows (time, torque, velocity, position; a 1 kHz
record of a resonant axis under a multisine) into a temporary folder, then
measures two child processes: one that only reads the recording
(:func:`hilident.datafile.load_dataset`) and ``hilident identify`` on it.
For each it prints the peak resident memory (``ru_maxrss`` of that child),
the bytes per row and the time taken. The target is below 1.5 GB for 2·10⁷
rows.

Run by hand (it is not part of the test suite)::

    python bench/identify_memory.py --rows 20000000
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import signal

import _isolate  # noqa: F401  (first: bench/ off sys.path, see _isolate.py)

RATE = 1000.0
CHUNK = 1_000_000


def axis_filter():
    """A free mass with one resonance: torque (N·m) to velocity (m/s), discretised at :data:`RATE`."""
    m, f0, zeta = 50.0, 21.8, 0.02
    w = 2 * np.pi * f0
    num = [w**2 / m]
    den = np.polymul([1.0, 0.0], [1.0, 2 * zeta * w, w**2])
    b, a, _ = signal.cont2discrete((num, den), 1.0 / RATE, method="bilinear")
    return np.ravel(b), a


def write_csv(path: Path, rows: int) -> None:
    """``rows`` rows of ``t,tau,v,x`` in chunks (bounded memory)."""
    b, a = axis_filter()
    zi = np.zeros(max(len(a), len(b)) - 1)
    period = 4000
    k = np.arange(2, 320)
    phases = np.pi * k * (k - 1) / len(k)  # Schroeder phases: a low crest factor
    one = np.sum(np.cos(2 * np.pi * np.outer(np.arange(period), k) / period + phases), axis=1)
    one *= 4.0 / np.abs(one).max()
    x0 = 0.0
    with path.open("w") as fh:
        fh.write("t,tau,v,x\n")
        for start in range(0, rows, CHUNK):
            n = min(CHUNK, rows - start)
            i = np.arange(start, start + n)
            tau = one[i % period]
            v, zi = signal.lfilter(b, a, tau, zi=zi)
            v -= v.mean()  # keep the free axis near its start
            x = x0 + np.cumsum(v) / RATE
            x0 = x[-1]
            np.savetxt(fh, np.column_stack([i / RATE, tau, v, x]), delimiter=",", fmt="%.6f,%.6g,%.6g,%.6g")


def measure(argv: list[str]) -> tuple[int, int, float, str]:
    """Exit code, peak resident bytes, seconds and output of one child process."""
    env = dict(os.environ, MPLBACKEND="Agg")
    t0 = time.monotonic()
    with subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as child:
        output = child.stdout.read()
        _, status, usage = os.wait4(child.pid, 0)
        child.returncode = os.waitstatus_to_exitcode(status)
    return child.returncode, usage.ru_maxrss * 1024, time.monotonic() - t0, output  # Linux reports KiB


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rows", type=int, default=20_000_000)
    p.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = p.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="hilident-memory-"))
    data = folder / "big.csv"
    t0 = time.monotonic()
    write_csv(data, args.rows)
    print(f"wrote {args.rows} rows, {data.stat().st_size / 1e6:.0f} MB in {time.monotonic() - t0:.0f} s")
    config = folder / "identify.toml"
    config.write_text(
        '[data]\ntime = "t"\ntorque = "tau"\nvelocity = "v"\nposition = "x"\n'
        "[identification]\nmax_resonances = 1\nsegment_s = 4.0\n"
    )
    load = (
        "import sys; from hilident.config.tables import load_config; from hilident.datafile import load_dataset; "
        "c = load_config(sys.argv[1]); d = load_dataset(sys.argv[2], c.data); print(len(d), 'rows used')"
    )
    children = {
        "read only": [sys.executable, "-c", load, str(config), str(data)],
        "hilident identify": [
            sys.executable,
            "-m",
            "hilident.cli",
            "identify",
            str(data),
            "--config",
            str(config),
            "--out",
            str(folder / "out"),
            "-q",
        ],
    }
    samples = 4 * args.rows * 8
    print(f"{samples / 1e9:.2f} GB of float64 samples")
    for name, argv in children.items():
        code, peak, elapsed, output = measure(argv)
        print(
            f"{name}: exit {code}; {elapsed:.0f} s; peak RSS {peak / 1e9:.2f} GB ({peak / args.rows:.0f} bytes a row)"
        )
        print("  " + "\n  ".join(output.strip().splitlines()[-3:]))
    if not args.keep:
        for f in sorted(folder.rglob("*"), reverse=True):
            f.unlink() if f.is_file() else f.rmdir()
        folder.rmdir()
    else:
        print(f"kept {folder}")


if __name__ == "__main__":
    main()
