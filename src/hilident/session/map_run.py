"""The ``[map]`` part of a run: the map, one model from all positions, the notches for the whole workspace.

:class:`WorkspaceRun` is what :class:`hilident.session.run.Session` delegates to when the configuration has a
``[map]``:

1. :meth:`WorkspaceRun.map`: the mode at every mapped position (:class:`~hilident.session.map_positions.WorkspaceMap`);
2. :meth:`WorkspaceRun.fit`: the joint two-mass fit with ``k(p)``, ``d(p)`` over all positions
   (:mod:`hilident.ident.map_fit`) and its mode beside each position's own;
3. :meth:`WorkspaceRun.notch_designs`: the notches that hold the mode down over the whole range it moves
   through (:mod:`hilident.filters.covering`, on what the device stores);
4. :meth:`WorkspaceRun.verify` (``[map] verify``): the reduction measured again at every mapped position;
5. :meth:`WorkspaceRun.plot`: ``map.png``.

``summary`` collects what goes to ``summary.json["workspace"]``. The session passes what the steps need
(its recorder, its identification of one record, its gap-free selection, the cart's last position); this
module reaches no device.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from hilident.config.tables import Config
from hilident.errors import ConfigError, DataError, UsageError
from hilident.pipeline.notches import PREDICTION_MARGIN_DB, NotchDesign, covering_design, design_notches
from hilident.pipeline.plant import analysis_band
from hilident.pipeline.responses import filtered_plant_response, loop_response, pooled_loop_response
from hilident.pipeline.verification import FLOOR_HEADROOM_DB, band_floor_db, floor_limited, peak_reductions
from hilident.session.excitation import Excitation, build_excitation, excitation_recipe
from hilident.session.map_positions import MAP_MODE, MapPoint, WorkspaceMap, move_axis, nearest_resonance


class WorkspaceRun:
    """The ``[map]`` steps of one run.

    Parameters
    ----------
    cfg : Config
        The run's configuration, its amplitude chosen (``[map]``, ``[notch]``, ``[model] c``).
    record : callable
        ``record(name, mode, samples, period_samples=..., recipe=...) -> Experiment``.
    identify : callable
        ``identify(experiment, excitation) -> identification result`` (``.resonances``, ``.plant``, ``.loop``),
        not feeding the grey-box model.
    analysis_samples : callable
        ``analysis_samples(experiment, excitation) -> samples``: the whole gap-free periods of a record.
    position : callable
        ``position() -> float or None``: the cart's position at the end of the last recording, m.
    progress : Progress
    warnings : list of str
        The run's warnings, appended to.
    filter_input : str or None
        The channel that records the command entering the filter slots (the driver's ``filter_input``):
        with it, :meth:`verify` measures what the notches do to the plant, not only to the loop.
    """

    def __init__(
        self,
        cfg: Config,
        record: Callable,
        identify: Callable,
        analysis_samples: Callable,
        position: Callable[[], float | None],
        progress,
        warnings: list[str],
        filter_input: str | None = None,
    ):
        self.cfg, self.record, self.identify = cfg, record, identify
        self.analysis_samples, self.position, self.progress, self.warnings = (
            analysis_samples,
            position,
            progress,
            warnings,
        )
        self.filter_input = filter_input
        self.command_responses: dict[str, Any] = {}  # each mapped position's excitation-to-command response, by name
        self.points: list[MapPoint] = []
        self.results: dict[str, Any] = {}  # each mapped position's identification, by recording name
        self.joint: Any = None  # the WorkspaceFit, None until fitted (or when the fit failed)
        self.excitation: Excitation | None = None  # what each mapped position is excited with
        self.recipe: dict | None = None  # and its recipe, for drives that play it themselves
        self.mapped_cfg: Config | None = None  # the run's configuration with that excitation
        self.chain: list = []  # the sections the notches are stored as, for the verification's prediction
        self.chain_rate_hz = 0.0  # and the rate they run at, Hz
        self.summary: dict[str, Any] = {}  # summary.json["workspace"]

    @property
    def found(self) -> list[MapPoint]:
        """The mapped positions where a mode was found."""
        return [p for p in self.points if p.frequency_hz is not None]

    def mode_at(self, position_m: float) -> tuple[float, float] | None:
        """The mapped mode ``(frequency_hz, damping_ratio)`` at ``position_m``: linear between the mapped
        positions, held beyond the outermost (None: no mode was mapped)."""
        found = sorted(
            (p.position_m, p.frequency_hz, p.damping_ratio)
            for p in self.found
            if p.frequency_hz is not None and p.damping_ratio is not None
        )
        if not found:
            return None
        at, frequency, damping = (np.array(column, dtype=float) for column in zip(*found, strict=True))
        return float(np.interp(position_m, at, frequency)), float(np.interp(position_m, at, damping))

    # --- 1. the map --------------------------------------------------------------------------------------

    def map(self, start_m: float, reference_hz: float | None) -> list[MapPoint]:
        """The mode at every mapped position, the axis back at ``start_m``; the joint fit follows."""
        cfg, e = self.cfg, self.cfg.excitation
        # the drive's loops add their own torque while they hold the position: half the run's amplitude by default
        amplitude = cfg.map.amplitude_nm or (0.5 * e.amplitude_value if e.mode in ("torque", MAP_MODE) else 0.0)
        if not amplitude:
            raise ConfigError(
                "map.amplitude_nm", f"is needed: the run's excitation (mode = {e.mode!r}) is no torque", cfg.source
            )
        mapped_cfg = replace(
            cfg,
            excitation=replace(e, mode=MAP_MODE, amplitude_nm=amplitude, duration_s=cfg.map.duration_s or e.duration_s),
        )
        excitation = self.excitation = build_excitation(mapped_cfg)
        self.mapped_cfg = mapped_cfg
        self.recipe = excitation_recipe(mapped_cfg)

        def identify(exp, name: str):
            self.command_responses[name] = self._command_response(exp, excitation)
            return self.identify(exp, excitation)

        mapper = WorkspaceMap(cfg, self.record, identify, self.progress)
        self.points = mapper.run(excitation, start_m, reference_hz, self.recipe)
        self.results = mapper.results
        missing = [p.target_m for p in self.points if p.frequency_hz is None]
        if missing:
            self.warnings.append("map: no resonance found at " + ", ".join(f"{p:+.3f} m" for p in missing))
        self.summary["joint_fit"] = self.fit()
        return self.points

    # --- 2. one model from all positions ----------------------------------------------------------------

    def fit(self) -> dict | None:
        """One two-mass model with ``k(p)``, ``d(p)`` from every mapped position's plant response
        (:func:`hilident.ident.map_fit.fit_workspace_responses`), and its mode beside each position's own.
        A fit that fails is a warning: the map and the per-position modes stand without it."""
        from hilident.ident.map_fit import compare_modes, fit_workspace_responses

        m, found = self.cfg.map, self.found
        if not found:
            self.warnings.append("map: no joint fit of k(p) and d(p): no mapped position showed the mode")
            return None
        modes_hz = [float(p.frequency_hz or 0.0) for p in found]
        try:
            fit = fit_workspace_responses(
                [p.position_m for p in found],
                [self._result(p).plant for p in found],
                torque_constant=self.cfg.model.c,
                k_degree=m.k_degree,
                d_degree=m.d_degree,
                band_hz=self._fit_band(modes_hz),
                sample_rate_hz=self.cfg.run.sample_rate_hz,
                resonance_hz=modes_hz,
                estimate_lag=True,
            )
        except (DataError, ConfigError) as exc:
            self.warnings.append(f"map: the joint fit of k(p) and d(p) failed: {exc}")
            return None
        self.warnings += [f"map: joint fit: {w}" for w in fit.warnings]
        comparison = compare_modes(
            fit,
            [p.position_m for p in found],
            modes_hz,
            [np.nan if p.frequency_ci95_hz is None else p.frequency_ci95_hz for p in found],
        )
        self.joint = fit
        return {**fit.as_dict(), "comparison": [c.as_dict() for c in comparison]}

    def _result(self, point: MapPoint):
        return self.results[point.recording.removesuffix(".h5")]

    def _fit_band(self, modes_hz: list[float]) -> tuple[float, float]:
        """The band the joint fit explains, Hz: a quarter of the lowest mapped mode to 2.5 times the highest,
        within the analysis band. Lower, the Coulomb friction and the loop holding the position shape the
        response, which a two-mass model with viscous friction does not describe (they bias m1 and k(p) by
        percents); higher, the next mode and the sensors' dynamics."""
        assert self.excitation is not None  # set by map() before it fits
        lo, hi = analysis_band(self.cfg.identification, self.excitation.band_hz)
        return max(lo, 0.25 * min(modes_hz)), min(hi, 2.5 * max(modes_hz))

    def modes_between(self, count: int = 50) -> list[dict]:
        """The joint model's mode (with its 95 % interval) at ``count`` positions spanning the mapped ones: the
        mode moves continuously with the position, and its extreme may lie between two mapped positions (the
        beam's midspan). Empty without a joint fit."""
        return [
            {k: row[k] for k in ("position_m", "frequency_hz", "frequency_ci95_hz")}
            for row in self._joint_rows(count)
            if row["frequency_ci95_hz"] is not None
        ]

    def shaper_table(self, count: int = 50) -> list[dict]:
        """The mode along the mapped travel for a shaper scheduled by position: the joint model's at ``count``
        positions (with its damping ratio and the 95 % interval of its frequency), else the mapped points."""
        return [row for row in self._joint_rows(count) if 0.0 <= row["damping_ratio"] < 1.0] or [
            p.to_dict() for p in self.found
        ]

    def _joint_rows(self, count: int) -> list[dict]:
        """The joint model's mode at ``count`` positions spanning the mapped ones (empty without a joint fit)."""
        positions = [p.position_m for p in self.found]
        if self.joint is None or len(positions) < 2:
            return []
        span = np.linspace(min(positions), max(positions), count)
        rows = []
        for p in span:
            m = self.joint.mode_at(float(p))
            if np.isfinite(m.frequency_hz):
                ci = m.frequency_ci95_hz if np.isfinite(m.frequency_ci95_hz) else None
                rows.append(
                    {
                        "position_m": float(p),
                        "frequency_hz": m.frequency_hz,
                        "damping_ratio": m.damping_ratio,
                        "frequency_ci95_hz": ci,
                    }
                )
        return rows

    # --- 3. the notches for the whole workspace ----------------------------------------------------------

    def notch_designs(self, adapter, resonances: list, slots: list[int], plant) -> list:
        """Notches that hold the mapped mode down over the whole workspace
        (:func:`hilident.pipeline.notches.covering_design`, worst case on what ``adapter``'s device stores): one notch,
        or when one would be wider than ``[notch] max_width_ratio`` a staggered set enabled together in as many
        ``slots``; the run's other ``resonances`` get their own notches in the slots left."""
        from hilident.filters.notch import design_notch

        nc, rate = self.cfg.notch, adapter.identity.loop_rate_hz
        points = [p.to_dict() for p in self.found] + self.modes_between()

        def realise(spec):
            return adapter.stored_form(design_notch(spec, rate), spec)

        covering = covering_design(points, nc, rate, realise=realise)
        # the mode moves continuously with the position: notches enabled together must tile the whole range
        groups = list(covering.groups if covering.kind == "single" else covering.staggered)
        how = "one notch" if covering.kind == "single" else f"{len(groups)} staggered notches, enabled together"
        if not groups or len(groups) > len(slots):
            groups = [covering.single]
            how = "one notch (the widest max_width_ratio allows: too few slots for the staggered set)"
            self.warnings.append(
                f"map: {covering.message}; the device has {len(slots)} filter slot(s), so the "
                f"one notch is used and gives {covering.single.worst_attenuation_db:.1f} dB at "
                f"worst"
            )
        elif not covering.meets_target:
            self.warnings.append(f"map: {covering.message}")
        groups, how, margin = self._keep_loop_margin(points, groups, how, realise, rate)
        self.summary["covering_notch"] = {
            **covering.as_dict(),
            "used": how,
            "loop_margin": margin,
            "used_worst_attenuation_db": min(g.worst_attenuation_db for g in groups),
        }
        lo, hi = covering.range_hz
        mapped = min(resonances, key=lambda r: abs(r.frequency_hz - (lo + hi) / 2))
        designs = [
            NotchDesign(
                g.spec,
                design_notch(g.spec, rate),
                slot,
                rate,
                mapped,
                width_reason="workspace range",
                attenuation_at_ci95_db=g.worst_attenuation_db,
            )
            for slot, g in zip(slots, groups, strict=False)
        ]
        others = [r for r in resonances if r is not mapped and not lo <= r.frequency_hz <= hi]
        if others:
            designs += design_notches(others, nc, rate, slots[len(designs) :], plant.loop)
        self.chain, self.chain_rate_hz = [adapter.stored_form(d.biquad, d.spec) for d in designs], rate
        return designs

    def _loop_gains(self) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """The holding loop's gain ``L = C G`` at every mapped position, ``(position_m, frequency_hz, L)``.

        At a mapped position the drive's loop holds the cart while the excitation enters ahead of the filter
        slots (the map's torque injection), so the loop response is ``T = G / (1 + C G)`` with ``G`` the plant
        response, and ``L = G / T - 1`` on the lines both measure well (coherence at least 0.5).
        """
        gains = []
        for point in self.found:
            result = self._result(point)
            plant, loop = result.plant, result.loop
            if plant.frequency_hz.shape != loop.frequency_hz.shape or not np.allclose(
                plant.frequency_hz, loop.frequency_hz
            ):
                continue
            good = (plant.coherence >= 0.5) & (loop.coherence >= 0.5) & (np.abs(loop.response) > 0)
            if good.any():
                f = plant.frequency_hz[good]
                gains.append((point.position_m, f, plant.response[good] / loop.response[good] - 1.0))
        return gains

    @staticmethod
    def _modulus_margin(gains, sections, rate: float) -> tuple[float, float, float]:
        """``min |1 + N L|`` over every position and line with the chain ``sections`` (``N``; none: the loop as
        it was measured), and the frequency (Hz) and position (m) where it lies."""
        from hilident.filters.notch import chain_response

        worst = (math.inf, math.nan, math.nan)
        for position, f, gain in gains:
            distance = np.abs(1.0 + chain_response(sections, f, rate) * gain)
            i = int(np.argmin(distance))
            if distance[i] < worst[0]:
                worst = (float(distance[i]), float(f[i]), float(position))
        return worst

    def _keep_loop_margin(self, points, groups, how: str, realise, rate: float):
        """The notches to use, given that they sit inside the loop that holds the axis: ``groups`` when they keep
        ``[notch] keep_modulus_margin`` of its modulus margin, else one notch narrowed until it does (the
        narrowest tried when none does, with a warning). Every 20 dB over a band a few hertz wide costs phase
        far below it, where the loop crosses over: a set that holds the mode down everywhere can leave the
        loop nearly unstable. Returns ``(groups, how, margin record for summary.json)``."""
        keep, nc = self.cfg.notch.keep_modulus_margin, self.cfg.notch
        gains = self._loop_gains()
        if not keep or not gains:
            return groups, how, None
        own, _, _ = self._modulus_margin(gains, [], rate)

        def candidates():
            """``groups``, then one notch ever narrower: each designed only when the one before fell short."""
            yield groups, how
            for k in (2, 4, 8):
                ratio = nc.max_width_ratio / k
                narrower = covering_design(points, replace(nc, max_width_ratio=ratio), rate, realise=realise)
                yield (
                    [narrower.single],
                    f"one notch at most {ratio:.3g} of its centre wide, to keep the holding loop's margin",
                )

        tried = []
        for chosen, chosen_how in candidates():
            sections = [realise(g.spec) for g in chosen]
            margin, at_hz, at_m = self._modulus_margin(gains, sections, rate)
            tried.append(
                {
                    "used": chosen_how,
                    "worst_attenuation_db": min(g.worst_attenuation_db for g in chosen),
                    "modulus_margin": margin,
                    "frequency_hz": at_hz,
                    "position_m": at_m,
                }
            )
            if margin >= keep * own:
                break
        record = {
            "without_notches": own,
            "with_notches": tried[-1]["modulus_margin"],
            "frequency_hz": tried[-1]["frequency_hz"],
            "position_m": tried[-1]["position_m"],
            "keep_fraction": keep,
            "tried": tried,
        }
        if len(tried) > 1:
            first = tried[0]
            self.warnings.append(
                f"map: {first['used']} ({first['worst_attenuation_db']:.1f} dB at worst over the range) would lower "
                f"the holding loop's modulus margin min|1 + L| from {own:.2f} to {first['modulus_margin']:.2f} (at "
                f"{first['frequency_hz']:.3g} Hz, {first['position_m']:+.3f} m), below the {keep * own:.2f} that "
                f"[notch] keep_modulus_margin = {keep:g} asks for; used instead: "
                f"{chosen_how}, {tried[-1]['worst_attenuation_db']:.1f} dB at worst, margin "
                f"{tried[-1]['modulus_margin']:.2f}. A loop with a lower bandwidth leaves room for a deeper notch"
            )
        if record["with_notches"] < keep * own:
            self.warnings.append(
                f"map: even the narrowest notch tried keeps only {record['with_notches']:.2f} of the "
                f"holding loop's modulus margin {own:.2f} ([notch] keep_modulus_margin = {keep:g})"
            )
        return chosen, chosen_how, record

    # --- 4. the reduction at every mapped position -------------------------------------------------------

    def verify(self) -> dict:
        """The map's excitation again at every mapped position with the notches enabled, and the reduction there
        (:func:`hilident.pipeline.verification.peak_reductions`, before = the map's own record); the axis ends where the
        verification began.

        Two figures per position. The headline (``band_reduction_db``, ``reduction_db``) is on the filter slots
        and the plant together, command to output (:func:`hilident.pipeline.responses.filtered_plant_response`), as a
        single-position run in open-loop torque measures it; it falls back to the loop's figure when the device
        records no filter input (``measured_on`` says which). The loop's figure (``loop_band_reduction_db``) is
        what a torque disturbance at the held cart sees: the notch also takes away the damping the loop gave
        the mode, so it is the smaller of the two.

        Beside each: the figure the stored sections predict on the map's own response
        (``predicted_band_reduction_db``) and the largest the record's noise lets it show (``floor_db``,
        :func:`hilident.pipeline.verification.band_floor_db`). A record whose floor hides the target is followed
        by a longer one at the same position (:meth:`_extend`), and the figures are measured on all their periods.
        """
        excitation, nc = self.excitation, self.cfg.notch
        if excitation is None:
            raise UsageError("the map is verified only after it ran (WorkspaceRun.map)")
        start = here = self._here()
        rows, measured_on = [], None
        for i, point in enumerate(self.points):
            before = self._result(point)
            mode = nearest_resonance(list(before.resonances), point.frequency_hz)
            if mode is None:
                continue
            here = move_axis(self.cfg, self.record, f"map_verify_move_{i}", here, point.target_m)
            records = [self._verification_record(f"map_verify_{i}", excitation, self.recipe)]
            row = self._reduction_at(point, mode, records)
            longer = self._extend(row)
            if longer is not None:
                records.append(
                    self._verification_record(
                        f"map_verify_{i}_more", build_excitation(longer), excitation_recipe(longer)
                    )
                )
                row = self._reduction_at(point, mode, records)
            here = self._here()
            rows.append(row)
        move_axis(self.cfg, self.record, "map_verify_return", here, start)
        worst = min(rows, key=lambda r: r["band_reduction_db"]) if rows else None
        if worst is not None and worst["band_reduction_db"] < nc.min_reduction_db:
            floor = worst["floor_db"]
            hidden = (
                f"; the record's noise floor is {floor:.1f} dB (a longer verification, "
                "[map] verify_max_duration_s, lowers it)"
                if worst["floor_limited"]
                else ""
            )
            self.warnings.append(
                f"map verification: at {worst['position_m']:+.3f} m the largest response near the mode dropped by only "
                f"{worst['band_reduction_db']:.1f} dB (notch.min_reduction_db = {nc.min_reduction_db:g}){hidden}"
            )
        measured_on = rows[0]["measured_on"] if rows else None
        self.summary["verification"] = {
            "measured_on": measured_on,
            "positions": [{k: v for k, v in r.items() if k != "measured_on"} for r in rows],
            "worst_band_reduction_db": worst["band_reduction_db"] if worst else None,
            "worst_position_m": worst["position_m"] if worst else None,
            "worst_loop_band_reduction_db": min(r["loop_band_reduction_db"] for r in rows) if rows else None,
        }
        return self.summary["verification"]

    def _verification_record(self, name: str, excitation: Excitation, recipe: dict | None):
        """Excite the held position with ``excitation`` (``recipe`` for a drive that plays it itself):
        ``(recording name, analysed samples, excitation)``."""
        exp = self.record(name, MAP_MODE, excitation.samples, period_samples=excitation.period_samples, recipe=recipe)
        return f"{name}.h5", self.analysis_samples(exp, excitation), excitation

    def _reduction_at(self, point: MapPoint, mode, records: list) -> dict:
        """The figures at one mapped position from its verification ``records`` (:meth:`_verification_record`),
        their periods averaged together."""
        nc, ic, rate = self.cfg.notch, self.cfg.identification, self.cfg.run.sample_rate_hz
        excitation = records[0][2]
        period, bins = excitation.period_samples, excitation.excited_bins

        def response(channel: str):
            if period and all(
                len(s["excitation"]) >= 2 * period and not len(s["excitation"]) % period for _, s, _ in records
            ):
                return pooled_loop_response(
                    [s["excitation"] for _, s, _ in records],
                    [s[channel] for _, s, _ in records],
                    rate,
                    ic,
                    period,
                    bins,
                )
            response, warnings = loop_response(
                records[-1][1]["excitation"], records[-1][1][channel], rate, ic, period, bins
            )
            self.warnings += [w for w in warnings if w not in self.warnings]
            return response

        before_loop = self._result(point).loop
        after = response(ic.output)
        (loop,) = peak_reductions(before_loop, after, [mode], nc.verify_band_bandwidths)
        before, after_measured = before_loop, after
        command_before = self.command_responses.get(point.recording.removesuffix(".h5"))
        measured_on, predicted = "loop", None
        if (
            command_before is not None
            and self.filter_input is not None
            and all(self.filter_input in s for _, s, _ in records)
        ):
            before = filtered_plant_response(before_loop, command_before)
            after_measured = filtered_plant_response(after, response(self.filter_input))
            measured_on, predicted = "filtered_plant", self._predicted(before, mode)
        (r,) = peak_reductions(before, after_measured, [mode], nc.verify_band_bandwidths)
        floor = band_floor_db(before, after_measured, mode, nc.verify_band_bandwidths)
        return {
            "position_m": point.position_m,
            "frequency_hz": r["frequency_hz"],
            "band_reduction_db": r["band_reduction_db"],
            "reduction_db": r["reduction_db"],
            "predicted_band_reduction_db": predicted,
            "floor_db": floor,
            "floor_limited": floor_limited(r["band_reduction_db"], floor),
            "loop_band_reduction_db": loop["band_reduction_db"],
            "loop_reduction_db": loop["reduction_db"],
            "periods": after.n_averages,
            "recording": records[0][0],
            "recordings": [name for name, _, _ in records],
            "measured_on": measured_on,
        }

    def _predicted(self, before, mode) -> float | None:
        """The band figure the stored sections give on ``before``, the map's own filtered-plant response (its
        noise in both), dB; None without sections."""
        if not self.chain:
            return None
        from hilident.filters.notch import chain_response

        after = replace(
            before, response=before.response * chain_response(self.chain, before.frequency_hz, self.chain_rate_hz)
        )
        (r,) = peak_reductions(before, after, [mode], self.cfg.notch.verify_band_bandwidths)
        return r["band_reduction_db"]

    def _extend(self, row: dict) -> Config | None:
        """The configuration (its excitation) of a second, longer record at a position whose first one cannot
        show the target: its band figure short of ``notch.min_reduction_db`` plus 2 dB and within 6 dB of its
        noise floor. It has enough periods for all of them together to lower the floor to the target plus 6 dB
        (the averages grow as the square of the noise's amplitude ratio), and at least as many as the first,
        within ``[map] verify_max_duration_s``; None when no second record is needed, none can help, or the
        excitation is not periodic."""
        nc, m, excitation = self.cfg.notch, self.cfg.map, self.excitation
        floor, periods = row["floor_db"], row["periods"]
        if (
            excitation is None
            or not excitation.period_samples
            or periods < 2
            or not row["floor_limited"]
            or row["band_reduction_db"] >= nc.min_reduction_db + PREDICTION_MARGIN_DB
            or not math.isfinite(floor)
        ):
            return None
        period_s = excitation.period_samples / self.cfg.run.sample_rate_hz
        first_s = len(excitation.samples) / self.cfg.run.sample_rate_hz
        cap_s = m.verify_max_duration_s or 4.0 * first_s
        # at least as many again: a floor estimated from a few periods is itself uncertain by a few dB
        lower_by_db = nc.min_reduction_db + FLOOR_HEADROOM_DB - floor
        needed = max(math.ceil(periods * 10.0 ** (lower_by_db / 10.0)) - periods, periods)
        room = int(round((cap_s - first_s) / period_s)) - 1  # the second record plays its own lead-in
        extra = min(needed, room)
        if extra < 2:
            if needed >= 2:
                self.warnings.append(
                    f"map verification: the longest verification at a position, {cap_s:g} s "
                    f"([map] verify_max_duration_s), leaves no room for the {needed} more periods "
                    "its noise floor needs"
                )
            return None
        assert self.mapped_cfg is not None
        return replace(self.mapped_cfg, excitation=replace(self.mapped_cfg.excitation, duration_s=extra * period_s))

    def _command_response(self, exp, excitation: Excitation):
        """The excitation to the command entering the filter slots at one mapped position (``u/r``, the
        denominator of :func:`hilident.pipeline.responses.filtered_plant_response`); None when the device records no
        filter input."""
        if self.filter_input is None or self.filter_input not in exp.samples:
            return None
        s = self.analysis_samples(exp, excitation)
        response, warnings = loop_response(
            s["excitation"],
            s[self.filter_input],
            self.cfg.run.sample_rate_hz,
            self.cfg.identification,
            excitation.period_samples,
            excitation.excited_bins,
        )
        self.warnings += [w for w in warnings if w not in self.warnings]
        return response

    def _here(self) -> float:
        here = self.position()
        return 0.0 if here is None else here

    # --- 5. the plot -------------------------------------------------------------------------------------

    def plot(self, path: Path, title: str) -> None:
        """``map.png``: the mode over the mapped positions, the joint model and the covered range (a plot that
        cannot be drawn is a warning)."""
        from hilident.plots.map import plot_map

        fit, covering = self.joint, self.summary.get("covering_notch")

        def joint_model(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            modes = [fit.mode_at(float(p)) for p in positions]
            return np.array([m.frequency_hz for m in modes]), np.array([m.frequency_ci95_hz for m in modes])

        try:
            plot_map(
                path,
                [p.to_dict() for p in self.points],
                title=title,
                model=joint_model if fit is not None else None,
                model_label="joint model, k(p) and d(p)",
                covered_hz=tuple(covering["range_hz"]) if covering else None,
            )
        except (DataError, ValueError) as exc:
            self.warnings.append(f"map.png could not be drawn: {exc}")
