"""Notch filters: analog design, pre-warped Tustin discretisation, quantisation.

The continuous-time notch is the thesis's eq. 2.63,
``H(s) = (s^2 + w0^2) / (s^2 + 2 wc s + w0^2)``, generalised to a finite depth::

    H(s) = (s^2 + 2 zeta_z w0 s + w0^2) / (s^2 + 2 zeta_p w0 s + w0^2)

    zeta_p = width_hz / (2 center_hz)
    zeta_z = zeta_p * 10**(-depth_db / 20)

so ``|H(j w0)| = 10**(-depth_db / 20)`` exactly and ``H(0) = H(j inf) = 1``.

Width: ``width_hz`` is the -3 dB bandwidth of the infinite-depth notch
(``zeta_z = 0``, eq. 2.63 with ``wc = zeta_p w0``): its two half-power
frequencies ``f1 < f0 < f2`` satisfy ``f2 - f1 = 2 zeta_p f0 = width_hz``
exactly (and ``f1 f2 = f0^2``).  A finite-depth notch has the same poles, hence
the same width parameter; its attenuation at ``f1`` and ``f2`` is slightly less
than 3 dB.

The discrete section is the bilinear transform pre-warped at the centre, so
the digital notch's deepest point lies exactly at ``center_hz`` with exactly
``depth_db`` attenuation, whatever ``center_hz / sample_rate_hz``.  The digital
width is that of the analog prototype seen through the frequency warping, i.e.
slightly narrower than ``width_hz`` when the centre approaches Nyquist.

Examples
--------
>>> from hilident.filters.notch import NotchSpec, design_notch
>>> bq = design_notch(NotchSpec(center_hz=120.0, width_hz=20.0, depth_db=30.0), 4000.0)
>>> round(float(20 * np.log10(abs(bq.response(120.0, 4000.0)))), 6)
-30.0
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from hilident.errors import ConfigError, DataError
from hilident.filters.biquad import Biquad

__all__ = [
    "NotchSpec",
    "chain_response",
    "design_notch",
    "float32_biquad",
    "interval_width_hz",
    "notch_analog",
    "notch_from_resonance",
    "quantize_biquad",
    "tustin_prewarped",
    "width_for_attenuation_hz",
]


def _number(key: str, value, *, positive: bool = True, allow_inf: bool = False) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ConfigError(key, f"must be a number, got {value!r}") from None
    if math.isnan(x) or (math.isinf(x) and not (allow_inf and x > 0)):
        raise ConfigError(key, f"must be finite, got {value!r}")
    if positive and x <= 0.0:
        raise ConfigError(key, f"must be positive, got {value!r}")
    return x


@dataclass(frozen=True)
class NotchSpec:
    """What a notch should do, independent of the sample rate.

    Parameters
    ----------
    center_hz : float
        Centre frequency in Hz (deepest point).
    width_hz : float
        -3 dB bandwidth of the infinite-depth notch in Hz (see the module docstring).
    depth_db : float
        Attenuation at the centre in dB, positive: 30 means ``|H| = -30 dB``.
        ``math.inf`` gives the zero-at-centre notch of eq. 2.63.
    """

    center_hz: float
    width_hz: float
    depth_db: float

    def __post_init__(self):
        object.__setattr__(self, "center_hz", _number("center_hz", self.center_hz))
        object.__setattr__(self, "width_hz", _number("width_hz", self.width_hz))
        object.__setattr__(self, "depth_db", _number("depth_db", self.depth_db, allow_inf=True))


def notch_analog(center_hz, width_hz, depth_db) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time notch ``(b_s, a_s)``, highest power of ``s`` first.

    ``b_s = [1, 2 zeta_z w0, w0^2]``, ``a_s = [1, 2 zeta_p w0, w0^2]`` with
    ``w0 = 2 pi center_hz``, ``zeta_p = width_hz / (2 center_hz)`` and
    ``zeta_z = zeta_p 10**(-depth_db/20)``.
    """
    spec = NotchSpec(center_hz, width_hz, depth_db)
    w0 = 2.0 * math.pi * spec.center_hz
    zeta_p = spec.width_hz / (2.0 * spec.center_hz)
    zeta_z = zeta_p * 10.0 ** (-spec.depth_db / 20.0)
    b_s = np.array([1.0, 2.0 * zeta_z * w0, w0 * w0])
    a_s = np.array([1.0, 2.0 * zeta_p * w0, w0 * w0])
    return b_s, a_s


