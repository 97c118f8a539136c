"""What the notches achieved: measured reductions, the record's noise floor, the section a device stores."""

from __future__ import annotations

import numpy as np

from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.filters.parametric import attenuation_db
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.frfquality import estimate_error_std
from hilident.pipeline.notches import NotchDesign, band_of


def peak_reductions(before: FrequencyResponse, after: FrequencyResponse, resonances, band_bandwidths: float = 2.0):
    """Measured reduction of each resonance between two runs with the same excitation.

    Both responses come from measurements; the notch design does not enter the
    numbers. For each resonance two figures are reported:

    * ``band_reduction_db`` (the headline): largest ``|before|`` over largest
      ``|after|`` within ``band_bandwidths`` half-power bandwidths
      (``2 zeta f``) either side of the resonance (:func:`~hilident.pipeline.notches.band_of`). It counts
      the skirts a notch leaves and a peak that moved: it is what the Bode
      plot shows a person;
    * ``reduction_db`` (``peak_reduction_db`` in the summary): ``|before| /
      |after|`` at the identified resonance frequency (nearest line).

    Returns
    -------
    list of dict
        ``frequency_hz``, ``before_db``, ``after_db``, ``reduction_db``,
        ``band_hz``, ``band_before_db``, ``band_after_db``,
        ``band_reduction_db`` per resonance.
    """
    f = before.frequency_hz
    mag_before = np.abs(before.response)
    mag_after = np.abs(after.response)
    if len(after.frequency_hz) != len(f) or not np.allclose(after.frequency_hz, f):
        # e.g. a shorter verification record: compare on the identification's lines
        if f[0] < after.frequency_hz[0] or f[-1] > after.frequency_hz[-1]:
            raise DataError("the verification response does not cover the identification's frequencies")
        mag_after = np.exp(np.interp(np.log(f), np.log(after.frequency_hz), np.log(np.maximum(mag_after, 1e-300))))
    mag_after = np.maximum(mag_after, 1e-300)
    out = []
    for res in resonances:
        i = int(np.argmin(np.abs(f - res.frequency_hz)))
        lo, hi = band_of(res.frequency_hz, res.damping_ratio, band_bandwidths)
        band = np.flatnonzero((f >= lo) & (f <= hi))
        band = band if len(band) else np.array([i])
        b_db, a_db = 20 * np.log10(mag_before[i]), 20 * np.log10(mag_after[i])
        band_b, band_a = 20 * np.log10(mag_before[band].max()), 20 * np.log10(mag_after[band].max())
        out.append(
            {
                "frequency_hz": float(f[i]),
                "before_db": float(b_db),
                "after_db": float(a_db),
                "reduction_db": float(b_db - a_db),
                "band_hz": [float(lo), float(hi)],
                "band_before_db": float(band_b),
                "band_after_db": float(band_a),
                "band_reduction_db": float(band_b - band_a),
            }
        )
    return out


#: Attenuation reported for an exact zero of a stored section (-20 log10 1e-300), dB
_DEEPEST_DB = 6000.0


#: Euler's constant: ``sqrt(ln K + gamma)`` approximates the largest of ``K`` complex Gaussian errors over their rms.
_EULER_GAMMA = 0.5772156649015329


#: A band figure within this of its record's noise floor (:func:`band_floor_db`) is floor-limited, dB.
FLOOR_HEADROOM_DB = 6.0


def floor_limited(band_reduction_db: float, floor_db: float) -> bool:
    """Whether a band figure lies within :data:`FLOOR_HEADROOM_DB` of its record's noise floor: it then says more
    about the record than about the notch (a floor of -inf, a record without coherence, always is)."""
    return bool(floor_db < band_reduction_db + FLOOR_HEADROOM_DB)


def shortfall_warning(row: dict, band_bandwidths: float, min_reduction_db: float, where: str = "") -> str | None:
    """The warning for a verification row whose band figure fell short of ``notch.min_reduction_db`` (None when it
    did not), saying when the record's own noise floor (``row["floor_db"]``, ``floor_limited``) is the reason.

    ``where`` names what the row measured (``"node 2: "``), before the figures.
    """
    if row["band_reduction_db"] >= min_reduction_db:
        return None
    floor = (
        f"; it is within {FLOOR_HEADROOM_DB:g} dB of the {row['floor_db']:.1f} dB its record's noise lets it show: "
        "a verification of more periods ([excitation] duration_s) lowers that floor"
        if row.get("floor_limited") and np.isfinite(row.get("floor_db", np.nan))
        else ""
    )
    return (
        f"verification: {where}the largest response within +-{band_bandwidths:g} half-power bandwidths of "
        f"{row['frequency_hz']:.4g} Hz dropped by only {row['band_reduction_db']:.1f} dB (at the resonance line: "
        f"{row['reduction_db']:.1f} dB; notch.min_reduction_db = {min_reduction_db:g}){floor}"
    )


