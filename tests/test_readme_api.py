"""The example of the documentation's Python API page (docs/api/index.md) runs as written, on a shortened copy
of the config it loads."""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import pytest
import tomli_w

pytestmark = pytest.mark.twin  # the example runs a session on the gantry twin

ROOT = Path(__file__).resolve().parents[1]
CONFIG = "configs/emulated-gantry.toml"


API_PAGE = ROOT / "docs" / "api" / "index.md"


def api_page_example() -> str:
    """The one ``python`` block of the Python API page."""
    blocks = re.findall(r"^```python\n(.*?)^```", API_PAGE.read_text(), re.S | re.M)
    assert len(blocks) == 1, f"expected one python block on {API_PAGE.name}, found {len(blocks)}"
    return blocks[0]


def quick_copy(folder: Path) -> None:
    """``folder/configs/emulated-gantry.toml``: the shipped config, shortened (no friction test, a fixed
    amplitude, two short periods, no verification run, faster simulated time, the clean twin)."""
    raw = tomllib.loads((ROOT / CONFIG).read_text())
    raw["friction_test"] = {"enabled": False}
    raw["excitation"].update(period_s=2.0, duration_s=4.0, amplitude_nm=8.0)
    raw["notch"]["verify"] = False
    raw["emulator"].update(time_scale=8.0, preset="clean")
    (folder / "configs").mkdir()
    (folder / CONFIG).write_text(tomli_w.dumps(json.loads(json.dumps(raw))))


def test_the_python_api_example_runs(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    code = api_page_example()
    assert f'load_config("{CONFIG}")' in code  # the copy below stands in for this file
    quick_copy(tmp_path)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "api_page_example"}
    try:
        exec(compile(code, "docs/api/index.md", "exec"), namespace)
        ax = namespace["ax"]
        assert ax.get_xlabel() == "time [s]"
        assert ax.get_ylabel() == "velocity_mps [m/s]"
        (line,) = ax.get_lines()
        run = namespace["run"]
        assert len(line.get_xdata()) == run.n_samples > 0
    finally:
        plt.close("all")

    summary, offline = namespace["summary"], namespace["offline"]
    assert (tmp_path / "runs" / "notebook" / "summary.json").is_file()
    assert not (tmp_path / "runs" / "notebook" / "bode.png").exists()  # plots=False
    assert summary["resonances"], summary["warnings"]
    truth = summary["resonances"][0]["frequency_hz"]
    assert offline["resonances"], offline["warnings"]
    assert offline["resonances"][0]["frequency_hz"] == pytest.approx(truth, rel=0.01)
    assert (tmp_path / "runs" / "notebook-offline" / "summary.json").is_file()
