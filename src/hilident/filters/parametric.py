"""Notches a drive builds from physical parameters, and what a stored section achieves.

Drives that take a notch as physical parameters run their own arithmetic on
them.  This module holds those formulas as plain functions, so the host (to
predict) and the emulated drive (to run) compute the same section:

* :func:`two_frequency_section` -- a general second-order filter given by a
  numerator natural frequency and damping and a denominator natural frequency
  and damping (Siemens-style "general 2nd-order filter"; Kollmorgen-style
  anti-resonance pole/zero pairs with ``damping = 1 / (2 Q)``), discretised by
  the bilinear transform with the numerator pre-warped at its own frequency and
  the denominator at its own, so the digital zeros and poles keep the analog
  natural frequencies.
* :func:`rejection_band_section` -- the Synapticon-style full-depth notch from a
  centre and a rejection band (the vendor's published discrete formula).
* :func:`center_ratio_section` -- the Beckhoff AX2000-style bi-quad given by a
  centre frequency, a pole/zero frequency ratio, a centre damping and a damping
  ratio (:func:`anti_resonance_pair` turns them into the zeros' and poles'
  frequencies and dampings; the split is an assumption, see there), then
  :func:`two_frequency_section`.
* :func:`achieved_notch` -- the centre, width and depth a stored section really
  has (the inverse of :func:`~hilident.filters.notch.design_notch`).

Examples
--------
>>> from hilident.filters.notch import NotchSpec, design_notch
>>> bq = design_notch(NotchSpec(120.0, 20.0, 30.0), 4000.0)
>>> got = achieved_notch(bq, 4000.0, 120.0)
>>> round(got.center_hz, 6), round(got.width_hz, 6), round(got.depth_db, 6)
(120.0, 20.0, 30.0)
"""

from __future__ import annotations

import math

import numpy as np

from hilident.errors import DataError
from hilident.filters.biquad import Biquad
from hilident.filters.notch import NotchSpec

__all__ = [
    "achieved_notch",
    "anti_resonance_pair",
    "attenuation_db",
    "center_ratio_section",
    "notch_width_hz",
    "rejection_band_section",
    "two_frequency_section",
]


def _warp_gain(frequency_hz: float, sample_rate_hz: float) -> float:
    """``K = w / tan(w T / 2)``: the bilinear constant that keeps ``frequency_hz`` in place."""
    if not 0.0 < frequency_hz < 0.5 * sample_rate_hz:
        raise DataError(
            f"frequency {frequency_hz:g} Hz is not between 0 and half the {sample_rate_hz:g} Hz filter rate"
        )
    w = 2.0 * math.pi * frequency_hz
    return w / math.tan(w / (2.0 * sample_rate_hz))


def _bilinear_quadratic(f_hz: float, damping: float, k: float) -> tuple[float, float, float]:
    """``s^2 / w^2 + 2 D s / w + 1`` with ``s = k (z - 1) / (z + 1)``, times ``(z + 1)^2``, in powers of ``z^-1``."""
    w = 2.0 * math.pi * f_hz
    c2, c1 = (k / w) ** 2, 2.0 * damping * k / w
    return (c2 + c1 + 1.0, 2.0 * (1.0 - c2), c2 - c1 + 1.0)


def two_frequency_section(zero_hz, zero_damping, pole_hz, pole_damping, sample_rate_hz) -> Biquad:
    """Digital section of ``(s^2/wz^2 + 2 Dz s/wz + 1) / (s^2/wp^2 + 2 Dp s/wp + 1)``.

    Each quadratic goes through the bilinear transform pre-warped at its own
    natural frequency, so the section's zeros sit at ``zero_hz`` and its poles
    at ``pole_hz`` exactly, whatever the sample rate; the DC gain is 1.  With
    ``zero_hz == pole_hz`` this is the pre-warped Tustin notch of
    :func:`~hilident.filters.notch.design_notch` with ``width_hz = 2 Dp f`` and
    ``depth_db = 20 log10(Dp / Dz)``.

    Parameters
    ----------
    zero_hz, pole_hz : float
        Natural frequencies of numerator and denominator in Hz, below half the rate.
    zero_damping, pole_damping : float
        Damping ratios (``1 / (2 Q)``); ``zero_damping = 0`` puts the zeros on the
        unit circle, ``pole_damping`` must be positive.
    sample_rate_hz : float
        Rate the section runs at, Hz.

    Raises
    ------
    DataError
        A frequency at or beyond half the rate, a negative damping, or an
        unstable section.
    """
    if not (zero_damping >= 0.0 and pole_damping > 0.0) or not all(map(math.isfinite, (zero_damping, pole_damping))):
        raise DataError(
            f"damping ratios must be finite, zero >= 0 and pole > 0, got {zero_damping!r}, {pole_damping!r}"
        )
    num = _bilinear_quadratic(zero_hz, zero_damping, _warp_gain(zero_hz, sample_rate_hz))
    den = _bilinear_quadratic(pole_hz, pole_damping, _warp_gain(pole_hz, sample_rate_hz))
    section = Biquad((num[0] / den[0], num[1] / den[0], num[2] / den[0]), (1.0, den[1] / den[0], den[2] / den[0]))
    if not section.is_stable():
        raise DataError(
            f"section with poles at {pole_hz:g} Hz (damping {pole_damping:g}) is unstable at {sample_rate_hz:g} Hz"
        )
    return section


