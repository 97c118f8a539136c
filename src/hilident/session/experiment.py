"""One recorded experiment: stream an excitation into the device and append every sample to its HDF5 file.

:class:`ExperimentRecorder` is what a session records with once its device is
connected; every ending of a run (normal, error, signal, full disk) leaves
the file closed with its status, the device's events and the stream counters.
"""

from __future__ import annotations

import platform
import time
from dataclasses import dataclass, field
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hilident import __version__, endings
from hilident.config.tables import Config
from hilident.errors import HilidentError
from hilident.events import RunEvent, StreamStats
from hilident.io.recording import RunWriter, read_run

if TYPE_CHECKING:
    from hilident.progress import Progress
    from hilident.session.connection import ConnectedDevice

__all__ = [
    "Experiment",
    "ExperimentRecorder",
    "FLUSH_INTERVAL_S",
    "clock_findings",
    "late_sampling_warnings",
    "length_line",
    "package_versions",
]

#: Longest stretch of data (and wall-clock time) held in memory before it is written to the recording, s.
FLUSH_INTERVAL_S = 0.5


def length_line(name: str, mode: str, played_s: float, recipe: dict | None = None) -> str:
    """The progress line of an experiment: how long it plays and, when that differs from the length asked, why.

    Parameters
    ----------
    name, mode : str
        The experiment and the mode it runs in.
    played_s : float
        Length of the excitation as played, s.
    recipe : dict, optional
        :func:`hilident.session.excitation.excitation_recipe` of the experiment:
        its ``kind``, ``duration_s`` (asked, s) and ``period_s``; None for
        set-points such as the friction test's ramps.

    Examples
    --------
    >>> length_line("identification", "torque", 20.0, {"kind": "multisine", "duration_s": 16.0, "period_s": 4.0})
    'identification: 16.0 s of torque excitation asked, 20.0 s played: one lead-in period (4.0 s, not analysed)'
    """
    asked = None if recipe is None else recipe.get("duration_s")
    if not isinstance(asked, (int, float)) or abs(played_s - asked) < 0.05:
        return f"{name}: {played_s:.1f} s of {mode} excitation"
    head = f"{name}: {asked:.1f} s of {mode} excitation asked, {played_s:.1f} s played"
    kind, period = recipe.get("kind") if recipe else None, recipe.get("period_s") if recipe else None
    if kind == "multisine" and isinstance(period, (int, float)) and period > 0:
        whole = max(1, round(asked / period))
        why = f"one lead-in period ({period:.1f} s, not analysed)"
        if abs(whole * period - asked) >= 0.05:
            why = f"{whole} whole periods of {period:.1f} s and one lead-in period (not analysed)"
        return f"{head}: {why}"
    if kind == "prbs":
        return f"{head}: whole PRBS sequences and one more"
    return head