def notch_from_resonance(
    frequency_hz,
    damping_ratio,
    depth_db=30.0,
    width_factor=2.0,
    min_relative_width=0.1,
) -> NotchSpec:
    """Notch for a resonance at ``frequency_hz`` with modal ``damping_ratio``.

    Rule: ``width_hz = max(width_factor * 2 zeta f, min_relative_width * f)``.
    ``2 zeta f`` is the resonance's half-power bandwidth; a notch ``width_factor``
    times wider also covers the identified frequency's uncertainty and its
    drift with load or position.  The floor keeps a very lightly damped mode
    (where ``2 zeta f`` is a fraction of a hertz) from getting a notch so narrow
    that a few percent of frequency error would miss it: with the default 0.1
    the -3 dB band spans about +-5 % of ``f``.

    Parameters
    ----------
    frequency_hz : float
        Resonance frequency in Hz.
    damping_ratio : float
        Modal damping ratio zeta, ``0 < zeta < 1``.
    depth_db : float
        Notch depth in dB (positive).
    width_factor : float
        Notch width per half-power bandwidth of the resonance.
    min_relative_width : float
        Smallest ``width_hz / frequency_hz``.
    """
    f = _number("frequency_hz", frequency_hz)
    zeta = _number("damping_ratio", damping_ratio)
    if zeta >= 1.0:
        raise ConfigError("damping_ratio", f"must be below 1 for a resonance, got {zeta:g}")
    factor = _number("width_factor", width_factor)
    floor = _number("min_relative_width", min_relative_width)
    width = max(factor * 2.0 * zeta * f, floor * f)
    return NotchSpec(center_hz=f, width_hz=width, depth_db=depth_db)


def width_for_attenuation_hz(center_hz, frequencies_hz, attenuation_db, depth_db, sample_rate_hz=None) -> float:
    """Smallest notch width that attenuates at least ``attenuation_db`` at each of ``frequencies_hz``.

    Closed form.  With ``r = w / w0`` and ``u = (1 - r^2) / (2 r)`` the
    notch of the module docstring has ``|H|^2 = (u^2 + zeta_z^2) / (u^2 +
    zeta_p^2)``; with ``A = 10**(-attenuation_db / 20)`` and ``g =
    10**(-depth_db / 20)``, ``|H| <= A`` holds exactly when
    ``zeta_p >= |u| sqrt((1 - A^2) / (A^2 - g^2))``.  For the digital notch of
    :func:`design_notch` (pre-warped at the centre) the digital response at
    ``f`` is the analog one at the warped ratio
    ``r = tan(pi f / fs) / tan(pi f0 / fs)``, so with ``sample_rate_hz`` the
    result is exact for the designed biquad, not only for its prototype.

    Parameters
    ----------
    center_hz : float
        Notch centre, Hz.
    frequencies_hz : array_like
        Frequencies that must be attenuated, Hz (below ``sample_rate_hz / 2``).
    attenuation_db : float
        Least attenuation wanted at each of them, dB (positive).
    depth_db : float
        Depth of the notch at its centre, dB; must exceed ``attenuation_db``.
    sample_rate_hz : float, optional
        Rate the notch runs at; ``None``: the analog prototype.

    Returns
    -------
    float
        ``width_hz`` (as :class:`NotchSpec` means it), Hz; 0 when every
        frequency is the centre.

    Raises
    ------
    ConfigError
        ``attenuation_db`` not below ``depth_db`` (a notch is never deeper
        than its centre), or a frequency at or above Nyquist.

    Examples
    --------
    >>> w = width_for_attenuation_hz(100.0, [99.0, 101.0], 20.0, 40.0, 4000.0)
    >>> bq = design_notch(NotchSpec(100.0, w, 40.0), 4000.0)
    >>> round(float(-20 * np.log10(abs(bq.response(99.0, 4000.0)))), 6)
    20.0
    """
    f0 = _number("center_hz", center_hz)
    target = _number("attenuation_db", attenuation_db)
    depth = _number("depth_db", depth_db, allow_inf=True)
    if not target < depth:
        raise ConfigError("attenuation_db", f"must be below the notch depth {depth:g} dB, got {target:g}")
    f = np.atleast_1d(np.asarray(frequencies_hz, dtype=float))
    if f.size == 0 or not np.all(np.isfinite(f)) or np.any(f <= 0.0):
        raise ConfigError("frequencies_hz", f"must be positive finite frequencies, got {f!r}")
    if sample_rate_hz is None:
        r = f / f0
    else:
        fs = _number("sample_rate_hz", sample_rate_hz)
        if np.any(f >= 0.5 * fs) or f0 >= 0.5 * fs:
            raise ConfigError("frequencies_hz", f"must lie below the Nyquist frequency {0.5 * fs:g} Hz")
        r = np.tan(np.pi * f / fs) / math.tan(math.pi * f0 / fs)
    u = float(np.max(np.abs(1.0 - r * r) / (2.0 * r)))
    a2, g2 = 10.0 ** (-target / 10.0), 10.0 ** (-depth / 10.0)
    zeta_p = u * math.sqrt((1.0 - a2) / (a2 - g2))
    return 2.0 * zeta_p * f0


