"""The plant the drive's loop sees tick by tick, from the identified response and the loop's description.

The recorded response (torque to the velocity estimate or the position,
recorded every ``D`` loop ticks) is brought to the tick rate
(:func:`hilident.control.loop_plant`) and made torque to position. The loop's
crossings often lie above the measured band: there the loop sees the plant's
mechanics (its integrators and the modes found in the band) held over a tick,
with the gain the measured lines give them. For a robust design the same
mechanics with their modes moved to the ends of their 95 % intervals are the
plant's variants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from hilident.control import Cascade, loop_plant

__all__ = ["PLANT_FILE", "SeenPlant", "load_seen_plant", "save_seen_plant", "seen_plant"]

#: Where a run keeps the plant its loop sees (for ``hilident upload --gains``).
PLANT_FILE = "loop_plant.npz"

#: Highest frequency of the dense grid, as a fraction of the loop rate.
GRID_TOP = 0.45
GRID_POINTS = 4000


@dataclass(frozen=True)
class SeenPlant:
    """Motor torque to encoder position, tick by tick, on a grid.

    Attributes
    ----------
    frequency_hz : ndarray
    response : ndarray of complex
        ``H``, m per N·m.
    source : str
        ``"model"`` (the mechanics on a dense grid) or ``"lines"`` (the measured lines).
    band_hz : (float, float)
        The band the plant was measured in, Hz.
    residual : (float, float) or None
        How far the measured lines lie from the mechanics: rms dB and degrees (None for ``"lines"``).
    variants : list of ndarray
        ``H`` with the modes at the ends of their 95 % intervals (empty without a model or intervals).
    mechanics : ModalModel or None
        The mechanics ``response`` rests on (``"model"`` only), without its gain and the tick's hold.
    gain : float
        The real gain that brings ``mechanics`` onto the measured lines.
    loop_rate_hz : float
        The tick rate, Hz.
    mode_shift : float
        The fraction the variants' modes are moved by (0: no variants).
    """

    frequency_hz: np.ndarray
    response: np.ndarray
    source: str
    band_hz: tuple[float, float]
    residual: tuple[float, float] | None = None
    variants: list = field(default_factory=list)
    mechanics: object = None
    gain: float = 1.0
    loop_rate_hz: float = math.nan
    mode_shift: float = 0.0

    def at(self, frequency_hz) -> list[np.ndarray]:
        """``H`` at other frequencies, Hz: the plant first, then its variants. The mechanics are evaluated
        where there are some; measured lines are interpolated (log magnitude and unwrapped phase, linear in log
        frequency) and are NaN outside the lines."""
        f = np.asarray(frequency_hz, dtype=float)
        if self.mechanics is not None:
            held = self.gain * _held_over_a_tick(f, self.loop_rate_hz)
            m = self.mechanics
            return [m.response(f) * held] + [  # type: ignore[attr-defined]
                _modes_moved(m, k).response(f) * held for k in _shifts(self.mode_shift)
            ]
        logf = np.log(self.frequency_hz)
        mag = np.interp(np.log(f), logf, np.log(np.abs(self.response)), left=np.nan, right=np.nan)
        phase = np.interp(np.log(f), logf, np.unwrap(np.angle(self.response)), left=np.nan, right=np.nan)
        return [np.exp(mag + 1j * phase)]


def _mechanics_to_position(model, band_hz: tuple[float, float], output_is_velocity: bool):
    """The fitted model's mechanics from torque to position: its integrators (one more for a velocity
    output), the modes and the corners inside the measured band, no delay (what lies beyond the band is the
    drive's filters and timing, which the loop description gives)."""
    m = model.modal
    inside = lambda hz: band_hz[0] <= abs(hz) <= band_hz[1]  # noqa: E731
    return replace(
        m,
        resonances=tuple(r for r in m.resonances if inside(r[0])),
        antiresonances=tuple(r for r in m.antiresonances if inside(r[0])),
        real_poles_hz=tuple(c for c in m.real_poles_hz if inside(c)),
        real_zeros_hz=tuple(c for c in m.real_zeros_hz if inside(c)),
        integrators=m.integrators + (1 if output_is_velocity else 0),
        delay_s=0.0,
    )


def _held_over_a_tick(frequency_hz: np.ndarray, loop_rate_hz: float) -> np.ndarray:
    """Half a tick's delay: the torque held over a tick, the position read at the tick's start."""
    return np.exp(-1j * np.pi * frequency_hz / loop_rate_hz)


def _fit_mechanics(mechanics, f: np.ndarray, measured: np.ndarray, loop_rate_hz: float):
    """``(mechanics, gain, residual)``: the number of integrators (0 to 3) and the real gain (of either sign)
    that bring ``mechanics``, held over a tick (half a tick late), closest to the ``measured`` lines (least
    squares on the log of their ratio); ``residual`` is ``(rms dB, rms degrees)`` of what is left.

    The fitted model's own integrators and sign may trade with corners outside the band (a low-frequency
    slope bent by friction, a zero near 0 Hz); the lines brought to the tick rate decide. The timing is the
    loop's own (the torque held over a tick, the position read at its start), not fitted: a delay fitted to
    noisy lines in a low band would move the crossings far above it.
    """
    held = _held_over_a_tick(f, loop_rate_hz)
    best = None
    for n in range(4):
        candidate = replace(mechanics, integrators=n)
        ratio = measured / (candidate.response(f) * held)
        log_magnitude = np.log(np.abs(ratio))
        log_gain = float(np.mean(log_magnitude))
        for sign in (1.0, -1.0):  # a real gain of either sign
            # each line's phase off the gain's, wrapped: an unwrap of noisy lines can slip a whole turn mid-band
            # and read the lines after the slip as 360 degrees off
            phase = np.angle(ratio * sign)
            cost = float(np.mean((log_magnitude - log_gain) ** 2 + phase**2))
            if best is None or cost < best[0]:
                residual = (
                    float(20 / math.log(10) * np.sqrt(np.mean((log_magnitude - log_gain) ** 2))),
                    float(np.degrees(np.sqrt(np.mean(phase**2)))),
                )
                best = (cost, candidate, sign * math.exp(log_gain), residual)
    assert best is not None
    return best[1], best[2], best[3]


def seen_plant(
    plant, cascade: Cascade, rates: tuple[float, float], torque_sampling: str, output: str, mode_shift: float = 0.0
) -> SeenPlant:
    """The plant the loop sees tick by tick, motor torque to encoder position.

    The recorded response (torque to ``output``: the velocity estimate or the position) is brought to the
    tick rate (:func:`~hilident.control.loop_plant`) and, for a velocity, divided by the velocity estimate.
    With a fitted model, those lines inside the fitted band fix the gain and the timing of the model's
    mechanics, which give ``H`` on a dense grid (``residual``: what the lines differ from it, rms dB and
    degrees); without one, the measured lines are ``H`` (``residual`` None). ``mode_shift`` (a fraction of
    each mode's frequency, the widest 95 % interval of the resonances) gives the variants.
    """
    loop_rate_hz, sample_rate_hz = rates
    frf = plant.plant
    f_all = np.asarray(frf.frequency_hz, dtype=float)
    ok = (f_all > 0) & np.isfinite(frf.response)
    velocity = output == "velocity_mps"

    def measured(f: np.ndarray, recorded: np.ndarray) -> np.ndarray:
        seen = loop_plant(
            f, recorded, loop_rate_hz, sample_rate_hz, cascade.current_loop_hz, cascade.delay_ticks, torque_sampling
        )
        return seen / cascade.velocity_estimate(f) if velocity else seen

    if plant.model is None:
        f = f_all[ok]
        return SeenPlant(
            f,
            measured(f, np.asarray(frf.response)[ok]),
            "lines",
            (float(f[0]), float(f[-1])),
            loop_rate_hz=loop_rate_hz,
        )
    lo, hi = plant.model.fit.band_hz
    band = (float(lo), float(hi))
    lines = ok & (f_all >= band[0]) & (f_all <= band[1])
    f_m = f_all[lines]
    mechanics, gain, residual = _fit_mechanics(
        _mechanics_to_position(plant.model, band, velocity),
        f_m,
        measured(f_m, np.asarray(frf.response)[lines]),
        loop_rate_hz,
    )
    f = np.geomspace(max(band[0] / 2, 0.1), GRID_TOP * loop_rate_hz, GRID_POINTS)
    held = _held_over_a_tick(f, loop_rate_hz)
    variants = [gain * _modes_moved(mechanics, factor).response(f) * held for factor in _shifts(mode_shift)]
    return SeenPlant(
        f,
        gain * mechanics.response(f) * held,
        "model",
        band,
        residual,
        variants,
        mechanics,
        gain,
        loop_rate_hz,
        mode_shift if _shifts(mode_shift) else 0.0,
    )


def _shifts(mode_shift: float) -> list[float]:
    """The factors the modes are moved by for the variants (none for no interval)."""
    return [1.0 - mode_shift, 1.0 + mode_shift] if 0.0 < mode_shift < 1.0 else []


def _modes_moved(mechanics, factor: float):
    """``mechanics`` with every mode (resonance and anti-resonance, as a stiffness change moves them) at
    ``factor`` times its frequency."""
    return replace(
        mechanics,
        resonances=tuple((hz * factor, z) for hz, z in mechanics.resonances),
        antiresonances=tuple((hz * factor, z) for hz, z in mechanics.antiresonances),
    )


def save_seen_plant(path, seen: SeenPlant) -> None:
    """Write ``seen`` on its grid (the plant, its variants, the band, the tick rate) to ``path`` (``.npz``)."""
    np.savez(
        path,
        frequency_hz=seen.frequency_hz,
        response=seen.response,
        variants=np.array(seen.variants, dtype=complex).reshape(len(seen.variants), seen.frequency_hz.size),
        band_hz=np.array(seen.band_hz, dtype=float),
        loop_rate_hz=np.array(seen.loop_rate_hz, dtype=float),
        source=np.array(seen.source),
    )


def load_seen_plant(path) -> SeenPlant:
    """The plant :func:`save_seen_plant` wrote: its grid, response and variants (interpolated between lines
    by :meth:`SeenPlant.at`).

    Raises
    ------
    DataError
        The file is missing or not such a plant, naming it.
    """
    from hilident.errors import DataError

    try:
        with np.load(path, allow_pickle=False) as data:
            return SeenPlant(
                np.asarray(data["frequency_hz"], dtype=float),
                np.asarray(data["response"], dtype=complex),
                str(data["source"]),
                (float(data["band_hz"][0]), float(data["band_hz"][1])),
                variants=[np.asarray(v, dtype=complex) for v in data["variants"]],
                loop_rate_hz=float(data["loop_rate_hz"]),
            )
    except (OSError, KeyError, ValueError, IndexError) as exc:
        raise DataError(f"{path}: not the plant a run's loop step writes ({exc})") from None