def package_versions() -> dict[str, str]:
    """Versions of hilident and the libraries that shape its numbers."""
    out = {"hilident": __version__, "python": platform.python_version()}
    for name in ("numpy", "scipy", "h5py", "pyserial", "cobs", "matplotlib", "python-can", "canopen", "pymodbus"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    return out


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
            out.append(
                f"{name}: {late} of {samples} SYNCs ({100 * late / samples:.1f} %) were sent more than one "
                "period late"
                + (f" (worst {1e3 * worst:.1f} ms)" if worst is not None else "")
                + ": the drive sampled at uneven instants and the frequency response is distorted; run on a "
                "machine with less load, or at a lower run.sample_rate_hz"
            )
    return out


#: Share of a run's cycles the host's clock may skip (each a missing sample) before the session warns.
SKIPPED_SHARE = 0.01
#: Share of a run's set-points the drive may hold one cycle more (the drive's clock; recorded as held) before
#: the session warns (below it, a note).
HELD_SHARE = 0.25
#: Share of a run's samples the device may play without a fresh set-point (that the host did not skip) unwarned:
#: a CANopen set-point the host sent a few µs before its SYNC's deadline may reach the drive just after it.
UNDERRUN_SHARE = 0.01


def clock_findings(name: str, clock: dict | None, cycles: int) -> tuple[list[str], list[str]]:
    """Warnings and notes from a run's clock report: skipped cycles, held set-points, SYNCs outside the window.

    On the host's clock a skipped cycle is a missing sample (a gap: the
    analysis keeps the whole gap-free periods), worth a warning past
    :data:`SKIPPED_SHARE`. With the drive's or the interface's clock a skipped
    set-point is one the drive held one cycle more, recorded as held: a note,
    and a warning only past :data:`HELD_SHARE`, where it reshapes the excitation.
    """
    if not clock or not cycles:
        return [], []
    warnings: list[str] = []
    notes: list[str] = []
    skipped = int(clock.get("setpoints_skipped", 0))
    share = f"{skipped} of {cycles} ({100 * skipped / cycles:.1f} %)"
    if clock.get("source") == "host":
        if skipped > SKIPPED_SHARE * cycles:
            warnings.append(
                f"{name}: {share} cycles skipped by the host's loop (no SYNC, no sample: the record has gaps); a "
                "drive that produces SYNC or an interface with its own cyclic transmit (SocketCAN) keeps the clock "
                "instead"
            )
    elif skipped:
        text = (
            f"{name}: {share} set-points reached the drive too late for their cycle; the drive held the last one "
            "(the recording holds the set-points applied)"
        )
        (warnings if skipped > HELD_SHARE * cycles else notes).append(
            text
            + (
                "; a less loaded host, or a lower run.sample_rate_hz, sends them in time"
                if skipped > HELD_SHARE * cycles
                else ""
            )
        )
    outside = int(clock.get("outside_window", 0))
    if outside:
        warnings.append(
            f"{name}: {outside} SYNC(s) strayed more than {1e6 * clock.get('window_s', 0):.0f} µs from their "
            f"cycle (the drive's SYNC window), worst {1e3 * clock.get('jitter_max_s', 0):.2f} ms"
        )
    return warnings, notes


@dataclass
class Experiment:
    """Samples of one recorded experiment (read back from its file)."""

    name: str
    path: Path
    samples: dict[str, np.ndarray]
    stats: StreamStats
    events: list[dict] = field(default_factory=list)


class ExperimentRecorder:
    """Records the experiments of one session on its connected device.

    Parameters
    ----------
    device : ConnectedDevice
    out : path
        The folder the recordings go to.
    progress : Progress
    warnings : list of str
        Appended to: lost or corrupt data, saturated values, late SYNCs.

    Attributes
    ----------
    totals : StreamStats
        The stream counters of every run recorded so far, added.
    """

    def __init__(self, device: ConnectedDevice, out: Path, progress: Progress, warnings: list[str]):
        self.device = device
        self.out = out
        self.progress = progress
        self.warnings = warnings
        self.totals = StreamStats()
        self.clocks: list[dict] = []  # each run's clock report (CANopen streamed runs)
        self.notes: list[str] = []  # worth knowing, nothing to act on (held set-points)

    def record(
        self,
        cfg: Config,
        name: str,
        mode: str,
        excitation: np.ndarray,
        tables: dict | None = None,
        period_samples: int | None = None,
        recipe: dict | None = None,
    ) -> Experiment:
        """Stream ``excitation`` in ``mode`` and record every sample to ``<out>/<name>.h5`` (``cfg``: the run's).

        ``period_samples`` (a periodic excitation's period) is stored with the
        recording, so ``hilident identify`` analyses it in whole periods too.
        ``recipe`` is the excitation as parameters, for a drive whose own
        generator plays it (:func:`excitation_recipe`); None for host-made
        set-points such as the friction test's ramps.
        """
        ad = self.device.adapter
        channels = ad.configure(cfg.run.sample_rate_hz, mode, cfg.run.channels or None)
        fs = ad.sample_rate_hz
        path = self.out / f"{name}.h5"
        attrs = {
            "experiment": name,
            "mode": mode,
            "seed": cfg.run.seed,
            "config_toml": cfg.text,
            "config_source": cfg.source,
            "driver_toml": self.device.driver.text,
            "versions": package_versions(),
            "device": {"name": ad.identity.name, "firmware": ad.identity.firmware, "port": ad.port},
        }
        if period_samples:
            attrs["period_samples"] = int(period_samples)
        writer = RunWriter(
            path, ["sample_index", "time_s", *channels], ["1", "s", *ad.channel_units], fs, attrs, overwrite=True
        )
        for table, columns in (tables or {}).items():
            writer.write_table(table, **columns)

        # Blocks are gathered for at most FLUSH_INTERVAL_S of data or of wall-clock time (one HDF5 flush per
        # block would stall the line), then written with the events known so far: a crash loses no more.
        pending: list[np.ndarray] = []
        rows_held, held_since, events_written = 0, time.monotonic(), 0
        flush_rows = max(1, int(FLUSH_INTERVAL_S * fs))

        def write_events(events: list[dict]) -> None:
            nonlocal events_written
            for ev in events[events_written:]:
                writer.log(RunEvent.from_dict(ev))
            events_written = max(events_written, len(events))

        def flush() -> None:
            nonlocal rows_held, held_since
            if pending:
                block = np.concatenate(pending)
                pending.clear()
                rows_held = 0
                writer.append(block)
            write_events(getattr(ad, "events", []))
            held_since = time.monotonic()

        def sink(index: np.ndarray, rows: np.ndarray) -> None:
            nonlocal rows_held
            pending.append(np.column_stack([index, index / fs, rows]))
            rows_held += len(rows)
            if rows_held >= flush_rows or time.monotonic() - held_since >= FLUSH_INTERVAL_S:
                flush()

        trace = cfg.device.canopen.trace
        if trace:
            ad.set_trace(self.out / f"{name}.{trace}")  # CAN trace beside the recording
        self.progress.step(length_line(name, mode, len(excitation) / fs, recipe))
        result = None
        status, reason = "aborted", ""
        ad.last_result = None
        try:
            ad.set_excitation_recipe(recipe)  # for a drive whose own generator plays the excitation
            result = ad.stream(excitation, sink, self.progress.fraction(name))
            status = "complete"
        except BaseException as exc:
            with endings.shielded():
                self.device.safe_stop()  # the device first, whatever ended the run
            reason = str(exc) or type(exc).__name__
            raise
        finally:
            with endings.shielded():
                self._close_recording(writer, status, reason, flush, write_events, ad)
        endings.raise_pending()
        run = read_run(path)
        stats = result.stats
        # underruns the host's skipped set-points explain are in the clock's warning; the others are the device's
        unexplained = max(0, stats.underruns - stats.setpoints_skipped)
        if (
            stats.lost_blocks
            or stats.corrupt_frames
            or stats.out_of_order
            or unexplained > UNDERRUN_SHARE * stats.samples
        ):
            self.warnings.append(
                f"{name}: {stats.lost_blocks} sample blocks ({stats.lost_samples} samples) lost, "
                f"{stats.out_of_order} blocks out of order (discarded), "
                f"{stats.corrupt_frames} corrupt frames, {unexplained} underrun samples"
                + (
                    f" beyond the {stats.setpoints_skipped} set-points the host skipped"
                    if stats.setpoints_skipped
                    else ""
                )
            )
        if stats.clipped_blocks:
            self.warnings.append(
                f"{name}: {stats.clipped_blocks} samples hold a value at the limit of its format "
                "(saturated, not measured; see the recording's events): the response there is not "
                "the plant's"
            )
        self.warnings += late_sampling_warnings(name, result.events, stats.samples)
        if result.clock is not None:
            self.clocks.append({"run": name, **result.clock})
            warnings, notes = clock_findings(name, result.clock, len(excitation))
            self.warnings += warnings
            self.notes += notes
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
                if result.clock is not None:
                    writer.set_attrs(clock=result.clock)
        except HilidentError as exc:
            failure = exc
            reason = reason or str(exc)
        finally:
            if result is not None:
                self.totals = self.totals.add(result.stats)
            writer.close("aborted" if failure else status, reason)
        if failure is not None and status == "complete":
            raise failure  # the run itself went well: the write is what failed
