"""The move test (``[verification] move``): the same point-to-point move without and with the notch, and with
input shapers.

The thesis's last proof was a move done twice, with and without the notch, compared by eye on an
accelerometer. This step does it on any device that holds position: it moves out by ``distance_m`` (in
position mode, a trapezoid or an S-curve), dwells, moves back, first with the notch out of the way and then
with it, records both, and measures the ringing over each dwell
(:func:`hilident.motion.residual.compare_moves`).

Where the notch acts in the second move (``notch``):

* **the host's set-point** (``"host"``, and ``"auto"``: every transport streams the move as position
  set-points): the move's set-point goes through the notch chain on the host
  (:func:`hilident.motion.shaping.shape_move`), as the thesis did for its robot; it still ends exactly where
  asked, a little later. The drive's filter slots are bypassed for both moves, so only the shaping differs;
* **the drive's filter slots** (``"drive"``, the notch uploaded there): for the first move the slots holding
  the notch are disabled, then put back as they were. The notch then filters the loop's torque, the
  feedback's too, which takes away some of the damping the loop gave the mode: expect less than from
  shaping.

With ``shapers`` (:class:`~hilident.pipeline.input_shaper.MoveShaper`), the same move is made again with each
input shaper's set-point, the drive's notch out of the way (or, for ``"both"``, with the notch where the second
move had it), and measured with the band of the move without shaping (:class:`ShapedMoveResult`). A shaper
scheduled by position is moved to where each move starts: every set-point is streamed relative to it.

What is measured: the load's deflection from the cart (``load_position_m - position_m``) when the device
records a load sensor, else the cart's following error (set-point minus position): the ringing of the
flexible mode, not the position loop's slower settling.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from hilident.config.tables import Config, MoveConfig
from hilident.errors import DataError
from hilident.motion.mode_excitation import WEAK_EXCITATION, mode_excitation, peak_acceleration
from hilident.motion.profiles import MoveProfile
from hilident.motion.residual import MoveComparison, ResidualVibration
from hilident.numbers import finite_or_none
from hilident.pipeline.input_shaper import MoveShaper
from hilident.session.map_positions import move_axis

LOAD = "load_position_m"
#: Held still before each measured move, s: the vibration the axis has at rest (the floor no notch removes).
STANDSTILL_S = 0.6
#: The start of the standstill left out of the floor, s (the drive settling after it is enabled).
_SETTLING_S = 0.1


def standstill_rms(time_s: np.ndarray, signal: np.ndarray) -> float:
    """RMS of ``signal`` about a fitted line over the standstill before the move (its first ``_SETTLING_S``
    left out), in the signal's unit."""
    keep = (time_s >= _SETTLING_S) & (time_s < STANDSTILL_S)
    t, y = time_s[keep], signal[keep]
    if t.size < 3:
        return float("nan")
    return float(np.std(y - np.polyval(np.polyfit(t, y, 1), t)))


def above_floor_db(without_rms: float, with_rms: float, floor_rms: float) -> float | None:
    """The reduction of the vibration the move left above the standstill's, dB: ``20 log10`` of the ratio of
    ``sqrt(rms^2 - floor^2)``; None when the move with the notch left none above the floor (or no floor)."""
    a, b = (r * r - floor_rms * floor_rms for r in (without_rms, with_rms))
    if not np.isfinite(floor_rms) or a <= 0 or b <= 0:
        return None
    return float(10.0 * np.log10(a / b))


