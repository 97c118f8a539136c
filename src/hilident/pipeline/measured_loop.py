"""The loop measured where the excitation breaks it: torque injection inside the closed cascade.

In ``torque_injection`` mode the drive closes both loops and adds the
excitation ``d`` to its controller's torque command; the recorded command
``e = d + c`` (before the filter slots) is what the controller's output ``c``
and the injection make together. Around the loop ``c = -L e``, so the
sensitivity is ``S = e / d`` and the open loop, broken at the torque command,
``L = d / e - 1`` (:meth:`hilident.control.Cascade.open_loop` with
``loop="torque"``). Each sample holds its injection over the ``D`` ticks of its
period; the lines of ``e / d`` are brought back to the tick through the
complementary sensitivity, whose images are small (:func:`measured_open_loop`).

Friction acts where the motor torque meets the plant: the command then also
holds ``K H F / (1 + L)`` (``K`` the controller from the encoder to the
command, ``F`` the friction torque). With the identified friction curve ``F``
of the recorded velocity gives that part, taken out before ``L`` is formed
(:func:`friction_in_command`), as the identification takes friction out of the
torque.

The measured ``L`` gives margins of its own, on its lines; the prediction from
the identified plant and the drive's parameters gives them on a dense grid.
Both are reported: a difference says the plant or the loop's description is
not what the drive runs.
"""

from __future__ import annotations

import numpy as np

from hilident.control import Cascade, loop_margins
from hilident.control.sampled import ticks_per_sample
from hilident.pipeline.loop_plant import SeenPlant

__all__ = ["SMALLEST_LOOP", "friction_in_command", "measured_loop_part", "measured_open_loop"]

#: The smallest ``|L|`` a line is read at: below it the recorded sensitivity differs from 1 by little more than
#: what the loop's images fold onto it, 1.
SMALLEST_LOOP = 0.1


def measured_open_loop(frequency_hz, sensitivity, loop_rate_hz: float, sample_rate_hz: float) -> np.ndarray:
    """``L`` at the tick from the recorded ``e / d`` (torque command over injection) per line, 1.

    The recorded ``S_rec = 1/D sum_k Hold(f_k) S(f_k)`` over the images ``f_k = f + k f_s``; the holds of the
    images add to ``D``, so ``1 - S_rec = 1/D sum_k Hold(f_k) T(f_k)`` with ``T = L / (1 + L)``, whose images
    are small (``T`` falls off above the crossover): ``T ~ (1 - S_rec) D / Hold`` and ``L = T / (1 - T)``.
    """
    f = np.asarray(frequency_hz, dtype=float)
    d = ticks_per_sample(loop_rate_hz, sample_rate_hz)
    zi = np.exp(-2j * np.pi * f / loop_rate_hz)
    hold = sum(zi**i for i in range(d))
    complementary = (1.0 - np.asarray(sensitivity)) * d / hold
    with np.errstate(divide="ignore", invalid="ignore"):
        return complementary / (1.0 - complementary)


def friction_in_command(cascade: Cascade, seen: SeenPlant, frequency_hz) -> np.ndarray:
    """Friction torque to the torque command in the closed cascade, ``K H / (1 + L)``, 1 (``K`` from the encoder
    to the command, before the filters and the current loop)."""
    f = np.asarray(frequency_hz, dtype=float)
    h = seen.at(f)[0]
    to_command = cascade.controller(f, "position") / cascade.torque_path(f)
    return to_command * h / (1.0 + cascade.open_loop(f, h, "torque"))


def _figures(f: np.ndarray, L: np.ndarray) -> dict:
    m = loop_margins(f, L)  # no set-point's response closes this loop: no bandwidth
    return {**m.to_dict(), "sensitivity_peak_db": m.sensitivity_peak_db, "bandwidth_hz": None}


def measured_loop_part(
    measured_frf,
    cascade: Cascade,
    seen: SeenPlant,
    sample_rate_hz: float,
    coherence_threshold: float,
    friction_frf=None,
) -> dict:
    """``summary.json["loop"]["measured"]``: the margins of the loop measured on its lines and of the one
    predicted (both loops closed, broken at the torque command), and how far the lines lie from the prediction
    where ``|L|`` is within 20 dB of 1 (where it decides the margins).

    Parameters
    ----------
    measured_frf : FrequencyResponse
        The recorded torque command over the injection, per line.
    cascade : Cascade
        The drive's cascade as it ran (its filters included).
    seen : SeenPlant
    coherence_threshold : float
        Lines below it are left out.
    friction_frf : FrequencyResponse, optional
        The identified friction of the recorded velocity over the injection, per line: its part of the
        command is taken out.
    """
    f = np.asarray(measured_frf.frequency_hz, dtype=float)
    keep = (f > 0) & np.isfinite(measured_frf.response) & (measured_frf.coherence >= coherence_threshold)
    f = f[keep]
    if f.size < 2:
        return {"loop": "torque", "lines": int(f.size), "note": "too few coherent lines to measure the loop"}
    sensitivity = np.asarray(measured_frf.response)[keep]
    if friction_frf is not None:
        sensitivity = sensitivity - friction_in_command(cascade, seen, f) * np.asarray(friction_frf.response)[keep]
    measured = measured_open_loop(f, sensitivity, cascade.loop_rate_hz, sample_rate_hz)
    readable = np.abs(measured) >= SMALLEST_LOOP
    f_read, measured_read = f[readable], measured[readable]
    predicted_lines = cascade.open_loop(f, seen.at(f)[0], "torque")
    near = (np.abs(predicted_lines) > 0.1) & (np.abs(predicted_lines) < 10.0)  # where L decides the margins
    ratio = measured[near] / predicted_lines[near] if near.any() else np.array([np.nan])
    below = seen.frequency_hz < cascade.loop_rate_hz / 2
    grid = seen.frequency_hz[below]
    return {
        "loop": "torque",
        "band_hz": [float(f[0]), float(f[-1])],
        "lines": int(f.size),
        "friction_removed": friction_frf is not None,
        "measured_lines": int(readable.sum()),
        "measured": _figures(f_read, measured_read) if f_read.size >= 2 else None,
        "predicted": _figures(grid, cascade.open_loop(grid, seen.response[below], "torque")),
        "compared_lines": int(near.sum()),
        "rms_gain_difference_db": float(np.sqrt(np.mean((20 * np.log10(np.abs(ratio))) ** 2))),
        "rms_phase_difference_deg": float(np.sqrt(np.mean(np.degrees(np.angle(ratio)) ** 2))),
        "note": (
            f"measured: the margins on the lines of {f[0]:.3g}-{f[-1]:.3g} Hz where |L| >= {SMALLEST_LOOP:g} (a "
            "crossing beyond them, or where the loop is smaller, is not seen); predicted: on the identified "
            "plant's dense grid"
        ),
    }
