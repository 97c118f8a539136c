"""What evidence a resonance needs before it gets a notch, and how much more excitation would give it."""

from __future__ import annotations

import numpy as np

from hilident.ident.resonance import Resonance


def coherence_amplitude_factor(coherence: float, target: float) -> float:
    """Factor on the excitation amplitude that lifts `coherence` to `target` when the noise stays as measured.

    Coherence is ``SNR / (1 + SNR)`` with the power ratio ``SNR`` growing as
    the amplitude squared, so the factor is
    ``sqrt((t / (1 - t)) / (c / (1 - c)))``. NaN for a coherence of 0 or 1.
    """
    c, t = float(coherence), min(float(target), 0.999)
    if not (0.0 < c < 1.0):
        return float("nan")
    return float(np.sqrt((t / (1.0 - t)) / (c / (1.0 - c))))


#: A notch needs the local fit's error within this many times the scatter of each bin
#: (:attr:`Resonance.local_fit_ratio`), or, without coherence, within NOTCH_FIT_FLOOR_DB rms.
NOTCH_FIT_NOISE_RATIO = 3.0
NOTCH_FIT_FLOOR_DB = 1.0
#: A notch needs the 95 % interval of its resonance's frequency within this fraction of the frequency either side
#: (the precision a notch is placed with and verified against): a damped mode's half-power bandwidth alone would
#: allow an interval of +-zeta, several per cent.
NOTCH_FREQUENCY_TOLERANCE = 0.005


def interval_eligibility(res: Resonance) -> dict:
    """Whether a resonance's frequency is known well enough for a notch: :func:`notch_eligibility` without its
    check of the local fit (for a mode whose evidence is of another kind, such as the stabilisation of a fit over
    several inputs and outputs).

    A notch needs a resonance with a 95 % frequency interval (full width ``2 frequency_ci95_hz``) narrower than
    its half-power bandwidth ``2 zeta f`` and within :data:`NOTCH_FREQUENCY_TOLERANCE` of the frequency either
    side; ``method`` must be ``"fit"`` (a fitted pole pair, not a peak read off the grid).

    Returns
    -------
    dict
        As :func:`notch_eligibility`.
    """
    out = {"frequency_hz": res.frequency_hz, "notchable": False, "reason": "", "amplitude_factor": float("nan")}
    if res.method != "fit" or not np.isfinite(res.frequency_ci95_hz):
        out["reason"] = (
            f"no local fit of the peak at {res.frequency_hz:.4g} Hz (method {res.method!r}): "
            "its frequency and damping are read off the frequency grid"
        )
        return out
    interval, bandwidth = 2.0 * res.frequency_ci95_hz, res.bandwidth_hz
    tolerance_hz = NOTCH_FREQUENCY_TOLERANCE * res.frequency_hz
    factor = float(max(1.0, 2.0 * interval / bandwidth))
    out["amplitude_factor"] = factor
    if not interval < bandwidth:
        out["reason"] = (
            f"the 95 % interval of its frequency ({res.frequency_hz:.4g} +- "
            f"{res.frequency_ci95_hz:.3g} Hz) is not narrower than its half-power bandwidth "
            f"({bandwidth:.3g} Hz): a notch could miss it"
        )
        return out
    if not res.frequency_ci95_hz <= tolerance_hz:
        out["amplitude_factor"] = float(max(factor, 2.0 * res.frequency_ci95_hz / tolerance_hz))
        out["reason"] = (
            f"the 95 % interval of its frequency ({res.frequency_hz:.4g} +- "
            f"{res.frequency_ci95_hz:.3g} Hz) is wider than +-{100 * NOTCH_FREQUENCY_TOLERANCE:g} % "
            "of it: the notch could sit off the mode by more than that"
        )
        return out
    out["notchable"] = True
    return out


def notch_eligibility(res: Resonance) -> dict:
    """Whether a resonance may be notched, and why not.

    A notch needs a resonance from a local fit whose 95 % frequency interval
    (full width ``2 frequency_ci95_hz``) is narrower than its half-power
    bandwidth ``2 zeta f`` and within :data:`NOTCH_FREQUENCY_TOLERANCE` of
    the frequency either side, and whose fit error is within
    :data:`NOTCH_FIT_NOISE_RATIO` times the scatter of each bin
    (``local_fit_ratio``; without coherence, :data:`NOTCH_FIT_FLOOR_DB` rms).

    Returns
    -------
    dict
        ``frequency_hz``, ``notchable`` (bool), ``reason`` ("" when
        notchable) and ``amplitude_factor``: by how much the excitation
        amplitude would have to grow for the interval to be half the bandwidth
        (and, when it is wider than the tolerance, half the tolerance; the
        interval shrinks as ``1 / (amplitude sqrt(averages))`` while the noise
        dominates; 1.0 when nothing needs to change, NaN when unknown).
    """
    out = interval_eligibility(res)
    if not out["notchable"]:
        return out
    out["notchable"] = False
    if np.isfinite(res.local_fit_ratio):
        if not res.local_fit_ratio <= NOTCH_FIT_NOISE_RATIO:
            out["reason"] = (
                f"the local fit misses the measured peak by {res.local_fit_ratio:.1f} times the "
                f"scatter of the estimate ({res.local_fit_db_rms:.2f} dB rms; allowed "
                f"{NOTCH_FIT_NOISE_RATIO:g} times): the peak is not one clean mode"
            )
            return out
    elif not res.local_fit_db_rms <= NOTCH_FIT_FLOOR_DB:
        out["reason"] = (
            f"the local fit misses the measured peak by {res.local_fit_db_rms:.2f} dB rms (allowed "
            f"{NOTCH_FIT_FLOOR_DB:g} dB without a coherence to judge it by): the peak is not one "
            "clean mode"
        )
        return out
    out["notchable"] = True
    return out