@dataclass(frozen=True)
class ModeExcitation:
    """How strongly the two moves' set-points excite one mode where they end
    (:func:`hilident.motion.mode_excitation.mode_excitation`).

    Attributes
    ----------
    frequency_hz, damping_ratio : float
        The mode at the move's end (the map's, interpolated over position, or the run's resonance).
    excitation : float
        ``V`` of the move without the notch: 1 is one step of its peak acceleration, a trapezoid gives 0..4.
    excitation_with_notch : float or None
        ``V`` of the set-point of the move with the notch, against the same step (None: the notch acts in the
        drive, not on the set-point).
    """

    frequency_hz: float
    damping_ratio: float
    excitation: float
    excitation_with_notch: float | None

    @property
    def predicted_reduction_db(self) -> float | None:
        """What the notch takes off the ringing the set-point causes, dB (None: not on the set-point)."""
        if self.excitation_with_notch is None or self.excitation <= 0:
            return None
        return float(20.0 * np.log10(self.excitation / max(self.excitation_with_notch, 1e-12)))

    def to_dict(self) -> dict:
        return {
            "frequency_hz": self.frequency_hz,
            "damping_ratio": self.damping_ratio,
            "excitation": self.excitation,
            "excitation_with_notch": self.excitation_with_notch,
            "predicted_reduction_db": self.predicted_reduction_db,
        }


@dataclass(frozen=True)
class ShapedMoveResult:
    """The move made with one input shaper, against the same move without shaping.

    Attributes
    ----------
    name : str
        :attr:`MoveShaper.name`.
    kind : str
        The shaper's kind where the move ends.
    frequency_hz, damping_ratio : float
        The mode the shaper acting where the move ends was designed for (the first, for several).
    residual : ResidualVibration
        Over the dwell, with the band of the move without shaping.
    rms_reduction_db, peak_to_peak_reduction_db : float
        Against the move without shaping, dB.
    added_delay_s : float
        How much later the shaped move reached its end, s.
    recordings : tuple of str
        The recording of the shaped move.
    excitations : tuple of float
        ``V`` of the shaped set-point at each of the test's modes (:attr:`MoveTestResult.modes`), against a
        step of the unshaped move's peak acceleration.
    max_accel_mps2 : float or None
        :attr:`MoveShaper.max_accel_mps2`.
    trace : tuple of ndarray
        ``(time_s, signal)`` of the measured move, for the plot.
    """

    name: str
    kind: str
    frequency_hz: float
    damping_ratio: float
    residual: ResidualVibration
    rms_reduction_db: float
    peak_to_peak_reduction_db: float
    added_delay_s: float
    recordings: tuple[str, ...]
    excitations: tuple[float, ...]
    max_accel_mps2: float | None
    trace: tuple

    def to_dict(self, floor_rms: float, without_rms: float) -> dict:
        return {
            "name": self.name,
            "kind": self.kind,
            "frequency_hz": self.frequency_hz,
            "damping_ratio": self.damping_ratio,
            "residual": self.residual.as_dict(),
            "rms_reduction_db": finite_or_none(self.rms_reduction_db),
            "peak_to_peak_reduction_db": finite_or_none(self.peak_to_peak_reduction_db),
            "rms_reduction_above_standstill_db": above_floor_db(without_rms, self.residual.rms, floor_rms),
            "added_delay_s": self.added_delay_s,
            "recordings": list(self.recordings),
            "excitations": list(self.excitations),
            "max_accel_mps2": self.max_accel_mps2,
        }


