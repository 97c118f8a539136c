"""Which poles and zeros of a transfer-function fit the measured data can support."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hilident.ident.tffit.model import REAL_TOL, TWO_PI, TfFit

__all__ = ["RootReport", "classify_roots"]

#: Least damping ratio of a pole counted off the imaginary axis (classify_roots' default).
AXIS_TOL = 1e-6


@dataclass(frozen=True)
class RootReport:
    """The poles and zeros of a fit, sorted into what the data support and what they do not.

    Attributes
    ----------
    modes : list of (float, float)
        ``(frequency_hz, damping_ratio)`` of complex pole pairs inside the
        supported range: the resonances the model claims.
    flagged_poles : list of dict
        Poles that are not reported as modes: ``frequency_hz``,
        ``damping_ratio`` (NaN for a real pole), ``reason``.
    antiresonances : list of (float, float)
        Complex left-half-plane zero pairs inside the supported range.
    rhp_zeros : list of dict
        Right-half-plane zeros: ``frequency_hz`` (``|z| / 2 pi``),
        ``real_part_rad_s``, ``kind`` (``"real"`` or ``"complex pair"``),
        ``explanation`` and, for a real one, ``equivalent_delay_s`` (``1 / z``:
        the delay whose phase lag it has well below ``z``).
    flagged_zeros : list of dict
        Zeros far outside the band, either half plane, and complex zero pairs
        outside it (``frequency_hz``, ``reason``).
    real_poles_hz, real_zeros_hz : list of float
        Corner frequencies of real left-half-plane poles and zeros in range, Hz.
    stable : bool
        Every pole except the integrators lies in the left half plane by more
        than the numerical tolerance.
    stability : str
        ``"stable"``, or why not (``"marginal: ..."``).
    """

    modes: list
    flagged_poles: list
    antiresonances: list
    rhp_zeros: list
    flagged_zeros: list
    real_poles_hz: list
    real_zeros_hz: list
    stable: bool
    stability: str

    def to_dict(self) -> dict:
        return {
            "resonances": [{"frequency_hz": f, "damping_ratio": z} for f, z in self.modes],
            "flagged_poles": list(self.flagged_poles),
            "antiresonances": [{"frequency_hz": f, "damping_ratio": z} for f, z in self.antiresonances],
            "rhp_zeros": list(self.rhp_zeros),
            "flagged_zeros": list(self.flagged_zeros),
            "real_poles_hz": list(self.real_poles_hz),
            "real_zeros_hz": list(self.real_zeros_hz),
            "stable": self.stable,
            "stability": self.stability,
        }


_RHP_EXPLANATION = (
    "right-half-plane (non-minimum-phase) zero: it adds phase lag without a dip in |G|, so it is no "
    "anti-resonance; on a drive it usually stands for a delay (computation, transport, current loop) or for "
    "a sensor that is not collocated with the actuator"
)


def classify_roots(
    fit: TfFit,
    band_hz: tuple[float, float] | None = None,
    axis_tol: float = AXIS_TOL,
    outside_factor: float = 10.0,
    resolution_hz: float | None = None,
) -> RootReport:
    """Which poles and zeros of a fit the data can support.

    A pole is flagged, not reported as a mode, when

    * its damping ratio is below `axis_tol` (within numerical noise of the
      imaginary axis; the model is then only marginally stable);
    * ``|p| / 2 pi`` lies above ``outside_factor`` times the top of the band
      or below the bottom divided by it (the fit put it there to bend the
      response at the band edge; it is not a mode the data show), or, for a
      complex pair, outside the band at all;
    * with `resolution_hz`, its half-power bandwidth ``2 zeta f`` is under a
      tenth of the line spacing (the measurement cannot resolve it).

    Zeros in the right half plane within reach of the band are listed as
    such with an explanation, never as anti-resonances; zeros far outside the
    band and complex zero pairs outside it are flagged.

    Parameters
    ----------
    fit : TfFit
    band_hz : (float, float), optional
        Band the data cover, Hz; default ``fit.band_hz``.
    axis_tol : float
        Least damping ratio of a pole (or ``|Re z| / |z|`` of a zero) counted
        off the imaginary axis.
    outside_factor : float
        How far outside the band a root may lie and still count (> 1).
    resolution_hz : float, optional
        Line spacing of the measured response, Hz.

    Returns
    -------
    RootReport
    """
    lo, hi = fit.band_hz if band_hz is None else band_hz
    band = _Band(lo, hi, axis_tol, outside_factor, resolution_hz)
    poles = np.asarray(fit.poles)[: len(fit.poles) - fit.integrators]
    modes, flagged, real_p = [], [], []
    marginal = []
    for p in _upper_half(poles):
        f_hz, zeta, is_complex = abs(p) / TWO_PI, _damping(p), _is_complex(p)
        reason = band.pole_reason(f_hz, zeta, is_complex)
        if not zeta > axis_tol:
            marginal.append(f_hz)
        if reason:
            flagged.append(
                {
                    "frequency_hz": float(f_hz),
                    "damping_ratio": float(zeta) if is_complex else float("nan"),
                    "real_part_rad_s": float(p.real),
                    "reason": reason,
                }
            )
        elif is_complex:
            modes.append((float(f_hz), float(zeta)))
        else:
            real_p.append(float(f_hz))
    anti, rhp, flagged_z, real_z = [], [], [], []
    for z in _upper_half(np.asarray(fit.zeros)):
        f_hz, is_complex = abs(z) / TWO_PI, _is_complex(z)
        if band.far_outside(f_hz):
            flagged_z.append(band.far_zero(z, f_hz))
        elif z.real > axis_tol * abs(z):
            rhp.append(_rhp_zero(z, f_hz, is_complex))
        elif is_complex and not lo <= f_hz <= hi:
            flagged_z.append(
                {
                    "frequency_hz": float(f_hz),
                    "reason": f"outside the fitted band {lo:.4g}-{hi:.4g} Hz: not an anti-resonance the data show",
                }
            )
        elif is_complex:
            anti.append((float(f_hz), float(-z.real / abs(z))))
        else:
            real_z.append(float(f_hz))
    stable = not marginal and bool(np.all(poles.real < 0.0))
    return RootReport(
        sorted(modes),
        flagged,
        sorted(anti),
        rhp,
        flagged_z,
        sorted(real_p),
        sorted(real_z),
        stable,
        _stability(stable, marginal),
    )


def _upper_half(roots: np.ndarray) -> list[complex]:
    """The roots without the lower member of each complex pair (the upper one speaks for the pair)."""
    return [r for r in roots if not r.imag < -REAL_TOL * abs(r)]


def _is_complex(r: complex) -> bool:
    return bool(r.imag > REAL_TOL * abs(r))


def _damping(p: complex) -> float:
    """``-Re p / |p|``; NaN for a pole at 0."""
    return -p.real / abs(p) if abs(p) > 0 else float("nan")


@dataclass(frozen=True)
class _Band:
    """The band the data cover and the limits of :func:`classify_roots`."""

    lo: float
    hi: float
    axis_tol: float
    outside_factor: float
    resolution_hz: float | None

    def far_outside(self, f_hz: float) -> bool:
        return bool(f_hz > self.outside_factor * self.hi or f_hz < self.lo / self.outside_factor)

    def pole_reason(self, f_hz: float, zeta: float, is_complex: bool) -> str:
        """Why a pole is not reported as a mode ("" when it is)."""
        lo, hi = self.lo, self.hi
        if not zeta > self.axis_tol:
            return (
                f"on the imaginary axis within numerical noise (zeta {zeta:.2g}): an undamped pole the "
                "data cannot support"
            )
        if self.far_outside(f_hz):
            return (
                f"far outside the fitted band {lo:.4g}-{hi:.4g} Hz: the fit uses it to bend the response "
                "at the band edge"
            )
        if is_complex and not lo <= f_hz <= hi:
            return f"outside the fitted band {lo:.4g}-{hi:.4g} Hz: the data show at most its skirt"
        if is_complex and self.resolution_hz and 2.0 * zeta * f_hz < 0.1 * self.resolution_hz:
            return (
                f"half-power bandwidth {2 * zeta * f_hz:.3g} Hz is under a tenth of the "
                f"{self.resolution_hz:.3g} Hz line spacing: the measurement cannot resolve it"
            )
        return ""

    def far_zero(self, z: complex, f_hz: float) -> dict:
        """The flag of a zero far outside the band, either half plane."""
        side = "right" if z.real > self.axis_tol * abs(z) else "left"
        acts = "a differentiator s" if f_hz < self.lo else "a constant"
        return {
            "frequency_hz": float(f_hz),
            "real_part_rad_s": float(z.real),
            "reason": f"{side}-half-plane zero far outside the fitted band {self.lo:.4g}-{self.hi:.4g} Hz: "
            f"in the band it acts as {acts}",
        }


def _rhp_zero(z: complex, f_hz: float, is_complex: bool) -> dict:
    entry = {
        "frequency_hz": float(f_hz),
        "real_part_rad_s": float(z.real),
        "kind": "complex pair" if is_complex else "real",
        "explanation": _RHP_EXPLANATION,
    }
    if not is_complex:
        # below it, 1 - s/z has the phase of a delay 1/z (and no effect on |G|)
        entry["equivalent_delay_s"] = float(1.0 / z.real)
    return entry


def _stability(stable: bool, marginal: list[float]) -> str:
    if stable:
        return "stable"
    if marginal:
        return "marginal: pole(s) at " + ", ".join(f"{f:.4g} Hz" for f in marginal) + " lie on the imaginary axis"
    return "unstable: a pole lies in the right half plane"
