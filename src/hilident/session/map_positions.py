"""The resonance over the workspace (``[map]``): at each position, move there, hold it, excite, identify.

The thesis behind the gantry (its eqs. 2.3-2.4) has the beam's stiffness and damping depend on the cart's
position; its author measured seven positions by hand. A run with ``[map]`` does it in one go, under the
run's one arming and one stop guarantee: after the identification at the start position the axis moves (in
position mode, a trapezoid within ``[map] max_velocity_mps``/``max_accel_mps2``) to each mapped position,
holds it for ``settle_s`` and is excited there with the run's excitation injected as torque around the held
position (``torque_injection``: the drive's loops keep the cart where it is), and the record is identified
as the run's is. Then the axis moves back to where it started, so the notch is verified where the plant was
identified.

The session passes what the step needs (``record``, ``identify``, ``progress``); this module knows nothing
of devices.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hilident.config.tables import Config, map_positions
from hilident.numbers import finite_or_none

#: The mode a mapped position is excited in: torque injected while the drive holds the position.
MAP_MODE = "torque_injection"


@dataclass(frozen=True)
class MapPoint:
    """The mode identified at one position of the map.

    Attributes
    ----------
    target_m : float
        The position asked for, m.
    position_m : float
        The cart's mean measured position over the analysed excitation, m.
    frequency_hz, damping_ratio : float or None
        The mode nearest the run's main resonance (None: no resonance found there).
    frequency_ci95_hz : float or None
        Half-width of the 95 % interval of ``frequency_hz``, Hz.
    coherence : float or None
        Coherence at the resonance.
    recording : str
        The recording of the excitation at this position (``map_<i>.h5``).
    """

    target_m: float
    position_m: float
    frequency_hz: float | None
    damping_ratio: float | None
    frequency_ci95_hz: float | None
    coherence: float | None
    recording: str

    def to_dict(self) -> dict:
        return {
            "position_m": self.position_m,
            "target_m": self.target_m,
            "frequency_hz": self.frequency_hz,
            "damping_ratio": self.damping_ratio,
            "frequency_ci95_hz": self.frequency_ci95_hz,
            "coherence": self.coherence,
            "recording": self.recording,
        }


def move_axis(cfg: Config, record: Callable, name: str, from_m: float, to_m: float) -> float:
    """Move the cart from ``from_m`` to ``to_m``: a trapezoid within ``[map] max_velocity_mps`` and
    ``max_accel_mps2`` in position mode, then ``[map] settle_s`` held, recorded as ``name``; then, until the
    cart is still at the target (:data:`STILL_MPS`, :data:`STILL_DISTANCE_M`), short moves over what is left
    (``name_settle_<n>``, at most :data:`MAX_SETTLES`). Returns the position reached, m (``from_m`` when the
    two are equal: nothing is recorded)."""
    from hilident.motion.profiles import trapezoid

    if to_m == from_m:
        return from_m
    m, rate = cfg.map, cfg.run.sample_rate_hz

    def trapezoid_to(target: float, here: float) -> np.ndarray:
        return trapezoid(
            target - here, m.max_velocity_mps, m.max_accel_mps2, rate, m.settle_s, key_prefix="map."
        ).position_m

    exp = record(name, "position", trapezoid_to(to_m, from_m))
    # Each experiment enables the drive afresh where the cart then is, and the loops may still be settling when
    # a profile ends: move the rest of the way until the cart is still at the target, so the next experiment
    # does not start by braking it (a torque peak on top of its excitation).
    for attempt in range(1, MAX_SETTLES + 1):
        here = float(exp.samples["position_m"][-1])
        off = to_m - here
        if _still(exp.samples["velocity_mps"], rate) and abs(off) <= STILL_DISTANCE_M:
            break
        exp = record(
            f"{name}_settle_{attempt}",
            "position",
            trapezoid_to(to_m, here) if off else np.zeros(int(round(max(m.settle_s, 0.2) * rate))),
        )
    return float(exp.samples["position_m"][-1])


#: How many short moves over what is left (each with its settle_s) a move may add before it gives up waiting.
MAX_SETTLES = 5
#: Still: the mean velocity over the last 0.1 s below this, m/s ...
STILL_MPS = 1e-3
#: ... and the cart within this of the target, m.
STILL_DISTANCE_M = 1e-3


def _still(velocity_mps: np.ndarray, rate_hz: float) -> bool:
    tail = velocity_mps[-max(int(0.1 * rate_hz), 1) :]
    return bool(tail.size and abs(float(np.mean(tail))) < STILL_MPS)


def nearest_resonance(resonances: list, reference_hz: float | None):
    """The resonance of ``resonances`` nearest ``reference_hz`` (the first when there is no reference)."""
    if not resonances:
        return None
    if reference_hz is None:
        return resonances[0]
    return min(resonances, key=lambda r: abs(math.log(r.frequency_hz / reference_hz)))


class WorkspaceMap:
    """The ``[map]`` step of a run.

    Parameters
    ----------
    cfg : Config
        The run's configuration (``[map]``, ``[run] sample_rate_hz``).
    record : callable
        ``record(name, mode, samples, period_samples=..., recipe=...) -> Experiment``: the session's recorder.
    identify : callable
        ``identify(experiment, name) -> identification result`` (``.resonances``, ``.plant``, ``.loop``): the
        session's identification of one record.
    progress : Progress
        Where the steps are shown.
    """

    def __init__(self, cfg: Config, record: Callable, identify: Callable, progress):
        self.cfg, self.record, self.identify, self.progress = cfg, record, identify, progress
        self.results: dict[str, object] = {}  # recording name -> its identification, for the joint fit

    def run(self, excitation, start_m: float, reference_hz: float | None, recipe: dict | None) -> list[MapPoint]:
        """Map every position of ``[map]``, then return to ``start_m``; one :class:`MapPoint` per position."""
        positions = map_positions(self.cfg)
        points, here = [], start_m
        for i, target in enumerate(positions):
            self.progress.step(f"map: position {i + 1} of {len(positions)}, {target:+.3f} m")
            here = self.move(f"map_move_{i}", here, target)
            name = f"map_{i}"
            exp = self.record(
                name, MAP_MODE, excitation.samples, period_samples=excitation.period_samples, recipe=recipe
            )
            result = self.identify(exp, name)
            self.results[name] = result
            here = float(exp.samples["position_m"][-1])
            points.append(self._point(target, exp, result, reference_hz, name))
        self.move("map_return", here, start_m)
        return points

    def move(self, name: str, from_m: float, to_m: float) -> float:
        """:func:`move_axis` with this map's configuration and recorder."""
        return move_axis(self.cfg, self.record, name, from_m, to_m)

    @staticmethod
    def _point(target: float, exp, result, reference_hz: float | None, name: str) -> MapPoint:
        mode = nearest_resonance(list(result.resonances), reference_hz)
        position = float(np.mean(exp.samples["position_m"]))
        if mode is None:
            return MapPoint(target, position, None, None, None, None, f"{name}.h5")
        return MapPoint(
            target,
            position,
            float(mode.frequency_hz),
            finite_or_none(mode.damping_ratio),
            finite_or_none(mode.frequency_ci95_hz),
            finite_or_none(mode.coherence),
            f"{name}.h5",
        )