@dataclass(frozen=True)
class MoveTestResult:
    """One move test, without and with the notch, at one place of the workspace.

    Attributes
    ----------
    start_m : float
        Where the moves started, m (the encoder's axis).
    comparison : MoveComparison
        Residual vibration of each move over its dwell and the reduction, dB.
    notch_in : str
        ``"drive"`` (the drive's filter slots) or ``"host"`` (the set-point shaped on the host).
    signal : str
        What was measured: ``"load deflection"`` or ``"following error"``.
    added_delay_s : float
        How much later the move with the notch reached its end (host shaping; 0 in the drive), s.
    recordings : tuple of str
        The recordings of the two measured moves.
    traces : dict
        ``{"without": (time_s, signal), "with_notch": (time_s, signal)}`` of the measured moves (time on each
        recording's axis, as the comparison's ``move_end_s``), for the plot.
    floor_rms : float
        RMS of the signal at rest before the moves (:data:`STANDSTILL_S`), in its unit: what process noise
        and disturbances keep the mode doing, which no notch in the set-point removes.
    distance_m : float
        The move out, signed, m (the measured dwell is at ``start_m + distance_m``).
    modes : tuple of ModeExcitation
        How strongly each move's set-point excites the modes where it ends (empty: no mode known there).
    shaped : tuple of ShapedMoveResult
        The same move with each input shaper (empty: none was made).
    """

    start_m: float
    comparison: MoveComparison
    notch_in: str
    signal: str
    added_delay_s: float
    recordings: tuple[str, str]
    traces: dict
    floor_rms: float = float("nan")
    distance_m: float = float("nan")
    modes: tuple[ModeExcitation, ...] = ()
    shaped: tuple[ShapedMoveResult, ...] = ()

    @property
    def rest_limit_db(self) -> float | None:
        """The largest RMS reduction the vibration at rest lets this move show, dB: ``20 log10`` of the move
        without the notch's RMS over the RMS at rest (None without a rest record)."""
        rest, without = self.floor_rms, self.comparison.without.rms
        if not (np.isfinite(rest) and rest > 0 and without > 0):
            return None
        return float(20.0 * np.log10(without / rest))

    @property
    def weakly_excited(self) -> list[ModeExcitation]:
        """The modes the move without the notch excites less than one step of its acceleration would."""
        return [m for m in self.modes if m.excitation < WEAK_EXCITATION]

    def to_dict(self) -> dict:
        c = self.comparison
        return {
            "start_m": self.start_m,
            "distance_m": finite_or_none(self.distance_m),
            "notch_in": self.notch_in,
            "signal": self.signal,
            "added_delay_s": self.added_delay_s,
            "recordings": list(self.recordings),
            "standstill_rms_m": finite_or_none(self.floor_rms),
            "rms_reduction_above_standstill_db": above_floor_db(c.without.rms, c.with_notch.rms, self.floor_rms),
            "rest_limit_db": self.rest_limit_db,
            "modes": [m.to_dict() for m in self.modes],
            **c.as_dict(),
            "shapers": [m.to_dict(self.floor_rms, c.without.rms) for m in self.shaped],
        }


def move_profile(move: MoveConfig, distance_m: float, sample_rate_hz: float):
    """The configured move over ``distance_m`` (signed), sampled at ``sample_rate_hz``, with its dwell."""
    from hilident.motion.profiles import s_curve, trapezoid

    prefix = "verification.move."
    if move.profile == "s-curve":
        return s_curve(
            distance_m,
            move.max_velocity_mps,
            move.max_accel_mps2,
            move.jerk_mps3,
            sample_rate_hz,
            move.dwell_s,
            key_prefix=prefix,
        )
    return trapezoid(
        distance_m, move.max_velocity_mps, move.max_accel_mps2, sample_rate_hz, move.dwell_s, key_prefix=prefix
    )


def measured_signal(samples: dict[str, np.ndarray], load: bool = True) -> tuple[str, np.ndarray]:
    """The ringing a move left: the load's deflection when a load sensor was recorded and read all along (and
    ``load``), else the following error (the position set-point, relative to the start, minus the cart's
    travel)."""
    position = samples["position_m"]
    if load and _read_load(samples):
        return "load deflection", samples[LOAD] - position
    return "following error", samples["excitation"] - (position - position[0])


def _read_load(samples: dict[str, np.ndarray]) -> bool:
    """Whether the record holds the load sensor, read all along."""
    return LOAD in samples and bool(np.all(np.isfinite(samples[LOAD])))


def averaged_signal(records: list[dict[str, np.ndarray]], sample_rate_hz: float) -> tuple[str, np.ndarray, np.ndarray]:
    """What the records of one move measured (:func:`measured_signal`), averaged sample by sample.

    The move's ringing is the same in every record, the vibration the axis has at rest is not: the average of
    ``n`` records keeps the one and lowers the other by ``sqrt(n)``. The records are aligned by their sample
    index; a sample lost in any record is left out of the average (never filled). One record is returned as it
    is. The load deflection is averaged when every record read the load sensor all along, else the following
    error.

    Returns
    -------
    tuple
        ``(what, time_s, signal)``: ``"load deflection"`` or ``"following error"``, the samples' times (s, from
        the set-point's start) and the averaged signal.
    """
    load = all(_read_load(r) for r in records)
    if len(records) == 1:
        what, signal = measured_signal(records[0], load)
        return what, records[0]["sample_index"] / sample_rate_hz, signal
    index = records[0]["sample_index"]
    for r in records[1:]:
        index = np.intersect1d(index, r["sample_index"])
    total = np.zeros(index.size)
    what = ""
    for r in records:
        what, signal = measured_signal(r, load)
        total += signal[np.searchsorted(r["sample_index"], index)]
    return what, index / sample_rate_hz, total / len(records)