def band_floor_db(
    before: FrequencyResponse, after: FrequencyResponse, resonance, band_bandwidths: float = 2.0
) -> float:
    """The largest band figure (:func:`peak_reductions`) the `after` measurement's own noise lets it show, dB.

    A notch takes the response near the mode down, but not what the output
    does that the excitation does not explain: noise, and forces that enter
    behind the filter slots (on the load, say) and drive the mode, which the
    notch may even leave less damped than before. `after` is measured through
    it. Its error per line (:func:`~hilident.ident.frfquality.estimate_error_std`)
    is pooled over the band (rms), and the largest of the band's ``K`` lines'
    errors is expected near ``rms * sqrt(ln K + 0.577)``; the floor is the
    largest ``|before|`` in the band over that. A measured band figure within a
    few dB of its floor says more about the measurement than about the notch:
    longer records lower the floor by 10 dB per tenfold the averages.

    Returns
    -------
    float
        dB; inf when `after` has no noise, NaN when its estimator gives no
        coherence or no line falls in the band.
    """
    lo, hi = band_of(resonance.frequency_hz, resonance.damping_ratio, band_bandwidths)
    in_band = (after.frequency_hz >= lo) & (after.frequency_hz <= hi)
    in_before = (before.frequency_hz >= lo) & (before.frequency_hz <= hi)
    if not in_band.any() or not in_before.any():
        return float("nan")
    errors = estimate_error_std(after)[in_band]
    if not np.all(np.isfinite(errors)):
        return float("nan") if np.isnan(errors).any() else float("-inf")
    rms = float(np.sqrt(np.mean(errors**2)))
    if rms == 0.0:
        return float("inf")
    expected_max = rms * np.sqrt(np.log(in_band.sum()) + _EULER_GAMMA)
    return float(20.0 * np.log10(np.abs(before.response[in_before]).max() / expected_max))


def achieved_notch(design: NotchDesign, stored: Biquad, planned: Biquad | None = None) -> dict:
    """What the section a device stores actually does, next to what was designed.

    A device rounds what it is sent: coefficients to REAL32, fixed point or
    scaled integers; physical notch parameters to its grid (a centre in 1 Hz
    steps, a width from a table). For a notch far below the filter rate that
    rounding can move the notch. This reports where the stored section's
    minimum lies and its attenuation at the designed centre, computed from the
    stored section.

    Parameters
    ----------
    design : NotchDesign
        The notch asked for (centre, width and depth) and its filter rate.
    stored : Biquad
        The section the device runs, from what it reads back.
    planned : Biquad, optional
        The section the host expected the device to store (the design after
        the device's quantisation, before anything was written).

    Returns
    -------
    dict
        ``center_hz`` (deepest point within half an octave, Hz), ``depth_db``
        (its attenuation), ``attenuation_at_design_center_db``,
        ``depth_error_db`` (that attenuation minus the designed depth, dB),
        ``dc_gain``, ``stable``; with ``planned`` also ``realisable_db`` (the
        planned section's attenuation at the designed centre: the design minus
        the device's quantisation), ``quantisation_loss_db`` (designed depth
        minus ``realisable_db``) and ``beyond_quantisation_db``
        (``realisable_db`` minus the stored attenuation: zero when the device
        holds what was planned).
    """
    f0, fs = design.spec.center_hz, design.sample_rate_hz

    def attenuation(section: Biquad) -> float:  # finite at an exact zero, for summary.json
        return min(attenuation_db(section, f0, fs), _DEEPEST_DB)

    grid = np.linspace(0.5 * f0, 1.5 * f0, 4001)
    mag = np.abs(stored.response(grid, fs))
    at_center = attenuation(stored)
    out = {
        "center_hz": float(grid[int(np.argmin(mag))]),
        "depth_db": float(-20 * np.log10(max(mag.min(), 1e-300))),
        "attenuation_at_design_center_db": at_center,
        "depth_error_db": at_center - float(design.spec.depth_db),
        "dc_gain": float(stored.dc_gain()),
        "stable": bool(stored.is_stable()),
    }
    if planned is not None:
        realisable = attenuation(planned)
        out.update(
            realisable_db=realisable,
            quantisation_loss_db=float(design.spec.depth_db) - realisable,
            beyond_quantisation_db=realisable - at_center,
        )
    return out
