"""One bench run: connect, guard limits, excite, record, identify, upload, verify, report.

The order of a session is fixed and every step leaves something on disk:

1. connect to the device (or start the embedded emulator) and load the limits;
2. friction test: constant-velocity legs both ways -> ``friction.h5``;
3. identification run with the configured excitation -> ``identification.h5``;
4. friction removal, FRF with coherence, resonances, notch design;
5. upload the notches, read them back, compare, enable;
6. verification run with the same excitation -> ``verification.h5``;
7. ``summary.json`` and plots.

Before step 1 the whole plan is built and checked (sizes, rates, travel,
channels) so nothing that can be known in advance fails after the axis moved;
on a real port the plan is shown and the user's go-ahead is asked for before
anything moves. Identification measures the bare plant: filter slots holding
filters are bypassed first and put back if the session ends before its upload.

On every ending (normal, error, signal, full disk) the device is commanded
safe first, then the filter slots are restored when needed, then every
recording is closed with its status and cause, then the device is released.

The session keeps the order; its parts live beside it (``docs/results.md``):
:mod:`hilident.session.connection` (the device, a complete :class:`ConnectedDevice`),
:mod:`hilident.session.experiment` (recording), :mod:`hilident.session.auto_amplitude`,
:mod:`hilident.session.slot_bypass`, :mod:`hilident.session.excitation`,
:mod:`hilident.io.summary` (the typed ``summary.json``).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hilident import endings, html_report
from hilident.adapters.backends import adapter_class
from hilident.config.tables import Config, check_auto_amplitude
from hilident.drivers.description import DriverDescription, check_run_against_driver, find_driver
from hilident.drivers.tools import check_run_mapping
from hilident.errors import ArmingRefused, ConfigError, DataError, DeviceError, HilidentError, UsageError
from hilident.events import StreamStats
from hilident.io.serialise import write_json
from hilident.io.summary import (
    NOT_REACHED,
    DevicePart,
    ExcitationPart,
    Summary,
    UploadOutcome,
    VerificationPart,
)
from hilident.lazy import lazy_module
from hilident.pipeline.input_shaper import MoveShapers, move_shapers
from hilident.plots import figures as report
from hilident.plots.common import plot_title
from hilident.progress import Progress
from hilident.session.auto_amplitude import AutoAmplitude
from hilident.session.connection import ConnectedDevice, DeviceConnection
from hilident.session.excitation import Excitation, build_excitation, excitation_recipe
from hilident.session.experiment import Experiment, ExperimentRecorder
from hilident.session.map_positions import MAP_MODE
from hilident.session.map_run import WorkspaceRun
from hilident.session.move_test import MoveTestResult, plot_worst_move, run_move_tests
from hilident.session.plan import RunPlan, excitation_travel_m, make_plan
from hilident.session.slot_bypass import BypassedSlots
from hilident.signals import generators as sig

#: The analysis steps, imported once an experiment needs them (a run ended before that starts and stops faster).
pipeline_friction = lazy_module("hilident.pipeline.friction")
pipeline_selection = lazy_module("hilident.pipeline.selection")
pipeline_plant = lazy_module("hilident.pipeline.plant")
pipeline_greybox = lazy_module("hilident.pipeline.greybox")
pipeline_notches = lazy_module("hilident.pipeline.notches")
pipeline_responses = lazy_module("hilident.pipeline.responses")
pipeline_verification = lazy_module("hilident.pipeline.verification")
pipeline_loop = lazy_module("hilident.pipeline.loop_analysis")
pipeline_output_modes = lazy_module("hilident.pipeline.output_modes")
#: The upload step, shared with ``hilident upload``.
uploading = lazy_module("hilident.session.upload")

#: Share of a friction window's samples its recorded rows must hold for the window to be averaged.
_WINDOW_COVER = 0.9


def check_excitation_travel(cfg: Config, excitation: Excitation) -> None:
    """A set-point perturbation must keep the axis within half the position window (it starts anywhere in it)."""
    e, lim = cfg.excitation, cfg.bench_limits
    if not e.closed_loop:
        return  # a torque excitation's travel depends on the plant; the limits guard it
    travel = excitation_travel_m(e.mode, excitation.samples, cfg.run.sample_rate_hz)
    half = (lim.position_max_m - lim.position_min_m) / 2
    if travel >= half:
        raise ConfigError(
            f"excitation.{e.amplitude_key}",
            f"the {e.mode} set-point perturbation travels up to {travel:.4g} m from where the axis holds, more "
            f"than half the position window [{lim.position_min_m:g}, {lim.position_max_m:g}] m (a smaller "
            f"amplitude or a higher f_min_hz)",
            cfg.source,
        )


def check_it_moved(cfg: Config, output: np.ndarray, friction) -> None:
    """A DataError that says what to change when the axis did not move at all during the identification."""
    finite = output[np.isfinite(output)]
    if finite.size and np.ptp(finite) > 0.0:
        return
    e = cfg.excitation
    held = ""
    if friction is not None and e.mode in ("torque", "torque_injection"):
        fs = max(friction.fit.params.Fs, friction.fit.params.Fc)
        held = (
            f"; the friction test measured a breakaway of {fs:.3g} N*m, so an amplitude of at least "
            f"{3 * fs:.3g} N*m is needed to move it over most of each period"
        )
    raise DataError(
        f"identification: the axis did not move ({cfg.identification.output} constant at "
        f"{finite[0] if finite.size else float('nan'):g}): the excitation ({e.amplitude:g} "
        f"{ {'velocity': 'm/s', 'position': 'm'}.get(e.mode, 'N*m') }) is too weak"
        f"{held}; raise excitation.{e.amplitude_key}"
        + (' or set it to "auto"' if e.amplitude_key == "amplitude_nm" else "")
    )


class Session(DeviceConnection):
    """A whole bench run as described by one configuration.

    Parameters
    ----------
    cfg : Config
    out_dir : path
        Where recordings, plots and ``summary.json`` go.
    progress : Progress, optional
    """

    def __init__(
        self,
        cfg: Config,
        out_dir: str | Path,
        progress: Progress | None = None,
        confirm: Callable[[RunPlan], bool] | None = None,
        dry_run: bool = False,
        plots: bool = True,
        save: bool = False,
    ):
        cfg.bench_limits  # noqa: B018 - raises the ConfigError of a config without [limits] before anything starts
        self.cfg = cfg
        self.out = Path(out_dir)
        self.progress = progress or Progress(enabled=False)
        self.driver: DriverDescription | None = None
        self.device: ConnectedDevice | None = None
        self.recorder: ExperimentRecorder | None = None  # made once the device is connected
        self.warnings: list[str] = []
        self.notes: list[str] = []  # worth knowing, nothing to act on (summary.json "notes")
        self.summary: dict = {}
        self.result: Summary | None = None  # the typed summary behind ``summary`` once the run has ended
        self._analysed: dict[str, dict[str, np.ndarray]] = {}  # gap-free samples of each analysed run
        self.confirm = confirm
        self.dry_run = dry_run
        self.plots = plots
        self.save = save  # store the device's parameters once the new notches are verified
        self.plan: RunPlan | None = None
        self.slots = BypassedSlots()  # what the filter slots held, and what is bypassed until the upload
        self.friction_mode = "velocity"  # or "position" on a drive without a velocity mode (set by prepare)
        self._uploaded = False
        self._auto: dict | None = None  # the automatic amplitude's choice, trials and reason
        self.workspace: WorkspaceRun | None = None  # [map]: the map, the joint fit, the covering notches
        self.move_results: list[MoveTestResult] | None = None  # [verification] move, at each place it ran
        self.move_shapers: MoveShapers | None = None  # the input shapers the move test made its moves with
        self.position_m: float | None = None  # the cart's position at the end of the last recording, m
        self.loop = None  # the drive's loop around the identified plant (a drive with [loop] only)
        self.joint = None  # the modes of identification.output and identification.outputs together
        self.gains = None  # the gain step ([tuning] upload), while it may have to put the old gains back
        # (samples, excitation) of the identification: a torque injection breaks the loop there
        self._identification: tuple[dict, Excitation] | None = None
        self._friction = None  # the friction fit the identification used

    # --- connection -----------------------------------------------------------------------

    def connect(self) -> None:
        """Open the device (one session per device), or start the embedded emulator and open it like a device.

        The adapter brings the device to a known state as it opens (stale
        frames discarded, axis stopped, latched faults reported and cleared
        only when allowed); the limits the device enforces are loaded.
        """
        device = self.open_device()
        self.recorder = ExperimentRecorder(device, self.out, self.progress, self.warnings)
        lim = self.cfg.bench_limits
        self.adapter.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)

    # --- filter slots: identify the bare plant ---------------------------------------------

    @property
    def filters_found(self) -> list[dict]:
        """What every filter slot held when the session began (for the plan and summary.json)."""
        return self.slots.found

    def _read_filter_slots(self) -> None:
        self.slots.read(self.adapter)

    def _bypass_filters(self) -> None:
        self.slots.bypass(self.adapter, self.progress)

    def _restore_filters(self) -> None:
        """Put back what the slots held when the session ends before its upload. Never raises."""
        if not self._uploaded and self.adapter is not None:
            self.slots.restore(self.adapter, self.warnings)

    # --- experiments ----------------------------------------------------------------------

    def record(
        self,
        name: str,
        mode: str,
        excitation: np.ndarray,
        tables: dict | None = None,
        period_samples: int | None = None,
        recipe: dict | None = None,
    ) -> Experiment:
        """Stream ``excitation`` in ``mode`` and record it to ``<out>/<name>.h5``
        (:meth:`hilident.session.experiment.ExperimentRecorder.record`, with the session's configuration)."""
        if self.recorder is None:
            raise UsageError(f"{name}: the session records only once connected (Session.connect)")
        exp = self.recorder.record(self.cfg, name, mode, excitation, tables, period_samples, recipe)
        if "position_m" in exp.samples and len(exp.samples["position_m"]):
            self.position_m = float(exp.samples["position_m"][-1])
        return exp

    @property
    def totals(self) -> StreamStats:
        """The stream counters of every run recorded so far, added."""
        return self.recorder.totals if self.recorder is not None else StreamStats()

    @property
    def clocks(self) -> list[dict]:
        """Each recorded run's clock report (who kept the bus clock, how well); empty on other transports."""
        return self.recorder.clocks if self.recorder is not None else []

    # --- the whole run ----------------------------------------------------------------------

    def run(self) -> dict:
        """Run every step; returns the summary (also written to ``summary.json``).

        With ``dry_run`` it connects, checks and plans, and returns
        ``{"dry_run": True, "plan": ...}`` without moving anything.
        """
        excitation, profile = self.prepare()
        started = time.monotonic()
        friction = plant = verification = None
        designs, upload = [], UploadOutcome()
        step = "connect"
        try:
            self.connect()
            self._read_filter_slots()
            plan = self.plan = make_plan(
                self.cfg, excitation, profile, self.adapter, self.filters_found, self.friction_mode
            )
            self._arm(plan)
            if self.dry_run:
                return {"dry_run": True, "plan": plan.to_dict()}
            self._bypass_filters()
            step = "friction test"
            friction = self._friction_step(profile)
            if self.cfg.excitation.amplitude_auto:
                step = "auto amplitude"
                excitation = self._auto_amplitude(friction)  # the run then plays the chosen amplitude
            step = "identification"
            ident = self.record(
                "identification",
                self.cfg.excitation.mode,
                excitation.samples,
                period_samples=excitation.period_samples,
                recipe=excitation_recipe(self.cfg),
            )
            plant = self._identify(ident, excitation, friction)
            if self.cfg.map.enabled:
                step = "map"
                self._map_step(ident, excitation, friction, plant)
            step = "notch upload"
            designs, upload = self._notch_step(plant)
            self.loop = self._loop_step(plant, designs, friction)
            step = "verification"
            verification = self._verify(excitation, plant, designs)
            if self.workspace is not None and verification is not None and self.cfg.map.verify:
                step = "map verification"
                self.workspace.verify()
            if self.loop is not None and self.cfg.tuning.upload:
                step = "gain upload"
                self._gain_step(upload, friction)
            if self.cfg.verification.move is not None:
                step = "move test"
                self.move_results = self._move_step(designs, upload)
            step = "save"
            self._save_step(upload, verification)
        except BaseException as exc:
            with endings.shielded():
                self.safe_stop()
                self._restore_gains(f"the {step} step ended: {exc}")  # before the partial summary says so
            if isinstance(exc, HilidentError) and (friction is not None or plant is not None):
                with endings.shielded():  # what the steps before found is kept, and the step that failed named
                    self._write_partial_summary(
                        step, exc, friction, plant, designs, upload, verification, time.monotonic() - started
                    )
            raise
        finally:
            with endings.shielded():
                self._restore_filters()  # nothing to do once the new notches are uploaded
                self._restore_gains()
                self.close()
        endings.raise_pending()
        model = self._greybox()
        if self.plots and self.workspace is not None:  # before the summary: a failed plot is one of its warnings
            self.workspace.plot(
                self.out / "map.png", plot_title(Path(self.cfg.source).name, what="Mode over the workspace")
            )
        if self.plots and self.move_results:
            plot_worst_move(self.move_results, self.out / "moves.png", Path(self.cfg.source).name, self.warnings)
        self.result = self._summary(
            friction, plant, designs, upload, verification, time.monotonic() - started, model=model
        )
        self.summary = self.result.to_dict()
        write_json(self.out / "summary.json", self.summary)
        if self.plots:
            self._plots(friction, plant, designs, verification, excitation.band_hz, model)
        html_report.write_report_quietly(self.out)
        return self.summary

    def _restore_gains(self, reason: str = "the run ended before the gains were proven") -> None:
        """Gains written and not yet proven go back (never raises; once)."""
        if self.gains is not None:
            self.gains.restore(reason)

    def prepare(self):
        """Everything that can be checked without the device, before it is opened.

        The output folder must be writable; the driver is found; the
        excitation and the friction test's profile are built (their sizes were
        bounded when the config was loaded); the friction test's travel must
        fit the position window. Returns ``(excitation, friction_profile)``.
        """
        self._prepare_out()
        cfg = self.cfg
        driver = self.driver = find_driver(cfg.device.driver, cfg.device.driver_paths)
        if (error := adapter_class(driver.transport).run_refusal(driver)) is not None:  # cannot play
            raise ConfigError(error.key, error.message, cfg.source)
        modes = check_run_against_driver(cfg, driver)
        if cfg.map.enabled and not {"position", MAP_MODE} <= set(modes):
            raise ConfigError(
                "map",
                f"driver {driver.name!r} offers the modes {', '.join(modes) or 'none'}: a map "
                f"needs position (to move) and {MAP_MODE} (to hold while exciting)",
                cfg.source,
            )
        check_auto_amplitude(cfg)  # again: a config changed in code after loading
        excitation = build_excitation(cfg)
        check_excitation_travel(cfg, excitation)
        # a drive without a velocity mode runs the friction test's legs as a position profile
        self.friction_mode = "velocity" if "velocity" in modes else "position"
        run_modes = (
            [cfg.excitation.mode]
            + [self.friction_mode] * cfg.friction_test.enabled
            + ["position", MAP_MODE] * cfg.map.enabled
        )
        check_run_mapping(cfg, driver, run_modes)  # what the run maps or writes, against the EDS, before it moves
        profile = None
        ft = cfg.friction_test
        if ft.enabled:
            profile = sig.velocity_ramps(ft.speeds_mps, ft.hold_s, ft.accel_mps2, cfg.run.sample_rate_hz, ft.settle_s)
            lim = cfg.bench_limits
            if profile.max_excursion_m >= (lim.position_max_m - lim.position_min_m) / 2:
                raise ConfigError(
                    "friction_test.speeds_mps",
                    f"the friction test travels up to {profile.max_excursion_m:.3f} m, more than half the "
                    f"position window [{lim.position_min_m:g}, {lim.position_max_m:g}] m (shorter hold_s or lower "
                    "speeds)",
                    cfg.source,
                )
        return excitation, profile

    def _prepare_out(self) -> None:
        """The output folder exists and takes files, or a one-line error before anything moves."""
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            probe = self.out / f".hilident-write-test-{os.getpid()}"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise UsageError(f"--out {self.out}: cannot write there: {exc.strerror or exc}") from None

    def _arm(self, plan: RunPlan) -> None:
        """On a real port, move only with the user's go-ahead: ``confirm(plan)`` shows the plan and asks."""
        if self.dry_run or self.cfg.uses_emulator:
            return
        if self.confirm is None or not self.confirm(plan):
            raise ArmingRefused("the run was not confirmed; nothing moved")

    def _friction_step(self, profile):
        """The friction test (:class:`~hilident.session.friction_test.FrictionTest`): the configured legs, then
        added rounds until the Coulomb and viscous intervals meet ``target_ci_percent`` or a limit stops it."""
        if profile is None:
            return None
        from hilident.session.friction_test import FrictionTest

        test = FrictionTest(
            self.cfg, self.record, self.friction_mode, self._window_rows, self.progress, lambda: self.position_m
        )
        result = test.run(profile)
        self.warnings += result.warnings
        return result

    @staticmethod
    def _window_rows(exp: Experiment, windows) -> list[tuple[int, int, float]]:
        """The recorded rows of each constant-velocity window ``(start, stop, velocity)`` (sample indices).

        A window is a steady state averaged over: the samples a lost frame or a
        skipped cycle took out of it are simply not in the mean (nothing is
        filled in), so a window counts when its rows hold at least
        :data:`_WINDOW_COVER` of its samples.
        """
        index = exp.samples["sample_index"].astype(np.int64)
        kept = []
        for a, b, v in windows:
            first, stop = np.searchsorted(index, [a, b])  # the rows with a <= index < b (the index only grows)
            rows = index[first:stop]
            if stop > first and stop - first >= _WINDOW_COVER * (b - a) and np.all(np.diff(rows) > 0):
                kept.append((int(first), int(stop), v))
        return kept

    # --- automatic excitation amplitude ---------------------------------------------------------

    def _auto_amplitude(self, friction) -> Excitation:
        """Choose the torque amplitude by short trials (``amplitude_nm = "auto"``) and build the run's excitation.

        :class:`~hilident.session.auto_amplitude.AutoAmplitude` plays the trials
        through :meth:`record`; the choice and its reason go to
        ``summary.json["excitation"]["auto"]``.
        """
        chooser = AutoAmplitude(self.cfg, self.record, self._analysis_samples, self.warnings, self.progress)
        self.cfg, self._auto = chooser.choose(friction)
        return build_excitation(self.cfg)

    def _analysis_samples(self, exp: Experiment, excitation: Excitation, gapped: bool = False) -> dict[str, np.ndarray]:
        """Whole gap-free periods of a periodic excitation, else the longest gap-free stretch (never spliced).
        A record selected twice warns of its gaps once.

        ``gapped``: when too few whole periods are gap-free, whole periods that miss a few samples, laid end
        to end with NaN where a sample is missing and ``present`` marking those that exist (for an analysis that
        reads periods around missing samples).
        """
        try:
            selection = pipeline_selection.select_gap_free(
                exp.samples["sample_index"], excitation.period_samples, exp.name
            )
        except DataError as exc:
            if gapped and excitation.period_samples:
                try:
                    periods = pipeline_selection.select_gapped_periods(
                        exp.samples["sample_index"], excitation.period_samples, exp.name
                    )
                except DataError:
                    pass
                else:
                    self.warnings += [w for w in periods.warnings if w not in self.warnings]
                    return {"present": periods.present, **{k: periods.spread(v) for k, v in exp.samples.items()}}
            skipped = self._host_clock_skips(exp.name)
            if not skipped:
                raise
            raise DataError(
                f"{exc}; here the gaps are {skipped} cycles the host's clock skipped (no SYNC, no sample): a drive "
                "that produces SYNC ([canopen.sync] producer = true), SocketCAN, a quieter host or a lower "
                "run.sample_rate_hz keeps them"
            ) from None
        self.warnings += [w for w in selection.warnings if w not in self.warnings]
        return {k: v[selection.keep] for k, v in exp.samples.items()}

    def _host_clock_skips(self, name: str) -> int:
        """Cycles the host's own SYNC clock skipped in the recording ``name`` (0: another clock, or none)."""
        for clock in reversed(self.clocks):
            if clock.get("run") == name and clock.get("source") == "host":
                return int(clock.get("setpoints_skipped", 0))
        return 0

    def _greybox(self):
        """``[model]`` fitted to the identification run, validated on the verification run (or a hold-out)."""
        if self.cfg.model.kind == "none" or "identification" not in self._analysed:
            return None
        s = self._analysed["identification"]
        others = {
            name: (v["torque_nm"], v["position_m"])
            for name, v in self._analysed.items()
            if name != "identification" and "position_m" in v
        }
        if "position_m" not in s:
            self.warnings.append(f"[model] {self.cfg.model.kind}: position_m was not recorded")
            return None
        self.progress.step(f"model: {self.cfg.model.kind} grey-box fit")
        try:
            from hilident.session.offline import model_for_mode

            model = model_for_mode(self.cfg, self.cfg.excitation.mode)  # a held torque command in open loop
            result = pipeline_greybox.fit_greybox(
                model, s["torque_nm"], s["position_m"], self.cfg.run.sample_rate_hz, others or None
            )
        except DataError as exc:
            self.warnings.append(f"[model] {self.cfg.model.kind}: {exc}")
            return None
        self.warnings += result.warnings
        return result

    def _identify(self, exp: Experiment, excitation: Excitation, friction, for_model: bool = True):
        """The plant identified from ``exp`` (``for_model``: its samples also feed the grey-box fit)."""
        cfg = self.cfg
        period = excitation.period_samples
        s = self._analysis_samples(exp, excitation, gapped=True)
        present = s.get("present")
        if exp.name == "identification":
            self._identification = (s, excitation)  # for a loop measured where the injection breaks it
            self._friction = friction
        if for_model and present is None:  # a time-domain model needs every sample
            self._analysed[exp.name] = s
        elif for_model and cfg.model.kind != "none":
            self.warnings.append(
                f"[model] {cfg.model.kind}: not fitted: {exp.name} misses samples, a time-domain model needs every one"
            )
        ic = cfg.identification
        band = pipeline_plant.analysis_band(ic, excitation.band_hz)
        check_it_moved(cfg, s[ic.output] if present is None else s[ic.output][present], friction)
        self.progress.step(f"{exp.name}: frequency response and resonances")
        extra = self._other_outputs(s) if exp.name == "identification" else None
        result = pipeline_plant.identify_plant(
            s["excitation"],
            s["torque_nm"],
            s[ic.output],
            s["velocity_mps"],
            cfg.run.sample_rate_hz,
            ic,
            band,
            friction=friction.fit.params if friction else None,
            velocity_deadband_mps=cfg.friction_test.velocity_deadband_mps,
            friction_slowest_mps=friction.slowest_mps if friction else 0.0,
            period_samples=period,
            excited_bins=excitation.excited_bins,
            present=present,
            extra_outputs=extra,
        )
        self.warnings += result.warnings
        self.notes += result.notes
        if extra:
            ad = self.adapter
            units = dict(zip(ad.channel_names, ad.channel_units, strict=False)) if ad is not None else {}
            self.joint = pipeline_output_modes.joint_output_modes(
                {ic.output: result.plant, **result.outputs},
                band,
                units,
                [{ic.output: plant, **outputs} for plant, outputs in result.output_groups],
            )
        return result

    def _other_outputs(self, s: dict) -> dict:
        """``identification.outputs`` the identification run recorded; each one it did not, a warning."""
        names = self.cfg.identification.outputs
        for name in names:
            if name not in s:
                self.warnings.append(
                    f"identification.outputs: {name} was not recorded (the driver streams no such channel)"
                )
        return {name: s[name] for name in names if name in s}

    def _map_step(self, ident: Experiment, excitation: Excitation, friction, plant) -> None:
        """``[map]`` (:class:`~hilident.session.map_run.WorkspaceRun`): the mode at every mapped position and the
        joint fit, the axis back where the identification ran."""
        self.workspace = WorkspaceRun(
            self.cfg,
            self.record,
            lambda exp, exc: self._identify(exp, exc, friction, for_model=False),
            self._analysis_samples,
            lambda: self.position_m,
            self.progress,
            self.warnings,
            filter_input=self.found_driver.filter_input_channel,
        )
        reference = plant.resonances[0].frequency_hz if plant.resonances else None
        self.workspace.map(float(ident.samples["position_m"][-1]), reference)

    def _move_step(self, designs: list, upload: UploadOutcome) -> list[MoveTestResult]:
        """``[verification] move`` (:func:`hilident.session.move_test.run_move_tests`): from where the run
        identified and from every mapped position; the axis ends where it started. The mode where each move ends
        is the map's there, else the resonances the notches were designed for."""
        start = self.position_m if self.position_m is not None else 0.0
        places = [p.target_m for p in self.workspace.points] if self.workspace else []
        workspace = self.workspace
        notched = {(d.resonance.frequency_hz, d.resonance.damping_ratio) for d in designs}
        resonances = sorted((f, zeta) for f, zeta in notched if np.isfinite(f) and f > 0 and 0 <= zeta < 1)

        def modes_at(position_m: float) -> list[tuple[float, float]]:
            mapped = workspace.mode_at(position_m) if workspace is not None else None
            return [mapped] if mapped is not None else resonances

        self.move_shapers = move_shapers(
            [d.resonance.to_dict() for d in designs], workspace.shaper_table() if workspace is not None else []
        )
        return run_move_tests(
            self.cfg,
            self.record,
            self.progress,
            self.warnings,
            self.found_driver,
            self.adapter,
            designs,
            upload.written and upload.verified_readback,
            start,
            places,
            lambda: self.position_m,
            modes_at,
            self.move_shapers.wanted(self.cfg.verification.move.shapers if self.cfg.verification.move else []),
        )

    def _notch_step(self, plant):
        nc = self.cfg.notch
        upload = UploadOutcome()
        if not nc.enabled:
            return [], upload
        resonances = self._notchable(plant, upload)
        if not resonances:
            return [], upload
        ad = self.adapter
        if ad.identity.filter_slots < 1:
            # designed all the same, for the user to enter by hand or to describe the drive's filter objects
            designs = pipeline_notches.design_notches(resonances, nc, ad.identity.loop_rate_hz, [0], plant.loop)
            upload.not_uploaded = (
                f"driver {self.found_driver.name!r} describes no filter capability (no [filters] "
                "table in its driver.toml): the designed notch was not uploaded"
            )
            self.warnings.append(upload.not_uploaded)
            return designs, upload
        slots = list(range(ad.identity.filter_slots))
        if self.workspace is not None and self.workspace.found:
            designs = self.workspace.notch_designs(ad, resonances, slots, plant)
        else:
            designs = pipeline_notches.design_notches(resonances, nc, ad.identity.loop_rate_hz, slots, plant.loop)
        self.warnings += [d.warning for d in designs if d.warning]
        self.progress.step(f"notch: uploading {len(designs)} filter(s)")
        # written disabled, read back, compared; enabled only as written, else the old contents put back
        uploading.upload_designs(ad, designs, self.warnings, upload)
        self._uploaded = True  # from here the device holds the new notches; other bypassed slots stay bypassed
        return designs, upload

    def _loop_step(self, plant, designs: list, friction=None):
        """The drive's loop around the identified plant, without and with the designed notches, and the
        feed-forward the plant and ``friction`` propose for the terms the drive has; None when the driver does
        not describe the loop. A drive that cannot be read is a warning, not a failed run."""
        ad = self.adapter
        if plant is None:
            return None
        try:
            parameters = ad.read_loop()
        except DeviceError as exc:
            self.warnings.append(f"loop: the drive's loop parameters could not be read: {exc}")
            return None
        if parameters is None:
            return None
        sampling = "mean" if "torque_nm" in self.found_driver.averaged_channels else "instant"
        try:
            analysis = pipeline_loop.analyse_loop(
                plant,
                parameters,
                ad.identity.loop_rate_hz,
                self.cfg.run.sample_rate_hz,
                [d.biquad for d in designs],
                sampling,
                self.cfg.identification.output,
                pipeline_loop.tuning_targets(self.cfg.tuning),
            )
        except (ConfigError, DataError, ValueError) as exc:
            self.warnings.append(f"loop: no margins: {exc}")
            return None
        self.notes += analysis.notes
        if analysis.tuning is not None:
            from hilident.pipeline.feedforward import propose_feedforward

            fit = friction.fit if friction is not None else None
            skips = sum(int(c.get("setpoints_skipped", 0)) for c in self.clocks if c.get("source") == "host")
            analysis.tuning["feedforward"] = propose_feedforward(parameters, analysis.seen, fit, skips)
        analysis.measured = self._measured_loop(analysis)
        if analysis.seen is not None:  # for hilident upload --gains: the plant the gains are checked on
            from hilident.pipeline.loop_plant import PLANT_FILE, save_seen_plant

            save_seen_plant(self.out / PLANT_FILE, analysis.seen)
        return analysis

    def _measured_loop(self, analysis) -> dict | None:
        """The loop measured where a torque injection breaks it (identification in ``torque_injection`` with the
        torque command recorded); None otherwise."""
        from hilident.pipeline.measured_loop import measured_loop_part

        if self._identification is None or self.cfg.excitation.mode != "torque_injection":
            return None
        s, excitation = self._identification
        if "torque_cmd_nm" not in s:
            return None
        if analysis.seen is None or analysis.cascade is None:
            return None
        rate, ic = self.cfg.run.sample_rate_hz, self.cfg.identification
        frf, warnings = pipeline_responses.periods_response(s, s["torque_cmd_nm"], excitation, rate, ic)
        self.warnings += warnings
        friction = None
        if self._friction is not None:  # its part of the command out, as from the plant's torque
            torque = self._friction.fit.predict(np.nan_to_num(s["velocity_mps"]))
            friction, _ = pipeline_responses.periods_response(s, torque, excitation, rate, ic)
        return measured_loop_part(
            frf,
            analysis.cascade,
            analysis.seen,
            self.cfg.run.sample_rate_hz,
            self.cfg.identification.coherence_threshold,
            friction,
        )

    def _gain_step(self, upload: UploadOutcome, friction) -> None:
        """The proposed gains into the drive, proven by a closed-loop run or put back
        (:class:`hilident.session.gain_step.GainStep`); the outcome goes to ``summary.json["loop"]["upload"]``."""
        from hilident.session.gain_step import GainStep, uploaded_notches

        assert self.loop is not None
        if self.loop.seen is None or self.loop.tuning is None:
            return
        self.gains = GainStep(
            self.adapter,
            self.cfg,
            self.loop,
            uploaded_notches(upload),
            friction,
            self.record,
            lambda exp, excitation: self._analysis_samples(exp, excitation, gapped=True),
            self.warnings,
            self.progress,
        )
        self.loop.upload = self.gains.part
        self.gains.run()

    def _notchable(self, plant, upload: UploadOutcome) -> list:
        """The resonances the evidence supports a notch for; why the others get none goes to warnings and upload."""
        e = self.cfg.excitation
        amplitude = e.amplitude if isinstance(e.amplitude, (int, float)) else None
        decision = pipeline_notches.notch_decision(
            plant, self.cfg.identification.coherence_threshold, e.amplitude_key, amplitude
        )
        self.warnings += decision.warnings
        if decision.skipped_reason is not None:
            upload.skipped_reason = decision.skipped_reason
        resonances, notes = pipeline_output_modes.notch_resonances(decision.resonances, self.joint)
        self.notes += notes
        return resonances

    def _save_step(self, upload: UploadOutcome, verification) -> None:
        """With ``save``: the device stores its parameters, only after an upload read back and verified."""
        upload.saved = False
        if not self.save:
            return
        if not (upload.written and upload.verified_readback and verification is not None):
            upload.not_saved = "nothing was saved: the notches were not uploaded, read back and verified"
            self.warnings.append(upload.not_saved)
            return
        saved_with, reason = uploading.store_parameters(self.adapter, self.found_driver.transport, self.progress)
        if saved_with is None:
            upload.not_saved = reason
            self.warnings.append(upload.not_saved)
            return
        upload.saved_with = saved_with
        upload.saved = True

    def _verify(self, excitation: Excitation, plant, designs):
        if not designs or not self.cfg.notch.verify or not self._uploaded:
            return None
        exp = self.record(
            "verification",
            self.cfg.excitation.mode,
            excitation.samples,
            period_samples=excitation.period_samples,
            recipe=excitation_recipe(self.cfg),
        )
        s = self._analysis_samples(exp, excitation, gapped=True)
        if "present" not in s:  # a time-domain model needs every sample
            self._analysed["verification"] = s
        self.progress.step("verification: frequency response")
        loop_after, warnings = pipeline_responses.periods_response(
            s, s[self.cfg.identification.output], excitation, self.cfg.run.sample_rate_hz, self.cfg.identification
        )
        self.warnings += warnings
        nc = self.cfg.notch
        # one row per resonance: the staggered notches of a covering design share theirs
        resonances = list(
            {(d.resonance.frequency_hz, d.resonance.damping_ratio): d.resonance for d in designs}.values()
        )
        reductions = pipeline_verification.peak_reductions(
            plant.loop, loop_after, resonances, nc.verify_band_bandwidths
        )
        for row, resonance in zip(reductions, resonances, strict=True):
            floor = pipeline_verification.band_floor_db(plant.loop, loop_after, resonance, nc.verify_band_bandwidths)
            row["floor_db"] = floor
            row["floor_limited"] = pipeline_verification.floor_limited(row["band_reduction_db"], floor)
        band = min(reductions, key=lambda r: r["band_reduction_db"])
        at_peak = min(r["reduction_db"] for r in reductions)
        short = pipeline_verification.shortfall_warning(band, nc.verify_band_bandwidths, nc.min_reduction_db)
        if short:
            self.warnings.append(short)
        return VerificationPart(band["band_reduction_db"], at_peak, nc.verify_band_bandwidths, reductions, loop_after)

    # --- outputs ----------------------------------------------------------------------------

    def _write_partial_summary(
        self, step: str, exc: BaseException, friction, plant, designs, upload, verification, elapsed_s: float
    ) -> None:
        """``summary.json`` of a session a step of which failed after others succeeded: their results, the
        failed step's name (``failed_step``) and its error."""
        summary = self._summary(friction, plant, designs, upload, verification, elapsed_s).failed(step, str(exc))
        write_json(self.out / "summary.json", summary.to_dict())
        html_report.write_report_quietly(self.out)
        self.progress.step(f"wrote {self.out / 'summary.json'} up to the failed step ({step})")

    def _summary(
        self,
        friction,
        plant,
        designs,
        upload: UploadOutcome,
        verification: VerificationPart | None,
        elapsed_s: float,
        model=NOT_REACHED,
    ) -> Summary:
        """The run's :class:`~hilident.io.summary.Summary` (``model`` left out when the run failed before it)."""
        cfg, ad = self.cfg, self.adapter
        connect = ad.connect_report.to_dict() if ad is not None and hasattr(ad, "connect_report") else None
        return Summary.of_run(
            config=cfg.source,
            device=DevicePart(self.found_driver.name, ad.port if ad else None, cfg.uses_emulator),
            sample_rate_hz=cfg.run.sample_rate_hz,
            excitation=ExcitationPart.of(cfg.excitation, self._auto),
            plant=plant,
            friction=friction,
            designs=designs,
            upload=upload,
            verification=verification,
            stream=self.totals,
            clock=self.clocks,
            connect=connect,
            filters_found=self.filters_found,
            recordings=sorted(p.name for p in self.out.glob("*.h5")),
            elapsed_s=elapsed_s,
            warnings=self.warnings,
            notes=self.notes + (self.recorder.notes if self.recorder is not None else []),
            model=model,
            workspace_map=self.workspace.points if self.workspace else None,
            move_test=self.move_results,
            workspace=self.workspace.summary if self.workspace else None,
            loop=self.loop.to_dict() if self.loop is not None else None,
            mimo=self.joint.part if self.joint is not None else None,
            shaper_over_travel=self._shaper_over_travel(),
        )

    def _shaper_over_travel(self) -> dict | None:
        """The fixed and the scheduled shaper along the mapped travel: the move test's, else designed from the
        map (None without one)."""
        shapers = self.move_shapers
        if shapers is None and self.workspace is not None and self.workspace.found:
            shapers = move_shapers([], self.workspace.shaper_table())
        return shapers.over_travel() if shapers is not None else None

    def _plots(self, friction, plant, designs, verification, excitation_band_hz, model=None) -> None:
        report.plot_run(
            self.out,
            friction,
            plant,
            designs,
            verification.loop_after if verification else None,
            self.cfg.identification.coherence_threshold,
            summary=self.summary,
            band_hz=pipeline_plant.analysis_band(self.cfg.identification, excitation_band_hz),
            output=self.cfg.identification.output,
        )
        joint = self.joint
        if joint is not None and joint.response is not None and joint.part.get("stabilisation"):
            from hilident.plots.stabilisation import STABILISATION_PNG, plot_stabilisation

            plot_stabilisation(
                self.out / STABILISATION_PNG,
                joint.part,
                joint.response.frequency_hz,
                joint.response.response,
                title=plot_title(Path(self.cfg.source).name, what="Stabilisation"),
            )
        if self.gains is not None and self.gains.check is not None:  # closed-loop.png: the gains' proof
            from hilident.plots.closed_loop import plot_closed_loop

            plot_closed_loop(
                self.out / "closed-loop.png",
                self.gains.check,
                self.gains.step,
                plot_title(Path(self.cfg.source).name, what="Closed loop after the gain upload"),
            )
        if model is not None:  # model.png: the fit of _greybox on the records it used
            from hilident.session.offline import model_for_mode

            s = self._analysed
            others = {
                name: (v["torque_nm"], v["position_m"])
                for name, v in s.items()
                if name != "identification" and "position_m" in v
            }
            records = report.greybox_records(
                self.cfg.model.holdout, (s["identification"]["torque_nm"], s["identification"]["position_m"]), others
            )
            report.plot_model(
                self.out / "model.png",
                model_for_mode(self.cfg, self.cfg.excitation.mode),
                model,
                records,
                self.cfg.run.sample_rate_hz,
                plot_title(Path(self.cfg.source).name),
            )