class MoveTest:
    """The ``[verification] move`` step.

    Parameters
    ----------
    cfg : Config
        The run's configuration (``[verification] move``, ``[run] sample_rate_hz``).
    record : callable
        ``record(name, mode, samples) -> Experiment``: the session's recorder.
    progress : Progress
    """

    def __init__(self, cfg: Config, record: Callable, progress):
        if cfg.verification.move is None:
            raise DataError("the move test needs [verification] move")
        self.cfg, self.move, self.record, self.progress = cfg, cfg.verification.move, record, progress

    def run(
        self,
        tag: str,
        start_m: float,
        distance_m: float,
        notch_in: str,
        host_sections: list | None,
        slots: DriveNotch | None,
        modes: list[tuple[float, float]] | None = None,
        shapers: Sequence[MoveShaper] = (),
    ) -> MoveTestResult:
        """Move ``distance_m`` out and back without the notch, then with it, then with each of ``shapers`` (the
        drive's ``slots`` disabled: the shaper alone); ``tag`` names the recordings.

        ``notch_in = "drive"``: the difference is the drive's filter ``slots`` (disabled for the first move);
        ``"host"``: the set-point of the second move is shaped by ``host_sections`` (biquads at the set-point
        rate), and the drive's ``slots`` (if any) stay disabled for both moves, so only the shaping differs.
        ``modes``: ``(frequency_hz, damping_ratio)`` of the modes where the move ends, for how strongly each
        move's set-point excites them (:class:`ModeExcitation`).
        """
        from hilident.motion.residual import compare_moves

        rate = self.cfg.run.sample_rate_hz
        out, back = (move_profile(self.move, d, rate) for d in (distance_m, -distance_m))
        with_out, with_back, delay = _with_notch(out, back, notch_in, host_sections)
        names = (f"move{tag}_without", f"move{tag}_with")

        self.progress.step(f"move test{tag}: {distance_m:+.3f} m from {start_m:+.3f} m, without the notch")
        with slots.disabled() if slots is not None else contextlib.nullcontext():
            without = self._out_and_back(names[0], out, back)
            if notch_in == "host":
                self.progress.step(f"move test{tag}: with the notch shaping the set-point")
                with_notch = self._out_and_back(names[1], with_out, with_back)
        if notch_in == "drive":
            self.progress.step(f"move test{tag}: with the notch in the drive's filter slots")
            with_notch = self._out_and_back(names[1], with_out, with_back)
        what, t_without, signal_without = without
        _, t_with, signal_with = with_notch
        band = self.move.settle_band_m or None
        ends = (STANDSTILL_S + out.move_end_s, STANDSTILL_S + with_out.move_end_s)
        comparison = compare_moves(
            (t_without, signal_without, ends[0]),
            (t_with, signal_with, ends[1]),
            self.move.dwell_s,
            band=band,
            detrend="linear",
        )
        if comparison.without.rms <= 0:
            raise DataError(f"move test{tag}: the move without the notch left no measurable vibration")
        shaped = self._shaped_moves(
            tag, shapers, (out, back, with_out, with_back), notch_in, slots, start_m + distance_m, comparison, modes
        )
        # the vibration at rest before every move of this place: the more records, the steadier the floor
        rests = [(t_without, signal_without), (t_with, signal_with), *(m.trace for m in shaped)]
        floor = float(np.sqrt(np.mean([standstill_rms(t, y) ** 2 for t, y in rests])))
        return MoveTestResult(
            start_m,
            comparison,
            notch_in,
            what,
            float(delay),
            (f"{names[0]}.h5", f"{names[1]}.h5"),
            {"without": (t_without, signal_without), "with_notch": (t_with, signal_with)},
            floor,
            distance_m,
            excitations(out, with_out if notch_in == "host" else None, modes or []),
            tuple(shaped),
        )

    def _shaped_moves(
        self,
        tag: str,
        shapers: Sequence[MoveShaper],
        moves: tuple[MoveProfile, MoveProfile, MoveProfile, MoveProfile],
        notch_in: str,
        slots: DriveNotch | None,
        end_m: float,
        comparison: MoveComparison,
        modes: list[tuple[float, float]] | None,
    ) -> list[ShapedMoveResult]:
        """The move with each of ``shapers``: alone, the drive's notch out of the way; a shaper with the notch,
        on the notch's set-point (``moves = (out, back, with_out, with_back)``) or with the drive's slots on."""
        out, back, with_out, with_back = moves
        shaped: list[ShapedMoveResult] = []
        for paired in (False, True):
            chosen = [s for s in shapers if s.with_notch == paired]
            if not chosen:
                continue
            keep_slots = slots is None or (paired and notch_in == "drive")
            there, home = (with_out, with_back) if paired else (out, back)
            with contextlib.nullcontext() if keep_slots or slots is None else slots.disabled():
                shaped += [
                    self._shaped_move(tag, s, (there, home, out), end_m, comparison, modes or []) for s in chosen
                ]
        return shaped

    def _out_and_back(self, name: str, there: MoveProfile, home: MoveProfile) -> tuple[str, np.ndarray, np.ndarray]:
        """The move out (after :data:`STANDSTILL_S` at rest) and back, ``repeats`` times: what was measured, its
        time (s) and the signal averaged over the repeats (:func:`averaged_signal`)."""
        rate = self.cfg.run.sample_rate_hz
        still = np.zeros(int(round(STANDSTILL_S * rate)))  # the vibration the axis has at rest, before it moves
        records = []
        for k in range(self.move.repeats):
            label = name if k == 0 else f"{name}_{k + 1}"
            records.append(self.record(label, "position", np.concatenate([still, there.position_m])).samples)
            self.record(f"{label}_back", "position", home.position_m)
        return averaged_signal(records, rate)

    def _shaped_move(
        self,
        tag: str,
        shaper: MoveShaper,
        moves: tuple[MoveProfile, MoveProfile, MoveProfile],
        end_m: float,
        comparison: MoveComparison,
        modes: list[tuple[float, float]],
    ) -> ShapedMoveResult:
        """``moves = (there, home, unshaped)``: the move out and back (the notch's set-point for a shaper with the
        notch on the host) made with ``shaper``'s set-point, measured with the unshaped move's band; its delay
        counted from the ``unshaped`` move's end, its ``V`` against that move's peak acceleration."""
        from hilident.motion.residual import reduction_db, residual_vibration
        from hilident.motion.shaping import impulse_shaped_move

        there, home, unshaped = moves
        rate = self.cfg.run.sample_rate_hz
        # each set-point starts from 0 where its move starts: a schedule by position is moved there
        shaped_out, shaped_back = (
            impulse_shaped_move(p, shaper.for_move_from(origin))
            for p, origin in ((there, end_m - there.distance_m), (home, end_m))
        )
        self.progress.step(f"move test{tag}: with the {shaper.name}")
        name = f"move{tag}_{shaper.tag}"
        _, t, signal = self._out_and_back(name, shaped_out.profile, shaped_back.profile)
        residual = residual_vibration(
            t,
            signal,
            STANDSTILL_S + shaped_out.profile.move_end_s,
            self.move.dwell_s,
            band=comparison.without.band,
            detrend="linear",
        )
        acting = shaper.design_at(end_m)
        peak = peak_acceleration(unshaped.position_m, rate)
        v = tuple(
            mode_excitation(
                shaped_out.profile.position_m, rate, shaped_out.profile.move_end_index, f, z, reference_accel_mps2=peak
            )
            for f, z in modes
        )
        return ShapedMoveResult(
            shaper.name,
            acting.kind,
            float(np.atleast_1d(acting.frequency_hz)[0]),
            float(np.atleast_1d(acting.damping_ratio)[0]),
            residual,
            reduction_db(comparison.without.rms, residual.rms),
            reduction_db(comparison.without.peak_to_peak, residual.peak_to_peak),
            float(shaped_out.profile.move_end_s - unshaped.move_end_s),
            (f"{name}.h5",),
            v,
            shaper.max_accel_mps2,
            (t, signal),
        )


