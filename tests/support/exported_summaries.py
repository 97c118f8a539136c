"""One short emulated run, an identify of its recording and an upload of its notch: a summary.json of each kind.

Made once per test process (each takes a few seconds against the serial twin) and shared by the export and
summary-schema tests.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import tomli_w

from hilident.cli.main import main
from support.twins import quick

CONFIGS = Path(__file__).resolve().parents[2] / "configs"

_made: dict[str, Path] = {}


def summaries(folder: Path) -> dict[str, Path]:
    """``{"run": DIR, "identify": DIR, "upload": DIR}``, each holding its command's summary.json (made in ``folder``
    the first time)."""
    if _made:
        return _made
    raw = quick(tomllib.loads((CONFIGS / "emulated-gantry.toml").read_text()), "serial")
    raw["excitation"]["duration_s"] = 6.0
    raw["notch"]["verify"] = True
    raw["friction_test"] = {"enabled": True, "speeds_mps": [0.01, 0.05, 0.15], "hold_s": 0.5, "settle_s": 0.2}
    raw["model"] = {"kind": "rigid_axis"}  # the grey-box parameters with standard deviations
    config = folder / "run.toml"
    config.write_text(tomli_w.dumps(raw))
    dirs = {"run": folder / "run", "identify": folder / "identify", "upload": folder / "upload"}
    assert main(["run", str(config), "--out", str(dirs["run"]), "-q", "--no-plots"]) == 0
    assert main(["identify", str(dirs["run"] / "identification.h5"), "--out", str(dirs["identify"]), "-q"]) == 0
    assert (
        main(["upload", "--from", str(dirs["identify"]), "--config", str(config), "--out", str(dirs["upload"]), "-q"])
        == 0
    )
    _made.update(dirs)
    return _made


def load(folder: Path) -> dict:
    return json.loads((folder / "summary.json").read_text())
