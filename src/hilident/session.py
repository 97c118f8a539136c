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
"""

from __future__ import annotations

import dataclasses
import os
import platform
import sys
import time
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from hilident import __version__, endings, report
from hilident.serialise import write_json
from hilident.summary import (NOT_REACHED, DevicePart, ExcitationPart, StreamStatistics, Summary,
                              UploadOutcome, VerificationPart)
from hilident.adapters.base import StreamStats, adapter_class
from hilident.config import (AUTO_BAND_SHARE, AUTO_START_SHARE, Config, amplitude_ceiling_nm,
                              auto_coherence_target, check_auto_amplitude)
from hilident.devicelock import DeviceLock, device_key
from hilident.drivers import DriverDescription, check_run_against_driver, find_driver
from hilident.events import RunEvent
from hilident.errors import ArmingRefused, ConfigError, DataError, HilidentError, UsageError
from hilident.plan import RunPlan, excitation_travel_m, make_plan
from hilident.recording import RunWriter, read_run
from hilident.lazy import lazy_module
from hilident.signals import generators as sig
from hilident.signals.excitation import Excitation
from hilident.signals.excitation import build_excitation as excitation_signal

if TYPE_CHECKING:
    from hilident.adapters.base import AdapterBase

#: The analysis, imported once an experiment needs it (a run ended before that starts and stops faster).
pipeline = lazy_module("hilident.pipeline")
#: The upload step, shared with ``hilident upload``.
uploading = lazy_module("hilident.upload")

#: Longest stretch of data (and wall-clock time) held in memory before it is written to the recording, s.
FLUSH_INTERVAL_S = 0.5


def package_versions() -> dict[str, str]:
    """Versions of hilident and the libraries that shape its numbers."""
    out = {"hilident": __version__, "python": platform.python_version()}
    for name in ("numpy", "scipy", "h5py", "pyserial", "cobs", "matplotlib", "python-can", "canopen", "pymodbus"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    return out


class Progress:
    """Progress of long steps on stderr: one updating line on a terminal, a few lines otherwise."""

    def __init__(self, stream=None, enabled: bool = True):
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._last = -1

    def step(self, message: str) -> None:
        if self.enabled:
            self._print(message)

    def _print(self, text: str, end: str = "\n") -> None:
        """Print, or fall silent when nobody reads any more (a closed pipe or terminal must not stop a run)."""
        try:
            print(text, end=end, file=self.stream, flush=True)
        except (OSError, ValueError):
            self.enabled = False

    def fraction(self, label: str) -> Callable[[float], None]:
        self._last = -1

        def update(x: float) -> None:
            pct = int(100 * x)
            every = 1 if self.tty else 25
            if not self.enabled or pct // every == self._last // every:
                return
            self._last = pct
            if self.tty:
                end = "\n" if pct >= 100 else ""
                self._print(f"\r  {label}: {pct:3d} %", end=end)
            else:
                self._print(f"  {label}: {pct:3d} %")

        return update


def build_excitation(cfg: Config, amplitude: float | None = None) -> Excitation:
    """The identification excitation of ``cfg`` (:func:`hilident.signals.excitation.build_excitation`).

    Torque (N·m) for ``torque`` and ``torque_injection``; a velocity (m/s) or
    position (m, relative to where the axis holds) set-point perturbation for
    ``velocity`` and ``position``. ``amplitude`` overrides the configured one;
    ``amplitude_nm = "auto"`` builds it at the ceiling auto may choose (what
    the plan shows and the limits are checked against).
    """
    e = cfg.excitation
    if amplitude is None:
        amplitude = (amplitude_ceiling_nm(cfg) or 1.0) if e.amplitude_auto else e.amplitude
    return excitation_signal(e, cfg.run.sample_rate_hz, amplitude, seed=cfg.run.seed)


#: Share of a host-clocked run's samples whose SYNC may be late before the session warns of uneven sampling.
LATE_SYNC_SHARE = 0.01


def late_sampling_warnings(name: str, events: list[dict], samples: int) -> list[str]:
    """A warning when the host sent many SYNCs late: the drive then sampled at uneven instants.

    A drive samples when the SYNC arrives while its own loop runs on, so a
    late SYNC shifts that sample in time; a few are harmless, many distort the
    frequency response (its phase above all) without losing a sample.
    """
    out = []
    for ev in events:
        if ev.get("kind") != "sync_late" or not samples:
            continue
        late = int(ev.get("value", 0))
        if late > LATE_SYNC_SHARE * samples:
            worst = ev.get("worst_s")
            out.append(f"{name}: {late} of {samples} SYNCs ({100 * late / samples:.1f} %) were sent more than one "
                       "period late" + (f" (worst {1e3 * worst:.1f} ms)" if worst is not None else "")
                       + ": the drive sampled at uneven instants and the frequency response is distorted; run on a "
                         "machine with less load, or at a lower run.sample_rate_hz")
    return out


def excitation_recipe(cfg: Config, amplitude: float | None = None, duration_s: float | None = None) -> dict:
    """``[excitation]`` as parameters, for a drive whose own generator plays it (``device.acquisition = "recorder"``).

    ``amplitude`` and ``duration_s`` override the configured ones (the trials of an automatic amplitude).
    """
    e = cfg.excitation
    return {"kind": e.kind, "mode": e.mode, "amplitude": e.amplitude if amplitude is None else amplitude,
            "amplitude_key": f"excitation.{e.amplitude_key}", "f_min_hz": e.f_min_hz,
            "f_max_hz": e.f_max_hz, "frequency_hz": e.frequency_hz,
            "duration_s": e.duration_s if duration_s is None else duration_s,
            "period_s": e.period_s, "register_length": e.register_length, "clock_divider": e.clock_divider,
            "chirp_method": e.chirp_method, "sample_rate_hz": cfg.run.sample_rate_hz}


# --- automatic excitation amplitude: the numbers (pure) ----------------------------------------

#: Share of the speed limit and of the room to the position window a trial's prediction may use.
AUTO_LIMIT_MARGIN = 0.8
#: Share of the torque limit the predicted peak measured torque may reach (the loop adds to the excitation).
AUTO_TORQUE_MARGIN = 0.95
#: Below this share of the Stribeck velocity the axis counts as sticking.
AUTO_STUCK_SHARE = 0.1
#: Factor to the next trial when a trial's response does not rise above the noise (nothing to scale from).
AUTO_NO_RESPONSE_STEP = 4.0
#: Without a friction test, the factor from a first trial to the second (the response change between two
#: amplitudes is what bounds the distortion then).
AUTO_LINEARITY_STEP = 2.0
#: Smallest factor between two trials (a smaller step tells nothing new).
AUTO_MIN_STEP = 1.1
#: Neighbouring excited lines a noise estimate is averaged over (a single period's line has two degrees of freedom).
AUTO_NOISE_LINES = 5


def period_spectra(x: np.ndarray, period_samples: int, lines: np.ndarray) -> np.ndarray:
    """DFT of each whole period of ``x`` at the DFT bins ``lines``, shape (periods, lines)."""
    n = len(x) // period_samples
    return np.fft.rfft(np.asarray(x[: n * period_samples], dtype=float).reshape(n, period_samples), axis=1)[:, lines]


def smooth_lines(power: np.ndarray) -> np.ndarray:
    """A per-line noise power averaged over :data:`AUTO_NOISE_LINES` neighbouring lines."""
    from scipy.ndimage import uniform_filter1d

    return uniform_filter1d(np.asarray(power, dtype=float), AUTO_NOISE_LINES, mode="nearest")


def predicted_coherence(signal: dict, noise: dict, factor: float, periods: int) -> np.ndarray:
    """Coherence per line of a periodic run of ``periods`` periods at ``factor`` times the trial's amplitude.

    Each channel's coherence over periods is ``(S r^2 + N / M) / (S r^2 + N)``
    (``|mean|^2 / (|mean|^2 + variance)`` with the mean's own noise ``N / M``),
    the signal power ``S`` growing with the amplitude squared and the noise
    power per period ``N`` staying as measured; the input's and the output's
    multiply.
    """
    out = 1.0
    for key in signal:
        s, n = signal[key] * factor**2, noise[key]
        out = out * (s + n / periods) / np.maximum(s + n, 1e-300)
    return np.clip(out, 0.0, 1.0)


def band_coherence(coherence: np.ndarray) -> float:
    """The coherence :data:`AUTO_BAND_SHARE` of the band's lines reach or exceed."""
    return float(np.quantile(coherence, 1.0 - AUTO_BAND_SHARE))


def coherence_factor(signal: dict, noise: dict, periods: int, target: float) -> float:
    """Smallest factor on the trial's amplitude whose predicted band coherence reaches ``target`` (inf: none)."""
    from scipy.optimize import brentq

    def gap(log_r: float) -> float:
        return band_coherence(predicted_coherence(signal, noise, float(np.exp(log_r)), periods)) - target

    lo, hi = np.log(1e-3), np.log(1e4)
    if gap(hi) < 0:
        return float("inf")
    if gap(lo) >= 0:
        return 1e-3
    return float(np.exp(brentq(gap, lo, hi, xtol=1e-4)))


def response_change(low: dict, high: dict) -> float:
    """Nonlinear distortion at the higher of two trials' amplitudes, from how much the response changed.

    For a linear plant the responses ``G = mean Y / mean U`` of two trials
    agree within their noise. Friction-like distortion ``D`` falls as
    ``1 / A``: with ``G(A) = G0 (1 + D0 / A)`` the relative change
    ``x = |G_low - G_high| / |G_high|`` is ``D (r - 1) / (1 + D)`` for the
    share ``D`` left at ``A_high`` and ``r = A_high / A_low``, so
    ``D = x / (r - 1 - x)``. ``x`` is the median over the lines, their noise
    (``var G / |G|^2`` of both) taken out. ``low`` and ``high``:
    ``{amplitude_nm, frf, relative_variance}``; inf when the change is too large to say.
    """
    change = np.abs(high["frf"] - low["frf"]) ** 2 / np.maximum(np.abs(high["frf"]) ** 2, 1e-300)
    x = float(np.sqrt(max(np.median(change - low["relative_variance"] - high["relative_variance"]), 0.0)))
    room = high["amplitude_nm"] / low["amplitude_nm"] - 1.0 - x
    return x / room if room > 0 else float("inf")


def friction_share(velocity: np.ndarray, excitation: np.ndarray, friction, stuck_mps: float) -> float:
    """Rms of the fitted friction's nonlinear part (Coulomb and Stribeck) over the rms excitation.

    Stick-slip repeats every period, so coherence does not see the distortion
    it brings; its share falls as the excitation grows (the viscous part is
    linear and left out). While the axis sticks (``|v| <= stuck_mps``)
    friction holds whatever torque is applied, up to ``Fs``.
    """
    from hilident.ident.friction import stribeck

    velocity, excitation = np.asarray(velocity, dtype=float), np.asarray(excitation, dtype=float)
    nonlinear = stribeck(velocity, dataclasses.replace(friction, Fv=0.0))
    stuck = np.abs(velocity) <= stuck_mps
    nonlinear[stuck] = np.clip(excitation[stuck], -friction.Fs, friction.Fs)
    rms_x = float(np.sqrt(np.mean(np.square(excitation))))
    return float(np.sqrt(np.mean(np.square(nonlinear)))) / rms_x if rms_x > 0 else float("inf")


@dataclass
class Experiment:
    """Samples of one recorded experiment (read back from its file)."""

    name: str
    path: Path
    samples: dict[str, np.ndarray]
    stats: StreamStats
    events: list[dict] = field(default_factory=list)


@dataclass(frozen=True)
class ConnectedDevice:
    """An open device, complete: its driver, the adapter talking to it, and what was started or taken to reach
    it (the embedded emulator, the device lock). Made by :func:`connect_device`."""

    driver: DriverDescription
    adapter: "AdapterBase"
    emulator: object | None = None
    lock: DeviceLock | None = None

    def safe_stop(self) -> None:
        """Command the axis safe now (first thing on every ending). Never raises."""
        try:
            self.adapter.safe_stop()
        except Exception:
            pass

    def close(self) -> None:
        """Stop the axis and release the device (and the emulator, and the device lock)."""
        try:
            self.adapter.close()
        finally:
            try:
                if self.emulator is not None:
                    self.emulator.close()
            finally:
                if self.lock is not None:
                    self.lock.release()


def connect_device(cfg: Config, driver: DriverDescription, progress: Progress) -> ConnectedDevice:
    """Open the device of ``[device]`` (taking its lock), or start the embedded emulator and open it like one.

    The adapter brings the device to a known state as it opens (stale frames
    discarded, axis stopped, latched faults reported and cleared only when
    allowed). The lock and the emulator are released again when opening fails.
    """
    cls = adapter_class(driver.transport)
    device, link, emulator, lock = cfg.device, None, None, None
    if cfg.uses_emulator:
        from hilident.emulator.factory import start_emulator

        emulator = start_emulator(cfg.emulator, driver, cfg.device)
        device, link = emulator.device, emulator.link
    else:
        d = cfg.device
        lock = DeviceLock(device_key(driver.transport, d.port, node_id=d.node_id, device_id=d.device_id,
                                     can_interface=d.can_interface)).acquire()
        if lock.recovered_from:
            progress.step(f"device lock of pid {lock.recovered_from} recovered (that session died)")
    try:
        adapter = cls.open_device(device, driver, link=link)
    except BaseException:
        with endings.shielded():
            _release(emulator, lock)
        raise
    return ConnectedDevice(driver, adapter, emulator, lock)


def _release(emulator, lock: DeviceLock | None) -> None:
    """Stop an emulator and release a lock of a device that did not open."""
    try:
        if emulator is not None:
            emulator.close()
    finally:
        if lock is not None:
            lock.release()


def connect_warnings(report_) -> list[str]:
    """What :attr:`AdapterBase.connect_report` found, as the session's warnings."""
    out = []
    if report_.discarded_frames:
        out.append(f"connect: {report_.discarded_frames} frame(s) left over from an earlier session were discarded")
    if report_.faults:
        out.append(f"connect: the device had latched fault(s): {'; '.join(report_.faults)}"
                   + ("; cleared (allow_fault_reset)" if report_.faults_cleared else ""))
    return out + [f"connect: {w}" for w in report_.warnings]


class DeviceConnection:
    """A device opened as ``[device]`` says (or the embedded emulator), one session per device.

    What ``hilident run`` and ``hilident upload`` share: the subclass sets
    ``cfg``, ``progress`` and ``warnings`` and may set ``driver``;
    :meth:`open_device` makes :attr:`device` (a :class:`ConnectedDevice`);
    ``adapter``, ``emulator`` and ``lock`` are its parts (None until then).
    """

    cfg: Config
    progress: Progress
    warnings: list[str]
    driver: DriverDescription | None = None
    device: ConnectedDevice | None = None

    @property
    def adapter(self):
        """The open device's adapter (None before :meth:`open_device`)."""
        return self.device.adapter if self.device is not None else None

    @property
    def emulator(self):
        """The embedded emulator (None on a real port, or before :meth:`open_device`)."""
        return self.device.emulator if self.device is not None else None

    @property
    def lock(self) -> DeviceLock | None:
        """The device lock (None for the emulator, or before :meth:`open_device`)."""
        return self.device.lock if self.device is not None else None

    def open_device(self) -> None:
        """Open the device (taking its lock), or start the embedded emulator and open it like a device.

        What the adapter found as it brought the device to a known state goes to ``warnings``.
        """
        self.driver = self.driver or find_driver(self.cfg.device.driver, self.cfg.device.driver_paths)
        self.device = connect_device(self.cfg, self.driver, self.progress)
        where = "emulated" if self.cfg.uses_emulator else "connected to"
        self.progress.step(f"{where} {self.adapter.identity.name} on {self.adapter.port}")
        report_ = getattr(self.adapter, "connect_report", None)
        if report_ is not None:
            self.warnings += connect_warnings(report_)

    def safe_stop(self) -> None:
        """Command the axis safe now (first thing on every ending). Never raises."""
        if self.device is not None:
            self.device.safe_stop()

    def close(self) -> None:
        """Stop the axis and release the device (and the emulator, and the device lock)."""
        if self.device is not None:
            self.device.close()


class Session(DeviceConnection):
    """A whole bench run as described by one configuration.

    Parameters
    ----------
    cfg : Config
    out_dir : path
        Where recordings, plots and ``summary.json`` go.
    progress : Progress, optional
    """

    def __init__(self, cfg: Config, out_dir: str | Path, progress: Progress | None = None,
                 confirm: Callable[[RunPlan], bool] | None = None, dry_run: bool = False, plots: bool = True,
                 save: bool = False):
        if cfg.limits is None:
            raise ConfigError(
                "limits", "is required for a bench run: torque_nm, velocity_mps, position_min_m, position_max_m",
                cfg.source,
            )
        self.cfg = cfg
        self.out = Path(out_dir)
        self.progress = progress or Progress(enabled=False)
        self.driver: DriverDescription | None = None
        self.device: ConnectedDevice | None = None
        self.totals = StreamStats()
        self.warnings: list[str] = []
        self.summary: dict = {}
        self._analysed: dict[str, dict[str, np.ndarray]] = {}  # gap-free samples of each analysed run
        self.confirm = confirm
        self.dry_run = dry_run
        self.plots = plots
        self.save = save  # store the device's parameters once the new notches are verified
        self.plan: RunPlan | None = None
        self.filters_found: list[dict] = []  # what the filter slots held when the session began
        self._bypassed: dict[int, object] = {}  # slot -> saved contents, until the new notches are uploaded
        self.friction_mode = "velocity"  # or "position" on a drive without a velocity mode (set by prepare)
        self._uploaded = False
        self._auto: dict | None = None  # the automatic amplitude's choice, trials and reason

    # --- connection -----------------------------------------------------------------------

    def connect(self) -> None:
        """Open the device (one session per device), or start the embedded emulator and open it like a device.

        The adapter brings the device to a known state as it opens (stale
        frames discarded, axis stopped, latched faults reported and cleared
        only when allowed); the limits the device enforces are loaded.
        """
        self.open_device()
        lim = self.cfg.limits
        self.adapter.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)

    # --- filter slots: identify the bare plant ---------------------------------------------

    def _read_filter_slots(self) -> None:
        """What every filter slot holds before the session changes anything (for the plan and summary.json)."""
        ad = self.adapter
        self.filters_found = []
        for slot in range(ad.identity.filter_slots):
            biquad, enabled = ad.read_filter(slot)
            self.filters_found.append({"slot": slot, "enabled": bool(enabled), "b": [float(x) for x in biquad.b],
                                       "a": [float(x) for x in biquad.a]})

    def _bypass_filters(self) -> None:
        """Bypass every slot that filters now, so identification measures the bare plant."""
        ad = self.adapter
        for found in self.filters_found:
            if found["enabled"]:
                slot = found["slot"]
                saved = ad.save_filter(slot)
                ad.disable_filter(slot)
                self._bypassed[slot] = saved
                found["bypassed"] = True
        if self._bypassed:
            self.progress.step(f"filter slot(s) {sorted(self._bypassed)} bypassed while the plant is measured")

    def _restore_filters(self) -> None:
        """Put back what the slots held, when the session ends without an upload (early, or with nothing to
        notch). Never raises."""
        if self._uploaded or not self._bypassed or self.adapter is None:
            return
        for slot, saved in sorted(self._bypassed.items()):
            try:
                self.adapter.restore_filter(slot, saved)
                for found in self.filters_found:
                    if found["slot"] == slot:
                        found["restored"] = True
            except Exception as exc:
                self.warnings.append(f"filter slot {slot}: could not restore its previous contents: {exc}")
        self._bypassed.clear()

    # --- experiments ----------------------------------------------------------------------

    def record(self, name: str, mode: str, excitation: np.ndarray, tables: dict | None = None,
               period_samples: int | None = None, recipe: dict | None = None) -> Experiment:
        """Stream ``excitation`` in ``mode`` and record every sample to ``<out>/<name>.h5``.

        ``period_samples`` (a periodic excitation's period) is stored with the
        recording, so ``hilident identify`` analyses it in whole periods too.
        ``recipe`` is the excitation as parameters, for a drive whose own
        generator plays it (:func:`excitation_recipe`); None for host-made
        set-points such as the friction test's ramps.
        """
        cfg = self.cfg
        ad = self.adapter
        channels = ad.configure(cfg.run.sample_rate_hz, mode, cfg.run.channels or None)
        fs = ad.sample_rate_hz
        path = self.out / f"{name}.h5"
        attrs = {
            "experiment": name, "mode": mode, "seed": cfg.run.seed, "config_toml": cfg.text,
            "config_source": cfg.source, "driver_toml": self.driver.text, "versions": package_versions(),
            "device": {"name": ad.identity.name, "firmware": ad.identity.firmware, "port": ad.port},
        }
        if period_samples:
            attrs["period_samples"] = int(period_samples)
        writer = RunWriter(path, ["sample_index", "time_s", *channels], ["1", "s", *ad.channel_units], fs, attrs,
                           overwrite=True)
        for table, columns in (tables or {}).items():
            writer.write_table(table, **columns)

        # Blocks are gathered for at most FLUSH_INTERVAL_S of data or of wall-clock time (one HDF5 flush per
        # block would stall the line), then written with the events known so far: a crash loses no more.
        pending: list[np.ndarray] = []
        held = {"rows": 0, "since": time.monotonic(), "events": 0}
        flush_rows = max(1, int(FLUSH_INTERVAL_S * fs))

        def write_events(events: list[dict]) -> None:
            for ev in events[held["events"]:]:
                writer.log(RunEvent.from_dict(ev))
            held["events"] = max(held["events"], len(events))

        def flush() -> None:
            if pending:
                block = np.concatenate(pending)
                pending.clear()
                held["rows"] = 0
                writer.append(block)
            write_events(getattr(ad, "events", []))
            held["since"] = time.monotonic()

        def sink(index: np.ndarray, rows: np.ndarray) -> None:
            pending.append(np.column_stack([index, index / fs, rows]))
            held["rows"] += len(rows)
            if held["rows"] >= flush_rows or time.monotonic() - held["since"] >= FLUSH_INTERVAL_S:
                flush()

        if cfg.device.trace:
            ad.set_trace(self.out / f"{name}.{cfg.device.trace}")  # CAN trace beside the recording
        self.progress.step(f"{name}: {len(excitation) / fs:.1f} s of {mode} excitation")
        result = None
        status, reason = "aborted", ""
        ad.last_result = None
        try:
            ad.set_excitation_recipe(recipe)  # for a drive whose own generator plays the excitation
            result = ad.stream(excitation, sink, self.progress.fraction(name))
            status = "complete"
        except BaseException as exc:
            with endings.shielded():
                self.safe_stop()  # the device first, whatever ended the run
            reason = str(exc) or type(exc).__name__
            raise
        finally:
            with endings.shielded():
                self._close_recording(writer, status, reason, flush, write_events, ad)
        endings.raise_pending()
        run = read_run(path)
        stats = result.stats
        if stats.lost_blocks or stats.corrupt_frames or stats.underruns or stats.out_of_order:
            self.warnings.append(
                f"{name}: {stats.lost_blocks} sample blocks ({stats.lost_samples} samples) lost, "
                f"{stats.out_of_order} blocks out of order (discarded), "
                f"{stats.corrupt_frames} corrupt frames, {stats.underruns} underrun samples"
            )
        if stats.clipped_blocks:
            self.warnings.append(f"{name}: {stats.clipped_blocks} samples hold a value at the limit of its format "
                                 "(saturated, not measured; see the recording's events): the response there is not "
                                 "the plant's")
        self.warnings += late_sampling_warnings(name, result.events, stats.samples)
        return Experiment(name, path, run.samples, stats, result.events)

    def _close_recording(self, writer: RunWriter, status: str, reason: str, flush, write_events, ad) -> None:
        """Write what is still held, the events and the stream counters, and close the file with its status.

        Runs on every ending; a write that fails here (the disk that ended the
        run is still full) leaves the file closed as ``aborted`` and never hides
        the error that ended the run.
        """
        result = ad.last_result
        failure = None
        try:
            flush()
            if result is not None:
                write_events(result.events)
                writer.set_attrs(stream=result.stats.__dict__)
        except HilidentError as exc:
            failure = exc
            reason = reason or str(exc)
        finally:
            if result is not None:
                self.totals = self.totals.add(result.stats)
            writer.close("aborted" if failure else status, reason)
        if failure is not None and status == "complete":
            raise failure  # the run itself went well: the write is what failed

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
            self.plan = make_plan(self.cfg, excitation, profile, self.adapter, self.filters_found,
                                  self.friction_mode)
            self._arm()
            if self.dry_run:
                return {"dry_run": True, "plan": self.plan.to_dict()}
            self._bypass_filters()
            step = "friction test"
            friction = self._friction_step(profile)
            if self.cfg.excitation.amplitude_auto:
                step = "auto amplitude"
                excitation = self._auto_amplitude(friction)  # the run then plays the chosen amplitude
            step = "identification"
            ident = self.record("identification", self.cfg.excitation.mode, excitation.samples,
                                period_samples=excitation.period_samples, recipe=excitation_recipe(self.cfg))
            plant = self._identify(ident, excitation, friction)
            step = "notch upload"
            designs, upload = self._notch_step(plant)
            step = "verification"
            verification = self._verify(excitation, plant, designs)
            step = "save"
            self._save_step(upload, verification)
        except BaseException as exc:
            with endings.shielded():
                self.safe_stop()
            if isinstance(exc, HilidentError) and (friction is not None or plant is not None):
                with endings.shielded():  # what the steps before found is kept, and the step that failed named
                    self._write_partial_summary(step, exc, friction, plant, designs, upload, verification,
                                                time.monotonic() - started)
            raise
        finally:
            with endings.shielded():
                self._restore_filters()  # nothing to do once the new notches are uploaded
                self.close()
        endings.raise_pending()
        model = self._greybox()
        self.result = self._summary(friction, plant, designs, upload, verification, time.monotonic() - started,
                                    model=model)
        self.summary = self.result.to_dict()
        write_json(self.out / "summary.json", self.summary)
        if self.plots:
            self._plots(friction, plant, designs, verification)
        return self.summary

    def prepare(self):
        """Everything that can be checked without the device, before it is opened.

        The output folder must be writable; the driver is found; the
        excitation and the friction test's profile are built (their sizes were
        bounded when the config was loaded); the friction test's travel must
        fit the position window. Returns ``(excitation, friction_profile)``.
        """
        self._prepare_out()
        cfg = self.cfg
        self.driver = find_driver(cfg.device.driver, cfg.device.driver_paths)
        refusal = getattr(adapter_class(self.driver.transport), "run_refusal", None)  # a drive that cannot play
        if refusal is not None and (error := refusal(self.driver)) is not None:
            raise ConfigError(error.key, error.message, cfg.source)
        modes = check_run_against_driver(cfg, self.driver)
        check_auto_amplitude(cfg)  # again: a config changed in code after loading
        excitation = build_excitation(cfg)
        self._check_excitation_travel(excitation)
        # a drive without a velocity mode runs the friction test's legs as a position profile
        self.friction_mode = "velocity" if "velocity" in modes else "position"
        profile = None
        ft = cfg.friction_test
        if ft.enabled:
            profile = sig.velocity_ramps(ft.speeds_mps, ft.hold_s, ft.accel_mps2, cfg.run.sample_rate_hz, ft.settle_s)
            lim = cfg.limits
            if profile.max_excursion_m >= (lim.position_max_m - lim.position_min_m) / 2:
                raise ConfigError(
                    "friction_test.speeds_mps",
                    f"the friction test travels up to {profile.max_excursion_m:.3f} m, more than half the "
                    f"position window [{lim.position_min_m:g}, {lim.position_max_m:g}] m (shorter hold_s or lower "
                    "speeds)", cfg.source,
                )
        return excitation, profile

    def _check_excitation_travel(self, excitation: Excitation) -> None:
        """A set-point perturbation must keep the axis within half the position window (it starts anywhere in it)."""
        e, lim = self.cfg.excitation, self.cfg.limits
        if not e.closed_loop:
            return  # a torque excitation's travel depends on the plant; the limits guard it
        travel = excitation_travel_m(e.mode, excitation.samples, self.cfg.run.sample_rate_hz)
        half = (lim.position_max_m - lim.position_min_m) / 2
        if travel >= half:
            raise ConfigError(
                f"excitation.{e.amplitude_key}",
                f"the {e.mode} set-point perturbation travels up to {travel:.4g} m from where the axis holds, more "
                f"than half the position window [{lim.position_min_m:g}, {lim.position_max_m:g}] m (a smaller "
                f"amplitude or a higher f_min_hz)", self.cfg.source,
            )

    def _prepare_out(self) -> None:
        """The output folder exists and takes files, or a one-line error before anything moves."""
        try:
            self.out.mkdir(parents=True, exist_ok=True)
            probe = self.out / f".hilident-write-test-{os.getpid()}"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise UsageError(f"--out {self.out}: cannot write there: {exc.strerror or exc}") from None

    def _arm(self) -> None:
        """On a real port, move only with the user's go-ahead: ``confirm(plan)`` shows the plan and asks."""
        if self.dry_run or self.cfg.uses_emulator:
            return
        if self.confirm is None or not self.confirm(self.plan):
            raise ArmingRefused("the run was not confirmed; nothing moved")

    def _friction_step(self, profile):
        if profile is None:
            return None
        windows = np.array(profile.windows, dtype=float).reshape(-1, 3)
        setpoints = profile.setpoint_mps
        if self.friction_mode == "position":
            setpoints = sig.position_of(setpoints, self.cfg.run.sample_rate_hz)
        exp = self.record("friction", self.friction_mode, setpoints,
                          tables={"windows": {"start": windows[:, 0], "stop": windows[:, 1], "velocity_mps": windows[:, 2]}})
        rows = self._rows_by_index(exp)
        kept = [(rows[a], rows[b - 1] + 1, v) for a, b, v in profile.windows if a in rows and b - 1 in rows
                and rows[b - 1] - rows[a] == b - 1 - a]
        self.progress.step("friction: fitting the friction curve")
        result = pipeline.identify_friction(exp.samples["velocity_mps"], exp.samples["torque_nm"], kept,
                                            self.cfg.friction_test.model)
        self.warnings += result.warnings
        return result

    @staticmethod
    def _rows_by_index(exp: Experiment) -> dict[int, int]:
        idx = exp.samples["sample_index"].astype(np.int64)
        return {int(i): r for r, i in enumerate(idx)}

    # --- automatic excitation amplitude ---------------------------------------------------------

    def _auto_amplitude(self, friction) -> Excitation:
        """Choose the torque amplitude by short trials (``amplitude_nm = "auto"``) and build the run's excitation.

        A record at standstill gives the noise floor per excited line; trials
        of a few periods of the same multisine, from the friction test's Fs
        up, predict the coherence the run would reach and the amplitude the
        target needs, and the friction's share the run would carry. Each
        next trial is that amplitude times ``auto_safety``, capped at the
        ceiling and at what the trial's measured peak speed, travel and torque,
        scaled linearly, leave within ``[limits]``. The choice and the reason
        go to ``summary.json["excitation"]["auto"]``.
        """
        cfg = self.cfg
        e = cfg.excitation
        probe = build_excitation(cfg, amplitude=1.0)
        period = probe.period_samples
        band = self._band(probe)
        fs = cfg.run.sample_rate_hz
        bins = np.asarray(probe.excited_bins)
        lines = bins[(bins * fs / period >= band[0]) & (bins * fs / period <= band[1])]
        if lines.size < AUTO_NOISE_LINES:
            lines = bins
        run_periods = len(probe.samples) // period - 1
        fit = friction.fit.params if friction is not None else None
        ceiling, target = amplitude_ceiling_nm(cfg), auto_coherence_target(cfg)
        highest = min(ceiling, AUTO_TORQUE_MARGIN * cfg.limits.torque_nm)  # a trial's peak stays off the trip level
        self.progress.step(f"excitation: choosing the amplitude (coherence target {target:.2f} over "
                           f"{band[0]:g}-{band[1]:g} Hz, ceiling {ceiling:g} N*m)")
        noise = self._auto_noise(period, lines, fit)
        amplitude = min(e.auto_start_nm or self._auto_start(probe, fit, ceiling), highest)
        trials, chosen, reason, needed = [], None, "", None
        for i in range(e.auto_max_trials):
            t = self._auto_trial(i + 1, amplitude, period, lines, run_periods, noise, fit, target,
                                 trials[-1] if trials else None)
            if t is None:
                continue
            trials.append(t)
            cap, cap_by = min((highest, "the ceiling" if highest == ceiling else "limits.torque_nm (with its margin)"),
                              (t["cap_nm"], t["cap_by"]))
            needed = t["needed_nm"]
            enough = needed <= amplitude * (1 + 1e-9)
            close = amplitude * AUTO_MIN_STEP >= cap  # no room left for a trial that would tell more
            if enough or (close and needed <= cap):
                chosen = min(cap, max(amplitude, needed * e.auto_safety))
                reason = self._auto_met(t, cap, band, run_periods, fit, tried=enough)
                break
            if close:
                chosen = cap
                reason = self._auto_capped(t, cap, cap_by, target)
                break
            amplitude = min(cap, max(needed * e.auto_safety, 1.5 * amplitude))
        else:
            chosen, reason = self._auto_out_of_trials(trials, amplitude, needed)
        self._auto = {"chosen_nm": float(chosen), "reason": reason, "target_coherence": target,
                      "band_share": AUTO_BAND_SHARE, "band_hz": [float(band[0]), float(band[1])],
                      "ceiling_nm": float(ceiling), "safety": e.auto_safety, "run_periods": run_periods,
                      "noise_floor": noise["report"], "trials": [t["report"] for t in trials]}
        if reason.startswith("target met"):
            why = f"coherence >= {target:.2f} over {band[0]:g}-{band[1]:g} Hz predicted"
        elif reason.startswith("capped"):
            why = reason.split(":")[0] + f" (coherence {target:.2f}): the notch decision rests on the evidence gates"
        else:
            why = f"target not reached in excitation.auto_max_trials = {e.auto_max_trials}"
        self._auto["line"] = (f"excitation: auto amplitude {chosen:.3g} N*m ({why}; "
                              f"{len(trials)} trial{'s' if len(trials) != 1 else ''})")
        self.progress.step(self._auto["line"])
        self.cfg = dataclasses.replace(cfg, excitation=dataclasses.replace(e, amplitude_nm=float(chosen)))
        return build_excitation(self.cfg)

    def _auto_met(self, trial: dict, cap: float, band, run_periods: int, fit, tried: bool) -> str:
        """The reason when the target is met (by the last trial, or as it predicts when the cap is that close)."""
        e = self.cfg.excitation
        how = "target met" if tried else "target met as predicted (the cap leaves no room for another trial)"
        source = "friction" if fit is not None else "response change between trials"
        return (f"{how}: {trial['needed_nm']:.3g} N*m needed (set by {trial['report']['needed_by']}) times "
                f"excitation.auto_safety = {e.auto_safety:g}, at least the trial's, at most {cap:.3g} N*m; "
                f"coherence >= {auto_coherence_target(self.cfg):.2f} at {AUTO_BAND_SHARE:.0%} of the excited lines "
                f"over {band[0]:g}-{band[1]:g} Hz predicted for the run's {run_periods} periods; nonlinear "
                f"distortion ({source}) within excitation.auto_nonlinear_share = {e.auto_nonlinear_share:g}")

    def _auto_out_of_trials(self, trials: list, amplitude: float, needed: float | None) -> tuple[float, str]:
        """``auto_max_trials`` made before the target: the last prediction (not tried), or an error without any."""
        e = self.cfg.excitation
        if not trials:
            raise DataError(f"excitation.amplitude_nm = \"auto\": none of the {e.auto_max_trials} trials could be "
                            "analysed (lost samples, see the warnings); check the line, or give the amplitude as "
                            "a number")
        reason = (f"excitation.auto_max_trials = {e.auto_max_trials} trials made before the target was met: the run "
                  f"uses the amplitude the last trial predicts ({amplitude:.3g} N*m, within its caps)")
        if needed > amplitude:
            self.warnings.append(f"excitation: auto amplitude {amplitude:.3g} N*m is below the {needed:.3g} N*m the "
                                 "last trial predicts the target needs; the notch decision will rest on the evidence "
                                 "gates")
        return amplitude, reason

    def _auto_start(self, probe: Excitation, fit, ceiling: float) -> float:
        """First trial's amplitude, N·m: the multisine whose rms is the friction test's ``Fs / auto_nonlinear_share``.

        Friction torque is at most Fs (breakaway) and about Fc while sliding, so
        below that rms its nonlinear part would exceed its allowed share for
        sure. Without a friction test, :data:`AUTO_START_SHARE` of the ceiling.
        """
        if fit is None or not fit.Fs > 0:
            return AUTO_START_SHARE * ceiling
        x = probe.samples[probe.period_samples:]  # amplitude 1: peak over rms is the crest factor
        crest = float(np.max(np.abs(x)) / np.sqrt(np.mean(np.square(x))))
        return crest * fit.Fs / self.cfg.excitation.auto_nonlinear_share

    def _auto_capped(self, trial: dict, cap: float, cap_by: str, target: float) -> str:
        """The reason (and a warning) when the cap stops the amplitude before the target."""
        band = trial["report"]["predicted_coherence_band"]
        reason = (f"capped at {cap:.3g} N*m by {cap_by} before the target: coherence {band:.2f} "
                  f"predicted at {AUTO_BAND_SHARE:.0%} of the lines (target {target:.2f}), "
                  f"{trial['needed_nm']:.3g} N*m would be needed (set by {trial['report']['needed_by']})")
        self.warnings.append(f"excitation: auto amplitude {reason}; the notch decision will then rest on the "
                             "evidence gates")
        return reason

    def _band(self, excitation: Excitation) -> tuple[float, float]:
        """The band searched for resonances: ``[identification]`` f_min_hz/f_max_hz, else the excitation's."""
        ic = self.cfg.identification
        return ic.f_min_hz or excitation.band_hz[0], ic.f_max_hz or excitation.band_hz[1]

    def _plant_input(self, s: dict, fit) -> np.ndarray:
        """The torque as the identification sees it: the friction fit removed when there is one."""
        if fit is None:
            return s["torque_nm"]
        from hilident.ident.friction import compensate

        return compensate(s["torque_nm"], s["velocity_mps"], fit, self.cfg.friction_test.velocity_deadband_mps)

    def _auto_noise(self, period: int, lines: np.ndarray, fit) -> dict:
        """Noise power per excited line and period, output and torque, from a record with zero excitation."""
        mode = self.cfg.excitation.mode
        recipe = excitation_recipe(self.cfg, amplitude=0.0, duration_s=1.25 * self.cfg.excitation.period_s)
        exp = self.record("auto_noise", mode, np.zeros(period + period // 4), period_samples=period, recipe=recipe)
        s = exp.samples
        index = s["sample_index"]
        out = {"output": np.zeros(len(lines)), "torque": np.zeros(len(lines))}
        if len(index) < period or index[-1] - index[-period] != period - 1:
            self.warnings.append("excitation: the standstill record lost samples; the noise floor comes from the "
                                 "trials' period-to-period scatter alone")
            out["report"] = None
            return out
        last = {k: v[-period:] for k, v in s.items()}
        for key, x in (("output", last[self.cfg.identification.output]), ("torque", self._plant_input(last, fit))):
            out[key] = smooth_lines(np.abs(period_spectra(x, period, lines)[0]) ** 2)
        # as the amplitude of a sine on one line (peak), the unit of the channel
        out["report"] = {"output_median": float(np.median(2 * np.sqrt(out["output"]) / period)),
                         "torque_nm_median": float(np.median(2 * np.sqrt(out["torque"]) / period)),
                         "output_channel": self.cfg.identification.output, "per": "excited line, peak"}
        return out

    def _auto_trial(self, number: int, amplitude: float, period: int, lines: np.ndarray, run_periods: int,
                    noise: dict, fit, target: float, previous: dict | None) -> dict | None:
        """One trial: the multisine at ``amplitude`` for a few periods, and what it predicts for the run."""
        cfg = self.cfg
        e = cfg.excitation
        duration = e.auto_trial_periods * e.period_s
        trial_cfg = dataclasses.replace(cfg, excitation=dataclasses.replace(e, duration_s=duration))
        x = build_excitation(trial_cfg, amplitude=amplitude)
        exp = self.record(f"auto_trial_{number}", e.mode, x.samples, period_samples=period,
                          recipe=excitation_recipe(cfg, amplitude=amplitude, duration_s=duration))
        try:
            s = self._analysis_samples(exp, x)
        except DataError as exc:  # lost samples: nothing to predict from, the next trial repeats it
            self.warnings.append(f"excitation: auto trial {number} at {amplitude:.3g} N*m could not be analysed: {exc}")
            return None
        spectra = {"output": period_spectra(s[cfg.identification.output], period, lines),
                   "torque": period_spectra(self._plant_input(s, fit), period, lines)}
        m = len(s["sample_index"]) // period
        signal, scatter = {}, {}
        for key, spec in spectra.items():
            scatter[key] = np.maximum(smooth_lines(np.var(spec, axis=0, ddof=1)), noise[key])
            # the periodic part less the mean's own noise; a line lost in the noise keeps a small signal (a tenth
            # of what the mean's noise could hide), so what it needs stays finite, and large
            signal[key] = np.maximum(np.abs(spec.mean(axis=0)) ** 2 - scatter[key] / m, 0.1 * scatter[key] / m)
            # no noise at all (a quantised sensor at rest): a floor far below the signal keeps the ratios finite
            scatter[key] = np.maximum(scatter[key], 1e-12 * max(float(np.max(signal[key])), 1e-300))
        coh = predicted_coherence(signal, scatter, 1.0, run_periods)
        factor = coherence_factor(signal, scatter, run_periods, target)
        means = {key: spec.mean(axis=0) for key, spec in spectra.items()}
        torque_mean = np.where(means["torque"] == 0, 1e-300, means["torque"])
        this = {"amplitude_nm": amplitude, "frf": means["output"] / torque_mean,
                "relative_variance": sum(scatter[k] / np.maximum(signal[k], 1e-300) for k in spectra) / m}
        share, share_by = None, "nonlinear distortion unknown until a second trial"
        if fit is not None:
            stuck = max(cfg.friction_test.velocity_deadband_mps, AUTO_STUCK_SHARE * fit.vs)
            share, share_by = friction_share(s["velocity_mps"], s["excitation"], fit, stuck), "friction's share"
        elif previous is not None and amplitude >= AUTO_MIN_STEP * previous["frf"]["amplitude_nm"]:
            share, share_by = response_change(previous["frf"], this), "response change between trials"
        elif previous is not None and previous["share"] is not None:  # as 1 / A from the last estimate
            share = previous["share"] * previous["frf"]["amplitude_nm"] / amplitude
            share_by = "response change between trials"
        nonlinear = share / e.auto_nonlinear_share if share is not None else AUTO_LINEARITY_STEP / e.auto_safety
        moved = np.median(signal["output"]) > np.median(scatter["output"]) and np.ptp(s[cfg.identification.output]) > 0
        if not moved:  # nothing above the noise: the prediction is weak, step at least this far
            factor, nonlinear = max(min(factor, 1e3), AUTO_NO_RESPONSE_STEP / e.auto_safety), 0.0
        needed = amplitude * max(factor, nonlinear)
        needed_by = ("no response above the noise" if not moved else share_by if nonlinear > factor else "coherence")
        limits = self._auto_caps(exp.samples, amplitude, period, run_periods)
        speed, torque, travel, cap, cap_by = (limits[k] for k in ("speed", "torque", "travel", "cap", "cap_by"))
        report_ = {"amplitude_nm": float(amplitude), "predicted_coherence_min": float(np.min(coh)),
                   "predicted_coherence_median": float(np.median(coh)), "predicted_coherence_band": band_coherence(coh),
                   "coherence_factor": float(factor), "nonlinear_share": float(share) if share is not None else None,
                   "nonlinear_share_from": "friction fit" if fit is not None else "response change between trials",
                   "responded": bool(moved),
                   "needed_nm": float(needed), "needed_by": needed_by, "peak_speed_mps": speed,
                   "peak_torque_nm": torque,
                   "travel_m": float(travel) if travel is not None else None, "cap_nm": float(cap), "cap_by": cap_by}
        self.progress.step(f"  trial {number}: {amplitude:.3g} N*m -> coherence "
                           f"{report_['predicted_coherence_band']:.2f} predicted, {needed:.3g} N*m needed")
        return {"report": report_, "needed_nm": float(needed), "cap_nm": float(cap), "cap_by": cap_by, "frf": this,
                "share": share}

    def _auto_caps(self, full: dict, amplitude: float, period: int, run_periods: int) -> dict:
        """What a trial's measurements allow: the run's peak torque, speed and travel, scaled linearly, in ``[limits]``.

        The travel adds the trial's drift per period (an open-loop axis creeps)
        over the run's extra periods; the room is to the nearer end of the
        position window from where the trial started or ended.
        """
        e, lim = self.cfg.excitation, self.cfg.limits
        speed = float(np.max(np.abs(full["velocity_mps"])))
        torque = float(np.max(np.abs(full["torque_nm"])))
        caps = [(amplitude * AUTO_TORQUE_MARGIN * lim.torque_nm / torque if torque > 0 else np.inf,
                 "limits.torque_nm (the trial's measured peak torque, scaled)"),
                (amplitude * AUTO_LIMIT_MARGIN * lim.velocity_mps / speed if speed > 0 else np.inf,
                 "limits.velocity_mps (the trial's measured peak speed, scaled)")]
        travel = None
        if "position_m" in full:
            pos = full["position_m"]
            start, end = float(pos[0]), float(pos[-1])
            excursion = float(np.max(np.abs(pos - start)))
            drift = abs(end - float(pos[min(period, len(pos) - 1)])) / e.auto_trial_periods
            travel = excursion + drift * max(run_periods - e.auto_trial_periods, 0)
            room = min(lim.position_max_m - max(start, end), min(start, end) - lim.position_min_m)
            caps.append((amplitude * AUTO_LIMIT_MARGIN * max(room, 0.0) / travel if travel > 0 else np.inf,
                         "the position window (the trial's travel and drift, scaled)"))
        cap, cap_by = min(caps)
        return {"speed": speed, "torque": torque, "travel": travel, "cap": float(cap), "cap_by": cap_by}

    def _analysis_samples(self, exp: Experiment, excitation: Excitation) -> dict[str, np.ndarray]:
        """Whole gap-free periods of a periodic excitation, else the longest gap-free stretch (never spliced)."""
        selection = pipeline.select_gap_free(exp.samples["sample_index"], excitation.period_samples, exp.name)
        self.warnings += selection.warnings
        return {k: v[selection.keep] for k, v in exp.samples.items()}

    def _greybox(self):
        """``[model]`` fitted to the identification run, validated on the verification run (or a hold-out)."""
        if self.cfg.model.kind == "none" or "identification" not in self._analysed:
            return None
        s = self._analysed["identification"]
        others = {name: (v["torque_nm"], v["position_m"]) for name, v in self._analysed.items()
                  if name != "identification" and "position_m" in v}
        if "position_m" not in s:
            self.warnings.append(f"[model] {self.cfg.model.kind}: position_m was not recorded")
            return None
        self.progress.step(f"model: {self.cfg.model.kind} grey-box fit")
        try:
            from hilident.offline import model_for_mode

            model = model_for_mode(self.cfg, self.cfg.excitation.mode)  # a held torque command in open loop
            result = pipeline.fit_greybox(model, s["torque_nm"], s["position_m"], self.cfg.run.sample_rate_hz,
                                          others or None)
        except DataError as exc:
            self.warnings.append(f"[model] {self.cfg.model.kind}: {exc}")
            return None
        self.warnings += result.warnings
        return result

    def _identify(self, exp: Experiment, excitation: Excitation, friction):
        cfg = self.cfg
        period = excitation.period_samples
        s = self._analysis_samples(exp, excitation)
        self._analysed["identification"] = s
        ic = cfg.identification
        band = pipeline.analysis_band(ic, excitation.band_hz)
        self._check_it_moved(s[ic.output], friction)
        self.progress.step("identification: frequency response and resonances")
        result = pipeline.identify_plant(
            s["excitation"], s["torque_nm"], s[ic.output], s["velocity_mps"], cfg.run.sample_rate_hz, ic, band,
            friction=friction.fit.params if friction else None,
            velocity_deadband_mps=cfg.friction_test.velocity_deadband_mps,
            period_samples=period, excited_bins=excitation.excited_bins,
        )
        self.warnings += result.warnings
        return result

    def _check_it_moved(self, output: np.ndarray, friction) -> None:
        """A DataError that says what to change when the axis did not move at all during the identification."""
        finite = output[np.isfinite(output)]
        if finite.size and np.ptp(finite) > 0.0:
            return
        e = self.cfg.excitation
        held = ""
        if friction is not None and e.mode in ("torque", "torque_injection"):
            fs = max(friction.fit.params.Fs, friction.fit.params.Fc)
            held = (f"; the friction test measured a breakaway of {fs:.3g} N*m, so an amplitude of at least "
                    f"{3 * fs:.3g} N*m is needed to move it over most of each period")
        raise DataError(f"identification: the axis did not move ({self.cfg.identification.output} constant at "
                        f"{finite[0] if finite.size else float('nan'):g}): the excitation ({e.amplitude:g} "
                        f"{ {'velocity': 'm/s', 'position': 'm'}.get(e.mode, 'N*m') }) is too weak"
                        f"{held}; raise excitation.{e.amplitude_key}"
                        + (' or set it to "auto"' if e.amplitude_key == "amplitude_nm" else ""))

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
            designs = pipeline.design_notches(resonances, nc, ad.identity.loop_rate_hz, [0], plant.loop)
            upload.not_uploaded = (f"driver {self.driver.name!r} describes no filter capability (no [filters] "
                                   "table in its driver.toml): the designed notch was not uploaded")
            self.warnings.append(upload.not_uploaded)
            return designs, upload
        slots = list(range(ad.identity.filter_slots))
        designs = pipeline.design_notches(resonances, nc, ad.identity.loop_rate_hz, slots, plant.loop)
        self.warnings += [d.warning for d in designs if d.warning]
        self.progress.step(f"notch: uploading {len(designs)} filter(s)")
        # written disabled, read back, compared; enabled only as written, else the old contents put back
        uploading.upload_designs(ad, designs, self.warnings, upload)
        self._uploaded = True  # from here the device holds the new notches; other bypassed slots stay bypassed
        return designs, upload

    def _notchable(self, plant, upload: UploadOutcome) -> list:
        """The resonances the evidence supports a notch for; why the others get none goes to warnings and upload."""
        e = self.cfg.excitation
        amplitude = e.amplitude if isinstance(e.amplitude, (int, float)) else None
        decision = pipeline.notch_decision(plant, self.cfg.identification.coherence_threshold, e.amplitude_key,
                                           amplitude)
        self.warnings += decision.warnings
        if decision.skipped_reason is not None:
            upload.skipped_reason = decision.skipped_reason
        return decision.resonances

    def _save_step(self, upload: UploadOutcome, verification) -> None:
        """With ``save``: the device stores its parameters, only after an upload read back and verified."""
        upload.saved = False
        if not self.save:
            return
        if not (upload.written and upload.verified_readback and verification is not None):
            upload.not_saved = "nothing was saved: the notches were not uploaded, read back and verified"
            self.warnings.append(upload.not_saved)
            return
        saved_with, reason = uploading.store_parameters(self.adapter, self.driver.transport, self.progress)
        if saved_with is None:
            upload.not_saved = reason
            self.warnings.append(upload.not_saved)
            return
        upload.saved_with = saved_with
        upload.saved = True

    def _verify(self, excitation: Excitation, plant, designs):
        if not designs or not self.cfg.notch.verify or not self._uploaded:
            return None
        exp = self.record("verification", self.cfg.excitation.mode, excitation.samples,
                          period_samples=excitation.period_samples, recipe=excitation_recipe(self.cfg))
        s = self._analysis_samples(exp, excitation)
        self._analysed["verification"] = s
        self.progress.step("verification: frequency response")
        loop_after, warnings = pipeline.loop_response(
            s["excitation"], s[self.cfg.identification.output], self.cfg.run.sample_rate_hz,
            self.cfg.identification, excitation.period_samples, excitation.excited_bins,
        )
        self.warnings += warnings
        nc = self.cfg.notch
        reductions = pipeline.peak_reductions(plant.loop, loop_after, [d.resonance for d in designs],
                                              nc.verify_band_bandwidths)
        band = min(reductions, key=lambda r: r["band_reduction_db"])
        at_peak = min(r["reduction_db"] for r in reductions)
        if band["band_reduction_db"] < nc.min_reduction_db:
            self.warnings.append(
                f"verification: the largest response within +-{nc.verify_band_bandwidths:g} half-power bandwidths of "
                f"{band['frequency_hz']:.4g} Hz dropped by only {band['band_reduction_db']:.1f} dB (at the resonance "
                f"line: {band['reduction_db']:.1f} dB; notch.min_reduction_db = {nc.min_reduction_db:g})"
            )
        return VerificationPart(band["band_reduction_db"], at_peak, nc.verify_band_bandwidths, reductions, loop_after)

    # --- outputs ----------------------------------------------------------------------------

    def _write_partial_summary(self, step: str, exc: BaseException, friction, plant, designs, upload,
                               verification, elapsed_s: float) -> None:
        """``summary.json`` of a session a step of which failed after others succeeded: their results, the
        failed step's name (``failed_step``) and its error."""
        summary = self._summary(friction, plant, designs, upload, verification, elapsed_s).failed(step, str(exc))
        write_json(self.out / "summary.json", summary.to_dict())
        self.progress.step(f"wrote {self.out / 'summary.json'} up to the failed step ({step})")

    def _summary(self, friction, plant, designs, upload: UploadOutcome, verification: VerificationPart | None,
                 elapsed_s: float, model=NOT_REACHED) -> Summary:
        """The run's :class:`~hilident.summary.Summary` (``model`` left out when the run failed before it)."""
        cfg, ad = self.cfg, self.adapter
        connect = ad.connect_report.to_dict() if ad is not None and hasattr(ad, "connect_report") else None
        return Summary.of_run(
            config=cfg.source, device=DevicePart(self.driver.name, ad.port if ad else None, cfg.uses_emulator),
            sample_rate_hz=cfg.run.sample_rate_hz, excitation=ExcitationPart.of(cfg.excitation, self._auto),
            plant=plant, friction=friction, designs=designs, upload=upload, verification=verification,
            stream=StreamStatistics.of(self.totals), connect=connect, filters_found=self.filters_found,
            recordings=sorted(p.name for p in self.out.glob("*.h5")), elapsed_s=elapsed_s, warnings=self.warnings,
            model=model)

    def _plots(self, friction, plant, designs, verification) -> None:
        if friction is not None:
            pts = friction.points
            vmax = float(np.max(np.abs(pts.v_mean)))
            v = np.linspace(-vmax, vmax, 801)
            from hilident.ident.friction import stribeck

            report.plot_friction(self.out / "friction.png", pts.v_mean, pts.tau_mean, v, stribeck(v, friction.fit.params),
                                 label=friction.model)
        responses = [("plant (net torque to output)", plant.plant), ("excitation to output, before notch", plant.loop)]
        if verification is not None:
            responses.append(("excitation to output, after notch", verification.loop_after))
        notch = pipeline.notch_chain_response(designs, plant.plant.frequency_hz)
        report.plot_bode(self.out / "bode.png", responses, resonances=plant.resonances, notch_response=notch,
                         coherence_threshold=self.cfg.identification.coherence_threshold,
                         **pipeline.bode_extras(plant))
