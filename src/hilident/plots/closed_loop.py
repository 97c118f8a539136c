"""``closed-loop.png``: the closed loop measured after a gain upload, overlaid on its prediction.

Left, the velocity set-point's response on the multisine's lines (magnitude and
phase), measured and predicted; right, one period of the velocity steps,
set-point, measured and predicted, with the rms difference in the title.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from hilident.pipeline.closed_loop import ClosedLoopCheck
from hilident.pipeline.step_check import StepCheck
from hilident.plots.common import plain_number, save

__all__ = ["plot_closed_loop"]


def plot_closed_loop(
    path: str | os.PathLike, check: ClosedLoopCheck, step: StepCheck | None = None, title: str = ""
) -> Path:
    """Draw the comparison into ``path`` (PNG); returns the path."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter, NullFormatter

    fig = Figure(figsize=(11.0, 5.0), dpi=110, layout="constrained")
    grid = fig.add_gridspec(2, 2 if step is not None else 1)
    gain, phase = fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[1, 0])
    f = check.frequency_hz
    for response, label, style in ((check.measured, "measured", "o"), (check.predicted, "predicted", "-")):
        gain.semilogx(f, 20 * np.log10(np.abs(response)), style, ms=3, label=label)
        phase.semilogx(f, np.degrees(np.unwrap(np.angle(response))), style, ms=3, label=label)
    gain.set_ylabel("|velocity / set-point| (dB)")
    phase.set_ylabel("phase (deg)")
    phase.set_xlabel("frequency (Hz)")
    gain.set_title(f"multisine: {int(check.outside.sum())} of {f.size} lines beyond their tolerance")
    gain.legend()
    for ax in (gain, phase):
        ax.grid(True, which="both", alpha=0.3)
        ax.xaxis.set_major_formatter(FuncFormatter(plain_number))
        ax.xaxis.set_minor_formatter(NullFormatter())
    if step is not None:
        ax = fig.add_subplot(grid[:, 1])
        ax.plot(step.time_s, step.setpoint, color="0.6", label="set-point")
        ax.plot(step.time_s, step.measured, label=f"measured (mean of {step.periods} periods)")
        ax.plot(step.time_s, step.predicted, "--", label="predicted")
        ax.set_xlabel("time in the period (s)")
        ax.set_ylabel("velocity (m/s)")
        ax.set_title(f"velocity steps: rms difference {100 * step.rms_error:.1f} % of the step")
        ax.legend()
        ax.grid(True, alpha=0.3)
    if title:
        fig.suptitle(title)
    return save(fig, path)