def interval_width_hz(frequency_hz, frequency_ci95_hz, attenuation_db, depth_db, sample_rate_hz=None) -> float:
    """Width a notch centred on ``frequency_hz`` needs to attenuate ``attenuation_db`` over its 95 % interval.

    The uncertainty-aware width rule: the identified frequency is only known
    to ``+- frequency_ci95_hz``, so the notch must reach the target at both
    ``frequency_hz - frequency_ci95_hz`` and ``frequency_hz + frequency_ci95_hz``
    (:func:`width_for_attenuation_hz`, exact for the designed biquad when
    ``sample_rate_hz`` is given).  A NaN or zero interval needs no width (0).

    Parameters
    ----------
    frequency_hz : float
        Identified frequency, the notch centre, Hz.
    frequency_ci95_hz : float
        Half-width of its 95 % confidence interval, Hz (NaN: unknown).
    attenuation_db : float
        Least attenuation wanted at both ends of the interval, dB.
    depth_db : float
        Depth of the notch, dB (above ``attenuation_db``).
    sample_rate_hz : float, optional
        Filter rate the notch runs at, Hz; ``None``: the analog prototype.
    """
    f = _number("frequency_hz", frequency_hz)
    try:
        ci = float(frequency_ci95_hz)
    except (TypeError, ValueError):
        raise ConfigError("frequency_ci95_hz", f"must be a number, got {frequency_ci95_hz!r}") from None
    if math.isnan(ci) or ci == 0.0:
        return 0.0
    if not 0.0 < ci < f:
        raise ConfigError("frequency_ci95_hz", f"must lie in [0, {f:g}) Hz, got {ci!r}")
    return width_for_attenuation_hz(f, [f - ci, f + ci], attenuation_db, depth_db, sample_rate_hz)


