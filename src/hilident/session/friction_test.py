"""The friction test: the configured legs, then rounds of added legs until the friction is known well enough.

The first round plays ``[friction_test]``'s legs (``friction.h5``). While the
95 % interval of the Coulomb level ``Fc`` or the viscous level ``Fv`` is wider
than ``target_ci_percent`` of its value, a further round plays the legs
:func:`hilident.pipeline.friction_plan.plan_round` chooses (``friction-2.h5``,
``friction-3.h5``, ...), every recording's points are pooled and the curve is
fitted again, its structure (Coulomb + viscous, Stribeck) chosen anew from all
of them. The test stops when the target is met, when ``max_duration_s`` is used
(``time``), when no new leg fits the travel (``travel``), or after
``max_rounds`` (``rounds``), and says which in ``summary.json["friction"]["extension"]``.

No added leg travels further than the first round's longest leg (the travel
the plan showed and the config checked against the position window), nor
further than the room the axis has on the side it starts towards; none runs
faster than the fastest configured speed. Each round is at most as long as
all the rounds before it, so an estimate made from few points costs little
when it is wrong.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from functools import partial
from pathlib import Path

import numpy as np

from hilident.config.tables import Config
from hilident.datafile.columns import read_friction_test
from hilident.errors import DataError
from hilident.pipeline import friction as pf
from hilident.pipeline.friction_plan import Leg, LegRules, RoundPlan, plan_round
from hilident.progress import Progress
from hilident.signals import generators as sig
from hilident.signals._checks import MAX_SAMPLES

#: Share of the room between the axis and the end of the position window an added leg may use.
ROOM_SHARE = 0.95
#: Fewest residual degrees of freedom (points beyond the parameters) an interval is judged on.
MIN_DOF = 6


class FrictionTest:
    """Play the friction test's rounds and fit the pooled points.

    Parameters
    ----------
    cfg : Config
    record : callable
        ``record(name, mode, setpoints, tables=...)`` -> Experiment: plays and records one run
        (:meth:`hilident.session.run.Session.record`).
    mode : str
        ``velocity``, or ``position`` on a drive without a velocity mode.
    window_rows : callable
        ``window_rows(experiment, windows)`` -> the recorded rows of each window
        (:meth:`hilident.session.run.Session._window_rows`).
    progress : Progress
    position : callable
        The axis's position now, m, or None when unknown.
    """

    def __init__(
        self,
        cfg: Config,
        record: Callable,
        mode: str,
        window_rows: Callable,
        progress: Progress,
        position: Callable[[], float | None] = lambda: None,
    ):
        self.cfg, self.record, self.mode = cfg, record, mode
        self.window_rows, self.progress, self.position = window_rows, progress, position

    def run(self, profile: sig.RampProfile) -> pf.FrictionResult:
        """The first round, then the added rounds while the intervals are wider than the target."""
        ft = self.cfg.friction_test
        fs = self.cfg.run.sample_rate_hz
        recorded = [self._play("friction", profile)]
        self.progress.step("friction: fitting the friction curve")
        result = pf.fit_recorded(recorded, ft.model)
        if ft.target_ci_percent <= 0.0:
            return result
        played = {Leg(abs(v), ft.hold_s) for v in profile.speeds_mps}
        duration = len(profile.setpoint_mps) / fs
        rules, direction = self._rules(profile)
        rounds, added, stopped, shortened = 1, [], "", False
        while not (met := _met(result, ft.target_ci_percent)):
            if rounds >= ft.max_rounds:
                stopped = "rounds"
                break
            budget = min(ft.max_duration_s - duration, duration, 0.9 * MAX_SAMPLES / fs)
            hold = ft.hold_s * (1.0 + 0.5 * rounds)  # longer legs each round, so no leg repeats another
            assert result.folded is not None  # a pooled fit keeps its folded points
            plan = plan_round(result.fit, result.folded, played, rules, hold, budget, ft.target_ci_percent, MIN_DOF)
            if not plan.legs:
                stopped = plan.limited_by
                break
            legs = self._round_profile(plan, rules, direction)
            if legs.max_excursion_m >= rules.travel_m:  # the plan's legs each fit; their sum must too
                stopped = "travel"
                break
            rounds += 1
            self._announce(rounds, plan, result)
            recorded += _steady(partial(self._play, f"friction-{rounds}", legs))
            played |= set(plan.legs)
            duration += len(legs.setpoint_mps) / fs
            shortened = shortened or bool(plan.shortened)
            added += [{"round": rounds, "speed_mps": leg.speed_mps, "hold_s": leg.hold_s} for leg in plan.legs]
            result = pf.fit_recorded(recorded, ft.model)
        result.extension = {
            "target_ci_percent": ft.target_ci_percent,
            "met": met,
            "stopped_by": "target" if met else stopped,
            "rounds": rounds,
            "duration_s": duration,
            "max_duration_s": ft.max_duration_s,
            "half_width_percent": {name: result.half_width_percent(name) for name in pf.LEVELS},
            "first_round_left_out": result.first_round_left_out,
            "legs": added,
        }
        if not met:
            result.warnings.append(_not_met(result, stopped, shortened, ft))
        return result

    # --- the rounds ------------------------------------------------------------------------

    def _play(self, name: str, profile: sig.RampProfile) -> pf.RecordedPoints:
        """Record ``profile`` as ``<name>.h5`` (with its windows) and return its steady windows."""
        windows = np.array(profile.windows, dtype=float).reshape(-1, 3)
        setpoints = profile.setpoint_mps
        if self.mode == "position":
            setpoints = sig.position_of(setpoints, self.cfg.run.sample_rate_hz)
        exp = self.record(
            name,
            self.mode,
            setpoints,
            tables={"windows": {"start": windows[:, 0], "stop": windows[:, 1], "velocity_mps": windows[:, 2]}},
        )
        kept = self.window_rows(exp, profile.windows)
        return pf.recorded_points(exp.samples["velocity_mps"], exp.samples["torque_nm"], kept)

    def _rules(self, profile: sig.RampProfile) -> tuple[LegRules, float]:
        """The added legs' bounds, and the direction their first leg runs (+1 or -1).

        A leg travels at most as far as the first round's longest leg; when the axis's position is
        known, the first leg heads where the window leaves more room, and uses at most
        :data:`ROOM_SHARE` of it.
        """
        ft, lim = self.cfg.friction_test, self.cfg.bench_limits
        travel, direction = profile.max_excursion_m, 1.0
        here = self.position()
        if here is not None and math.isfinite(here):
            above, below = lim.position_max_m - here, here - lim.position_min_m
            direction = 1.0 if above >= below else -1.0
            travel = min(travel, ROOM_SHARE * max(above, below))
        rules = LegRules(
            accel_mps2=ft.accel_mps2,
            settle_s=ft.settle_s,
            sample_rate_hz=self.cfg.run.sample_rate_hz,
            travel_m=travel,
            max_speed_mps=max(ft.speeds_mps),
            min_hold_s=ft.hold_s,
        )
        return rules, direction

    def _round_profile(self, plan: RoundPlan, rules: LegRules, direction: float) -> sig.RampProfile:
        """The set-points of a round: each planned pair of legs, first towards ``direction``, one after another."""
        pieces, windows, offset = [], [], 0
        for leg in plan.legs:
            one = sig.velocity_ramps(
                [direction * leg.speed_mps],
                leg.hold_s,
                rules.accel_mps2,
                rules.sample_rate_hz,
                rules.settle_for(leg.hold_s),
            )
            pieces.append(one.setpoint_mps)
            windows += [(a + offset, b + offset, v) for a, b, v in one.windows]
            offset += len(one.setpoint_mps)
        setpoint = np.concatenate(pieces)
        travel = sig.position_of(setpoint, rules.sample_rate_hz)
        setpoint.setflags(write=False)
        return sig.RampProfile(
            setpoint_mps=setpoint,
            windows=tuple(windows),
            speeds_mps=tuple(direction * leg.speed_mps for leg in plan.legs),
            excursion_m=(float(travel.min()), float(travel.max())),
        )

    def _announce(self, rounds: int, plan: RoundPlan, result: pf.FrictionResult) -> None:
        now = ", ".join(f"{n} +-{result.half_width_percent(n):.1f} %" for n in pf.LEVELS)
        aim = ", ".join(f"{n} +-{p:.1f} %" for n, p in plan.predicted_percent.items())
        self.progress.step(
            f"friction: round {rounds}: {len(plan.legs)} more pairs of legs, {plan.duration_s:.0f} s "
            f"({now} now, {aim} expected)"
        )


def round_recordings(first: str | Path) -> list[Path]:
    """``friction.h5`` and the rounds recorded beside it (``friction-2.h5``, ``friction-3.h5``, ...), in order."""
    first = Path(first)
    rounds = {}
    for path in first.parent.glob(f"{first.stem}-*{first.suffix}"):
        found = re.fullmatch(rf"{re.escape(first.stem)}-(\d+)", path.stem)
        if found:
            rounds[int(found[1])] = path
    return [first] + [rounds[k] for k in sorted(rounds)]


def refit_recordings(first: str | Path, model: str = "stribeck") -> pf.FrictionResult:
    """The friction a run fitted, from its recordings: ``first`` (``friction.h5``) and every round beside it,
    pooled as the run pooled them (:func:`round_recordings`)."""
    paths = round_recordings(first)
    recorded = [_read_points(paths[0])]
    for path in paths[1:]:
        recorded += _steady(partial(_read_points, path))
    return pf.fit_recorded(recorded, model)


def _read_points(path: Path) -> pf.RecordedPoints:
    return pf.recorded_points(*read_friction_test(path))


def _steady(points: Callable[[], pf.RecordedPoints]) -> list[pf.RecordedPoints]:
    """``[points()]``, or none when no window of an added round was steady (the rounds before still hold)."""
    try:
        return [points()]
    except DataError as exc:
        if "no constant-velocity window was steady" not in str(exc):
            raise
        return []


def _met(result: pf.FrictionResult, target_percent: float) -> bool:
    """Both levels' 95 % intervals within ``target_percent`` of their values, their scatter estimated from at
    least :data:`MIN_DOF` degrees of freedom.

    Stopping as soon as an interval looks narrow favours the rounds whose few points happened to agree;
    a scatter estimated from more points leaves less to that luck.
    """
    enough = result.fit.dof >= MIN_DOF
    return enough and all(result.half_width_percent(name) <= target_percent for name in pf.LEVELS)


#: What each stopping reason asks of the user.
_REMEDY = {
    "time": "the test used friction_test.max_duration_s; allow more time",
    "rounds": "the test played friction_test.max_rounds rounds; allow more",
    "travel": "no further leg fits the travel of the first round's longest leg within the position window",
}


def _not_met(result: pf.FrictionResult, stopped: str, shortened: bool, ft) -> str:
    """The warning of a test that stopped before its intervals met the target: where they are, and why."""
    widths = ", ".join(f"{n} +-{result.half_width_percent(n):.3g} %" for n in pf.LEVELS)
    why = _REMEDY.get(stopped, stopped)
    if shortened and stopped != "travel":
        why += "; the travel shortened the fastest legs (a wider position window or a higher accel_mps2 lengthens them)"
    return (
        f"friction: the 95 % intervals are {widths}, not within the +-{ft.target_ci_percent:g} % of "
        f"friction_test.target_ci_percent: {why}"
    )