def _with_notch(
    out: MoveProfile, back: MoveProfile, notch_in: str, host_sections: list | None
) -> tuple[MoveProfile, MoveProfile, float]:
    """The move out and back with the notch, and how much later it ends (s): the set-point shaped by
    ``host_sections`` (``notch_in = "host"``), else the same set-point (the notch acts in the drive)."""
    from hilident.motion.shaping import shape_move

    if notch_in != "host":
        return out, back, 0.0
    if not host_sections:
        raise DataError("move test: no notch to shape the move with")
    shaped_out, shaped_back = (shape_move(p, host_sections) for p in (out, back))
    return shaped_out.profile, shaped_back.profile, shaped_out.added_delay_s


def excitations(
    move: MoveProfile, shaped: MoveProfile | None, modes: list[tuple[float, float]]
) -> tuple[ModeExcitation, ...]:
    """How strongly ``move`` (and ``shaped``, its set-point with the notch; None: the notch is in the drive)
    excites each of ``modes`` ``(frequency_hz, damping_ratio)``, against a step of ``move``'s peak
    acceleration."""
    rate = move.sample_rate_hz
    peak = peak_acceleration(move.position_m, rate)
    found = []
    for f, zeta in modes:
        v = mode_excitation(move.position_m, rate, move.move_end_index, f, zeta)
        v_shaped = (
            None
            if shaped is None
            else mode_excitation(shaped.position_m, rate, shaped.move_end_index, f, zeta, reference_accel_mps2=peak)
        )
        found.append(ModeExcitation(float(f), float(zeta), v, v_shaped))
    return tuple(found)