def anti_resonance_pair(center_hz, ratio, center_damping, damping_ratio) -> tuple[float, float, float, float]:
    """Zeros' and poles' natural frequencies (Hz) and dampings of a centre/ratio bi-quad (Beckhoff AX2000-style).

    Beckhoff documents the parameters of the AX2000's bi-quad (BQFC the centre
    frequency ``sqrt(w_AR w_R)``, BQFR the ratio ``w_R / w_AR``, BQDC a centre
    damping, BQDR a damping ratio), not its transfer function.  Assumed here:
    the zeros sit at the anti-resonance ``w_AR`` and the poles at ``w_R``, and
    the two dampings are centred geometrically like the two frequencies::

        f_AR = center / sqrt(ratio),        f_R = center * sqrt(ratio)
        D_AR = center_damping / sqrt(damping_ratio),  D_R = center_damping * sqrt(damping_ratio)

    so ``ratio = 1`` puts zeros and poles on one frequency (a notch whose depth
    at the centre is ``damping_ratio``, ``20 log10(damping_ratio)`` dB), and
    ``ratio = damping_ratio = 1`` is the identity.

    Parameters
    ----------
    center_hz : float
        Centre frequency, Hz (positive).
    ratio : float
        Poles' frequency over the zeros' (positive).
    center_damping : float
        Geometric mean of the two dampings (positive).
    damping_ratio : float
        Poles' damping over the zeros' (positive).

    Returns
    -------
    zero_hz, zero_damping, pole_hz, pole_damping : float
        The arguments of :func:`two_frequency_section`, Hz and dimensionless.

    Raises
    ------
    DataError
        A parameter that is not a finite positive number.
    """
    values = (center_hz, ratio, center_damping, damping_ratio)
    if not all(math.isfinite(v) and v > 0.0 for v in values):
        raise DataError(
            "centre frequency, frequency ratio, centre damping and damping ratio must be finite and positive, "
            f"got {center_hz!r}, {ratio!r}, {center_damping!r}, {damping_ratio!r}"
        )
    f, d = math.sqrt(ratio), math.sqrt(damping_ratio)
    return center_hz / f, center_damping / d, center_hz * f, center_damping * d


def center_ratio_section(center_hz, ratio, center_damping, damping_ratio, sample_rate_hz) -> Biquad:
    """Digital section of the centre/ratio bi-quad (Beckhoff AX2000-style BQFC, BQFR, BQDC, BQDR).

    :func:`anti_resonance_pair` (an assumed split, see there), discretised by
    :func:`two_frequency_section` (bilinear, each quadratic pre-warped at its
    own frequency: also an assumption, Beckhoff does not document it).

    Parameters
    ----------
    center_hz : float
        Centre frequency, Hz.
    ratio, center_damping, damping_ratio : float
        Frequency ratio, centre damping and damping ratio (dimensionless).
    sample_rate_hz : float
        Rate the section runs at, Hz.

    Raises
    ------
    DataError
        A parameter that is not a finite positive number, or a zero or pole
        frequency at or beyond half the rate.

    Examples
    --------
    >>> from hilident.filters.parametric import attenuation_db
    >>> round(attenuation_db(center_ratio_section(300.0, 1.0, 0.3, 5.0, 4000.0), 300.0, 4000.0), 2)
    13.98
    """
    return two_frequency_section(*anti_resonance_pair(center_hz, ratio, center_damping, damping_ratio), sample_rate_hz)