def tustin_prewarped(b_s, a_s, sample_rate_hz, prewarp_hz) -> Biquad:
    """Bilinear transform with the response matched exactly at ``prewarp_hz``.

    Substitutes ``s = K (z - 1) / (z + 1)`` with ``K = wp / tan(wp T / 2)``,
    ``wp = 2 pi prewarp_hz``, ``T = 1 / sample_rate_hz``: the digital response
    at ``prewarp_hz`` equals the analog one there.  This is
    ``scipy.signal.bilinear(b_s, a_s, fs=K / 2)``, written out for a section
    of order <= 2 so the DC sum of the coefficients is not lost to rounding.

    Parameters
    ----------
    b_s, a_s : array_like
        Analog numerator and denominator, highest power of ``s`` first, order <= 2.
    sample_rate_hz : float
        Rate the section will run at.
    prewarp_hz : float
        Frequency matched exactly, ``0 < prewarp_hz < sample_rate_hz / 2``.

    Returns
    -------
    Biquad
        Coefficients with ``a0`` normalised to 1.
    """
    fs = _number("sample_rate_hz", sample_rate_hz)
    fp = _number("prewarp_hz", prewarp_hz)
    if fp >= 0.5 * fs:
        raise ConfigError("prewarp_hz", f"must be below the Nyquist frequency {0.5 * fs:g} Hz, got {fp:g}")
    b = _second_order("b_s", b_s)
    a = _second_order("a_s", a_s)
    if not np.any(a):
        raise DataError("a_s must not be all zero")
    wp = 2.0 * math.pi * fp
    k = wp / math.tan(wp / (2.0 * fs))
    # multiply numerator and denominator by (z + 1)^order, not always (z + 1)^2, so a
    # first-order system gets no cancelling pole-zero pair on the unit circle at z = -1
    order = 2 if (b[0] or a[0]) else 1 if (b[1] or a[1]) else 0

    def z_coefficients(p):
        # p2 s^2 + p1 s + p0 with s = K (z-1)/(z+1), in powers of z^-1
        p2k2, p1k, p0 = p[0] * k * k, p[1] * k, p[2]
        if order == 2:
            return (p2k2 + p1k + p0, 2.0 * (p0 - p2k2), p2k2 - p1k + p0)
        if order == 1:
            return (p1k + p0, p0 - p1k, 0.0)
        return (p0, 0.0, 0.0)

    num = z_coefficients(b)
    den = z_coefficients(a)
    if den[0] == 0.0:
        raise DataError("the analog denominator maps to a0 = 0 (pole at s = -K)")
    return Biquad(tuple(x / den[0] for x in num), (1.0, den[1] / den[0], den[2] / den[0]))


def _second_order(key: str, p) -> np.ndarray:
    p = np.atleast_1d(np.asarray(p, dtype=float))
    if p.ndim != 1 or p.size == 0 or not np.all(np.isfinite(p)):
        raise DataError(f"{key} must be a 1-D array of finite coefficients, got {p!r}")
    p = np.trim_zeros(p, "f")
    if p.size > 3:
        raise DataError(f"{key} has order {p.size - 1}; a biquad holds order <= 2")
    return np.concatenate((np.zeros(3 - p.size), p))


def design_notch(spec: NotchSpec, sample_rate_hz) -> Biquad:
    """Digital notch section for ``spec`` at ``sample_rate_hz``.

    Analog notch (:func:`notch_analog`), then :func:`tustin_prewarped` at
    ``spec.center_hz``, then checks.

    Raises
    ------
    ConfigError
        ``center_hz`` at or above Nyquist.
    DataError
        The section is unstable or its DC gain differs from 1 by more than 1e-9
        (a centre so low against the sample rate that double precision cannot
        hold the coefficients).
    """
    fs = _number("sample_rate_hz", sample_rate_hz)
    if spec.center_hz >= 0.5 * fs:
        raise ConfigError(
            "center_hz",
            f"must be below the Nyquist frequency {0.5 * fs:g} Hz, got {spec.center_hz:g}",
        )
    b_s, a_s = notch_analog(spec.center_hz, spec.width_hz, spec.depth_db)
    section = tustin_prewarped(b_s, a_s, fs, spec.center_hz)
    if not section.is_stable():
        raise DataError(
            f"notch at center_hz={spec.center_hz:g} Hz, width_hz={spec.width_hz:g} Hz is "
            f"unstable at {fs:g} Hz (pole radius {np.max(np.abs(section.poles())):.12f})"
        )
    dc = section.dc_gain()
    if abs(dc - 1.0) > 1e-9:
        raise DataError(
            f"notch at center_hz={spec.center_hz:g} Hz has DC gain {dc!r} at {fs:g} Hz; "
            "the centre is too low for this sample rate"
        )
    return section