class DriveNotch:
    """The filter slots holding the uploaded notch, disabled for the move without it and put back after."""

    def __init__(self, adapter, slots: list[int]):
        self.adapter, self.slots = adapter, slots

    @contextlib.contextmanager
    def disabled(self) -> Iterator[None]:
        saved = {slot: self.adapter.save_filter(slot) for slot in self.slots}
        for slot in self.slots:
            self.adapter.disable_filter(slot)
        try:
            yield
        finally:
            for slot, contents in saved.items():
                self.adapter.restore_filter(slot, contents)


def move_distance(move: MoveConfig, start_m: float, low_m: float, high_m: float) -> float:
    """``move.distance_m``, or the same move the other way when it would leave ``[low_m, high_m]`` from
    ``start_m`` (a move test at the end of the travel goes back towards the middle)."""
    for distance in (move.distance_m, -move.distance_m):
        if low_m <= start_m + distance <= high_m:
            return distance
    raise DataError(
        f"[verification.move] distance_m = {move.distance_m:g} m does not fit either way from "
        f"{start_m:+.3f} m within [{low_m:g}, {high_m:g}] m"
    )


def run_move_tests(
    cfg: Config,
    record: Callable,
    progress,
    warnings: list[str],
    driver,
    adapter,
    designs: list,
    in_slots: bool,
    start_m: float,
    places_m: list[float],
    position: Callable[[], float | None],
    modes_at: Callable[[float], list[tuple[float, float]]] | None = None,
    shapers: Sequence[MoveShaper] = (),
) -> list[MoveTestResult]:
    """The move test from ``start_m`` (or, with a map, from each of ``places_m``, then back to ``start_m``).

    Parameters
    ----------
    cfg : Config
        ``[verification] move``, ``[map]`` (its margin and the moves between places), ``[limits]``.
    record : callable
        ``record(name, mode, samples) -> Experiment``: the session's recorder.
    progress : Progress
    warnings : list of str
        The run's warnings, appended to.
    driver : DriverDescription
        Its channels say whether a load sensor could be streamed.
    adapter : DeviceAdapter
        Its filter slots, for ``notch = "drive"`` and to bypass them while the host shapes the move.
    designs : list of NotchDesign
        The run's notches.
    in_slots : bool
        Whether they were uploaded and read back as written.
    start_m : float
        Where the axis is, m.
    places_m : list of float
        The mapped positions, m (empty: the move test from ``start_m`` only).
    position : callable
        ``position() -> float or None``: the cart's position at the end of the last recording, m.
    modes_at : callable, optional
        ``modes_at(position_m) -> [(frequency_hz, damping_ratio), ...]``: the modes at a position, for how
        strongly each move excites them; a move that excites them weakly gets a warning
        (:func:`weak_excitation_warning`).
    shapers : sequence of MoveShaper
        The input shapers each place's move is made with as well (:class:`ShapedMoveResult`).
    """
    move = cfg.verification.move
    if not designs or move is None:
        warnings.append("move test: no notch was designed, so there is nothing to compare")
        return []
    notch_in = _notch_place(move, in_slots)
    slots, host = _notch_means(adapter, designs, in_slots, notch_in, cfg.run.sample_rate_hz)
    _warn_unstreamed_load(cfg, driver, warnings)
    tester = MoveTest(cfg, record, progress)
    lim, margin = cfg.bench_limits, cfg.map.margin_m
    results, here = [], start_m
    for target, tag in _move_places(start_m, places_m):
        if tag:
            here = move_axis(cfg, record, f"move{tag}_approach", here, target)
        distance = move_distance(move, here, lim.position_min_m + margin, lim.position_max_m - margin)
        modes = modes_at(here + distance) if modes_at is not None else []
        results.append(tester.run(tag, here, distance, notch_in, host, slots, modes, shapers))
        last = position()
        here = here if last is None else last
    if places_m:
        move_axis(cfg, record, "move_return", here, start_m)
    weak = weak_excitation_warning(move, results, cfg.run.sample_rate_hz)
    if weak:
        warnings.append(weak)
    return results


