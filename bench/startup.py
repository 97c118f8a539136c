"""Wall time from starting ``hilident`` to its answer, for commands that end early.

Each command runs ``--repeats`` times, every time in a fresh interpreter started
as the ``hilident`` console script starts it (``from hilident.cli.main import main``),
with this checkout's ``src`` first on ``PYTHONPATH``:

- ``run CONFIG`` on a shipped config with one value wrong that only the
  cross-checks at the end of loading find (``[excitation] f_max_hz`` above
  Nyquist): the time to a config error, target 0.3 s;
- ``--help``;
- ``identify MISSING.h5``, a recording that does not exist;
- ``python -c pass``, the interpreter alone, for scale.

Bytecode is cached (in a temporary folder) before anything is timed, as an
installed package has it. It prints the median, the fastest and slowest wall
time of each, the median CPU time (user + system: what the process itself
costs, whatever else the machine runs), the target and median / target, and
checks each command's exit code (2 for the config error, 0 for help, 3 for the
missing file). Other busy processes lengthen every wall time but not the CPU
time; compare with the interpreter's own line.

Usage::

    python bench/startup.py [--repeats 15] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 0.3
CLI = "import sys; from hilident.cli.main import main; sys.exit(main(sys.argv[1:]))"


def cases(folder: Path) -> list[tuple[str, list[str], int]]:
    """(name, interpreter arguments, expected exit code) of each measured command."""
    text = (ROOT / "configs" / "emulated-gantry.toml").read_text()
    if "f_max_hz = 80.0" not in text:
        raise SystemExit("configs/emulated-gantry.toml changed: no 'f_max_hz = 80.0' to break")
    bad = folder / "bad.toml"
    bad.write_text(text.replace("f_max_hz = 80.0", "f_max_hz = 800.0"))
    return [
        ("hilident run BAD.toml (config error)", ["-c", CLI, "run", str(bad)], 2),
        ("hilident --help", ["-c", CLI, "--help"], 0),
        ("hilident identify MISSING.h5", ["-c", CLI, "identify", str(folder / "missing.h5")], 3),
        ("python -c pass (interpreter only)", ["-c", "pass"], 0),
    ]


def child_environment(pycache: Path) -> dict[str, str]:
    """The measured processes' environment: this checkout first, and bytecode cached as an installed package has it.

    Without a cache every start compiles hilident's modules again
    (``PYTHONDONTWRITEBYTECODE`` is often set in development shells); the
    cache goes to ``pycache`` (``PYTHONPYCACHEPREFIX``), not into the source tree.
    """
    env = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT / "src"), os.environ.get("PYTHONPATH")]))
    env["PYTHONPYCACHEPREFIX"] = str(pycache)
    return env


def time_once(args: list[str], expected: int, cwd: Path, env: dict[str, str]) -> tuple[float, float]:
    """Wall and CPU time (user + system) of one fresh ``python ARGS``, s; exits unless it ends with ``expected``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=120)
    elapsed = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if done.returncode != expected:
        raise SystemExit(
            f"{' '.join(args[2:]) or args[-1]}: exit {done.returncode}, expected {expected}\n{done.stderr}"
        )
    return elapsed, cpu


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=15, help="fresh processes per command (default 15)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    results = []
    with tempfile.TemporaryDirectory(prefix="hilident-startup-") as tmp:
        folder = Path(tmp)
        env = child_environment(folder / "pycache")
        measured = cases(folder)
        for _, command, expected in measured:  # one unmeasured start each: bytecode caches written
            time_once(command, expected, folder, env)
        for name, command, expected in measured:
            runs = [time_once(command, expected, folder, env) for _ in range(args.repeats)]
            times = [wall for wall, _ in runs]
            median = statistics.median(times)
            results.append(
                {
                    "command": name,
                    "repeats": args.repeats,
                    "median_s": median,
                    "min_s": min(times),
                    "max_s": max(times),
                    "cpu_median_s": statistics.median(cpu for _, cpu in runs),
                    "target_s": TARGET_S,
                    "ratio": median / TARGET_S,
                }
            )
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(f"{'command':40s} {'median':>8s} {'min':>7s} {'max':>7s} {'cpu':>7s} {'target':>7s} {'ratio':>6s}")
    for r in results:
        print(
            f"{r['command']:40s} {r['median_s']:7.3f}s {r['min_s']:6.3f}s {r['max_s']:6.3f}s "
            f"{r['cpu_median_s']:6.3f}s {r['target_s']:6.2f}s {r['ratio']:6.2f}"
        )
    print(
        f"{args.repeats} fresh processes per command; wall times; cpu = median user + system time of the process; "
        f"ratio = median wall / target"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