def quantize_biquad(biquad: Biquad, fractional_bits, total_bits=32, preserve_dc=True) -> Biquad:
    """Round coefficients to signed fixed point with ``fractional_bits`` fraction bits.

    Each of ``b0, b1, b2, a1, a2`` becomes ``round(c * 2**fractional_bits)``,
    an integer that must fit in ``total_bits`` two's complement
    (``-2**(total_bits-1) .. 2**(total_bits-1) - 1``), divided back by
    ``2**fractional_bits``.  ``a0 = 1`` is implicit, as in drives that store
    five coefficients.  A notch at a low ``center_hz / sample_rate_hz`` has
    ``a1`` near -2, so the format needs at least two integer bits besides the sign.

    With ``preserve_dc`` (default), ``b1`` is not rounded on its own but set
    so that ``b0 + b1 + b2`` is the grid value nearest to the original DC gain
    times ``1 + a1 + a2``: for a notch the quantised DC gain is then exactly 1
    (plain rounding can miss it by a percent when the poles sit close to
    ``z = 1``).  ``b1`` moves by a few steps of the grid at most.

    Raises
    ------
    ConfigError
        ``fractional_bits`` or ``total_bits`` out of range.
    DataError
        A coefficient overflows the format, or the quantised section is unstable.
    """
    if isinstance(total_bits, bool) or int(total_bits) != total_bits or not 2 <= total_bits <= 64:
        raise ConfigError("total_bits", f"must be an integer in 2..64, got {total_bits!r}")
    total = int(total_bits)
    if isinstance(fractional_bits, bool) or int(fractional_bits) != fractional_bits or not 0 <= fractional_bits < total:
        raise ConfigError("fractional_bits", f"must be an integer in 0..{total - 1}, got {fractional_bits!r}")
    frac = int(fractional_bits)
    scale = 2.0**frac
    lo, hi = -(2 ** (total - 1)), 2 ** (total - 1) - 1
    names = ("b0", "b1", "b2", "a1", "a2")
    values = (*biquad.b, biquad.a[1], biquad.a[2])
    ints = {name: int(np.round(c * scale)) for name, c in zip(names, values, strict=False)}
    if preserve_dc:
        # integers on the grid, so the sums below are exact
        den_sum = 2**frac + ints["a1"] + ints["a2"]
        num_sum = int(np.round(biquad.dc_gain() * den_sum)) if den_sum else None
        if num_sum is not None:
            ints["b1"] = num_sum - ints["b0"] - ints["b2"]
    for name, c in zip(names, values, strict=False):
        if not lo <= ints[name] <= hi:
            raise DataError(
                f"coefficient {name} = {c!r} overflows Q{total - frac}.{frac} (range {lo / scale:g} .. {hi / scale:g})"
            )
    rounded = [ints[name] / scale for name in names]
    section = Biquad((rounded[0], rounded[1], rounded[2]), (1.0, rounded[3], rounded[4]))
    _require_stable(section, f"quantised to {total} bits with {frac} fractional bits")
    return section


def float32_biquad(biquad: Biquad) -> Biquad:
    """Coefficients rounded to IEEE-754 single precision (a drive's REAL32 objects).

    Raises
    ------
    DataError
        The rounded section is unstable.
    """
    b0, b1, b2 = (float(np.float32(x)) for x in biquad.b)
    a = (1.0, float(np.float32(biquad.a[1])), float(np.float32(biquad.a[2])))
    section = Biquad((b0, b1, b2), a)
    _require_stable(section, "rounded to float32")
    return section


def _require_stable(section: Biquad, how: str) -> None:
    _, a1, a2 = section.a
    # Jury's triangle, exact on the rounded coefficients: |a2| < 1 and |a1| < 1 + a2
    if not (abs(a2) < 1.0 and abs(a1) < 1.0 + a2):
        raise DataError(f"section {how} is unstable: a1 = {a1!r}, a2 = {a2!r}")


def chain_response(biquads: Iterable[Biquad], frequency_hz, sample_rate_hz) -> np.ndarray:
    """Complex response of ``biquads`` in series at ``frequency_hz`` (Hz)."""
    f = np.asarray(frequency_hz, dtype=float)
    h = np.ones(f.shape, dtype=complex)
    for section in biquads:
        h = h * section.response(f, sample_rate_hz)
    return h
