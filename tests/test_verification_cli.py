"""The run's verification line leads with the band figure, the at-resonance figure beside it."""

from pathlib import Path

import hilident.session.run
from hilident.cli.main import main

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "emulated-gantry.toml"


class _FakeSession:
    """Stands in for a session: returns a finished summary without a device."""

    def __init__(self, cfg, out, *args, **kwargs):
        self.out = out
        self.verification = {
            "band_reduction_db": 21.43,
            "peak_reduction_db": 32.51,
            "band_bandwidths": 2.0,
            "resonances": [],
        }

    def run(self):
        return {
            "resonances": [{"frequency_hz": 21.8, "damping_ratio": 0.018}],
            "friction": None,
            "model": None,
            "verification": self.verification,
            "upload": {"written": True},
            "stream": {"samples": 1, "lost_blocks": 0, "corrupt_frames": 0, "underruns": 0},
            "warnings": [],
        }


def test_verification_line_leads_with_the_band_figure(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(hilident.session.run, "Session", _FakeSession)
    assert main(["run", str(CONFIG), "--out", str(tmp_path), "-q", "--no-plots"]) == 0
    (line,) = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("verification:")]
    assert line.index("21.4 dB") < line.index("32.5 dB")
    assert "near the resonance" in line and "at the resonance line" in line