def _notch_place(move: MoveConfig, in_slots: bool) -> str:
    """Where the notch acts in the second move: ``"drive"`` (its filter slots) or ``"host"`` (the set-point).

    Every transport streams the move as position set-points, so by default the notch shapes that set-point;
    ``notch = "drive"`` compares the drive's filter slots instead.

    Raises
    ------
    DataError
        ``notch = "drive"`` while the notch is not in the drive's filter slots (``in_slots`` false).
    """
    notch_in = "drive" if move.notch == "drive" else "host"
    if notch_in == "drive" and not in_slots:
        raise DataError(
            '[verification.move] notch = "drive": the notch is not in the drive\'s filter slots '
            "(not uploaded, or not read back as written)"
        )
    return notch_in


def _notch_means(
    adapter, designs: list, in_slots: bool, notch_in: str, sample_rate_hz: float
) -> tuple[DriveNotch | None, list | None]:
    """The drive's filter slots holding the notch (None: it is not in them) and, when the host shapes the move
    (``notch_in = "host"``), the notch's sections at the set-point rate ``sample_rate_hz`` in Hz (else None)."""
    from hilident.filters.notch import design_notch

    slots = DriveNotch(adapter, [d.slot for d in designs]) if in_slots else None
    host = [design_notch(d.spec, sample_rate_hz) for d in designs] if notch_in == "host" else None
    return slots, host


def _warn_unstreamed_load(cfg: Config, driver, warnings: list[str]) -> None:
    """Warn when the device has a load sensor that the run does not stream (the ringing is then measured on the
    following error)."""
    streamed = cfg.run.channels or [c.name for c in driver.streamed_channels]
    if LOAD in [c.name for c in driver.channels] and LOAD not in streamed:
        warnings.append(
            f"move test: {driver.name} has a load sensor ({LOAD}) that is not streamed; add it to "
            "[run] channels to measure the load's ringing rather than the following error"
        )