def rejection_band_section(center_hz, band_hz, sample_rate_hz) -> Biquad:
    """Synapticon-style notch: zeros on the unit circle at ``center_hz``, pole radius ``1 - 3 band / rate``.

    The vendor's formula (object 0x2023), with ``f = center_hz / rate`` and
    ``BW = band_hz / rate``::

        R = 1 - 3 BW,  K = (1 - 2 R cos(2 pi f) + R^2) / (2 - 2 cos(2 pi f))
        b = K (1, -2 cos(2 pi f), 1),  a = (1, -2 R cos(2 pi f), R^2)

    (scipy sign convention; the vendor writes ``+ b1 y[k-1] + b2 y[k-2]`` with
    ``b1 = 2 R cos``, ``b2 = -R^2``).  ``K`` makes the DC gain 1.  The -3 dB width
    is close to ``3 band_hz / pi`` for narrow bands.

    Raises
    ------
    DataError
        ``center_hz`` not between 0 and half the rate, or a band so wide that
        the pole radius is not in ``(0, 1)``.
    """
    if not 0.0 < center_hz < 0.5 * sample_rate_hz:
        raise DataError(
            f"notch centre {center_hz:g} Hz is not between 0 and half the {sample_rate_hz:g} Hz filter rate"
        )
    r = 1.0 - 3.0 * band_hz / sample_rate_hz
    if not 0.0 < r < 1.0:
        raise DataError(
            f"rejection band {band_hz:g} Hz gives pole radius {r:g} at {sample_rate_hz:g} Hz (must be between 0 and 1)"
        )
    c = math.cos(2.0 * math.pi * center_hz / sample_rate_hz)
    k = (1.0 - 2.0 * r * c + r * r) / (2.0 - 2.0 * c)
    return Biquad((k, -2.0 * k * c, k), (1.0, -2.0 * r * c, r * r))


def attenuation_db(section: Biquad, frequency_hz: float, sample_rate_hz: float) -> float:
    """``-20 log10 |H(f)|`` in dB (positive for attenuation, ``inf`` at an exact zero)."""
    mag = float(abs(section.response(np.array([frequency_hz]), sample_rate_hz)[0]))
    return math.inf if mag == 0.0 else -20.0 * math.log10(mag)


def achieved_notch(section: Biquad, sample_rate_hz: float, near_hz: float) -> NotchSpec:
    """Centre, width and depth of the notch ``section`` really is, near ``near_hz``.

    Centre: the deepest point within a factor 1.5 of ``near_hz``.  Depth: the
    attenuation there.  Width: ``-(s1 + s2) / (2 pi)`` with ``s1, s2`` the
    section's poles mapped back to the s-plane by the bilinear transform
    pre-warped at the centre -- for a section from
    :func:`~hilident.filters.notch.design_notch` exactly its ``width_hz``.

    Raises
    ------
    DataError
        The section has no attenuation near ``near_hz`` (not a notch there).
    """
    nyq = 0.5 * sample_rate_hz
    lo, hi = near_hz / 1.5, min(near_hz * 1.5, nyq * 0.99999)
    grid = np.geomspace(lo, hi, 801)
    mag = np.abs(section.response(grid, sample_rate_hz))
    i = int(np.argmin(mag))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    import scipy.optimize  # here: an adapter that never realises a parametric notch starts without it

    res = scipy.optimize.minimize_scalar(
        lambda f: abs(section.response(f, sample_rate_hz)),
        bounds=(a, b),
        method="bounded",
        options={"xatol": 1e-9 * near_hz},
    )
    center = float(res.x) if res.fun <= mag[i] else float(grid[i])
    depth = attenuation_db(section, center, sample_rate_hz)
    if not depth > 0.0:
        raise DataError(f"the section does not attenuate near {near_hz:g} Hz")
    width = notch_width_hz(section, sample_rate_hz, center)
    if not width > 0.0:
        raise DataError(f"the section's poles give no positive width near {near_hz:g} Hz")
    return NotchSpec(center, width, depth)


def notch_width_hz(section: Biquad, sample_rate_hz: float, center_hz: float) -> float:
    """Width parameter (Hz) of the section's poles seen from ``center_hz``.

    ``-(s1 + s2) / (2 pi)`` with ``s1, s2`` the poles mapped to the s-plane by
    the bilinear transform pre-warped at ``center_hz``: the ``width_hz`` of
    :class:`~hilident.filters.notch.NotchSpec` (the analog prototype's), so
    near Nyquist it is wider than the digital -3 dB band.  ``0`` when the
    section has fewer than two poles.
    """
    poles = section.poles()
    if poles.size != 2:
        return 0.0
    k = _warp_gain(center_hz, sample_rate_hz)
    s = k * (poles - 1.0) / (poles + 1.0)
    return float(-np.sum(s).real / (2.0 * math.pi))