def _move_places(start_m: float, places_m: list[float]) -> list[tuple[float, str]]:
    """``(position in m, recording tag)`` of each place the move test starts from: each mapped place, tagged by
    its index, or ``start_m`` alone, untagged."""
    return [(p, f"_{i}") for i, p in enumerate(places_m)] or [(start_m, "")]


def weak_excitation_warning(move: MoveConfig, results: list[MoveTestResult], sample_rate_hz: float) -> str | None:
    """A warning naming the moves that excite their mode less than one step of their acceleration, with the
    velocity and acceleration nearest the configured ones that would excite every mode of the test (None: every
    move excites its modes). Only accelerations at or above the configured one are suggested: a gentler move
    rings less, and what it has to ring above, the vibration at rest, stays the same."""
    from hilident.motion.mode_excitation import exciting_move

    weak = [(r, m) for r in results for m in r.weakly_excited]
    if not weak:
        return None

    def rang(r: MoveTestResult) -> str:
        limit = r.rest_limit_db
        return "" if limit is None else f", rang {limit:.1f} dB above rest"

    where = "; ".join(
        f"ending at {r.start_m + r.distance_m:+.3f} m, {m.frequency_hz:.2f} Hz: V = {m.excitation:.2f}{rang(r)}"
        for r, m in weak
    )
    text = (
        f"move test: the move excites the mode less than one step of its acceleration would ({where}). "
        "A move that rings little above the axis at rest shows the vibration at rest and at the stop more "
        "than the notch."
    )

    def profile(distance: float, v: float, a: float) -> tuple[np.ndarray, int]:
        p = move_profile(replace(move, max_velocity_mps=v, max_accel_mps2=a), distance, sample_rate_hz)
        return p.position_m, p.move_end_index

    tested = [r for r in results if r.modes and np.isfinite(r.distance_m)]
    best = exciting_move(
        profile,
        [r.distance_m for r in tested],
        [[(m.frequency_hz, m.damping_ratio) for m in r.modes] for r in tested],
        sample_rate_hz,
        np.linspace(0.5, 1.0, 11) * move.max_velocity_mps,
        np.linspace(1.0, 1.5, 11) * move.max_accel_mps2,
        (move.max_velocity_mps, move.max_accel_mps2),
    )
    if best is None or best.min_excitation <= min(m.excitation for _, m in weak):
        return text + (
            " No velocity of 0.5-1 times max_velocity_mps with an acceleration of 1-1.5 times "
            "max_accel_mps2 excites every mode of this test better."
        )
    return text + (
        f" [verification] move with max_velocity_mps = {best.max_velocity_mps:.3g} and max_accel_mps2 = "
        f"{best.max_accel_mps2:.3g} excites every mode of this test at V >= {best.min_excitation:.2f}"
        f" ({best.max_accel_mps2 / move.max_accel_mps2:.3g} times the acceleration: check the torque it "
        "needs against [limits] torque_nm)."
    )


def plot_worst_move(results: list[MoveTestResult], path: Path, config_name: str, warnings: list[str]) -> None:
    """``moves.png``: the move without and with the notch where the reduction was least (a plot that cannot be
    drawn is a warning)."""
    from hilident.plots.moves import plot_moves

    worst = min(results, key=lambda r: r.comparison.rms_reduction_db)
    (t0, y0), (t1, y1) = worst.traces["without"], worst.traces["with_notch"]
    try:
        plot_moves(
            path,
            worst.comparison,
            t0,
            y0,
            t1,
            y1,
            signal_name=worst.signal,
            subject=f"{config_name}, from {worst.start_m:+.3f} m",
            added_delay_s=worst.added_delay_s or None,
            shaped=tuple((m.name, *m.trace, m.residual, m.added_delay_s) for m in worst.shaped),
        )
    except (DataError, ValueError) as exc:
        warnings.append(f"moves.png could not be drawn: {exc}")
