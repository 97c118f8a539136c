"""``summary.json`` as typed parts, built in one place for ``run``, ``identify`` and ``upload``.

A :class:`Summary` is made of the parts a command produced (friction, plant
and resonances, grey-box model, notch designs, upload, verification, stream
statistics, excitation, warnings and notes, failure); :meth:`Summary.to_dict` lays them
out in the documented order of the command (docs/results.md).
:func:`hilident.io.serialise.write_json` writes it. Pure: no files, no devices.

Examples
--------
>>> s = Summary.of_upload(config="axis.toml", source={"summary": "run/summary.json", "kind": "run",
...                       "notch_filters": []}, device=DevicePart("myrio-board", None, True, identity={}),
...                       filters_before=[], designs=[], upload=UploadOutcome(rolled_back=[]), elapsed_s=0.5,
...                       warnings=[])
>>> list(s.to_dict())[:4]
['hilident_version', 'command', 'config', 'source']
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hilident import __version__
from hilident.events import StreamStats
from hilident.pipeline.findings import grouped

__all__ = [
    "DevicePart",
    "ExcitationPart",
    "Failure",
    "PlantPart",
    "Summary",
    "UploadOutcome",
    "VerificationPart",
    "designed_and_stored",
    "friction_summary",
]

#: The top-level keys of each command's summary.json, in their documented order.
LAYOUTS: dict[str, tuple[str, ...]] = {
    "run": (
        "hilident_version",
        "config",
        "device",
        "sample_rate_hz",
        "excitation",
        "resonances",
        "rejected_peaks",
        "plant_model",
        "measurement",
        "mimo",  # with [identification] outputs only
        "friction",
        "notch_filters",
        "input_shaper",  # with resonances only
        "upload",
        "verification",
        "stream",
        "clock",
        "connect",
        "filters_found",
        "recordings",
        "elapsed_s",
        "warnings",
        "notes",
        "model",
        "map",
        "workspace",
        "move_test",
        "loop",
    ),
    "identify": (
        "hilident_version",
        "config",
        "data",
        "mimo",  # with [data] inputs and outputs only
        "resonances",
        "rejected_peaks",
        "friction",
        "model",
        "plant_model",
        "measurement",
        "notch_filters",
        "notch_skipped_reason",
        "input_shaper",  # with resonances only
        "upload",
        "verification",
        "stream",
        "elapsed_s",
        "warnings",
        "notes",
    ),
    "upload": (
        "hilident_version",
        "command",
        "config",
        "source",
        "device",
        "filters_before",
        "notch_filters",
        "upload",
        "elapsed_s",
        "warnings",
    ),
}


class _NotReached:
    """A part whose step was never reached: its key is left out of summary.json (a run's ``model`` after a
    failed step)."""

    def __repr__(self) -> str:
        return "NOT_REACHED"


NOT_REACHED: Any = _NotReached()


def _set_fields(obj: Any, names: tuple[str, ...]) -> dict[str, Any]:
    """``names`` of ``obj`` that are not None, in that order."""
    return {name: getattr(obj, name) for name in names if getattr(obj, name) is not None}


@dataclass
class UploadOutcome:
    """What became of the notch upload (``summary.json["upload"]``).

    ``written``, ``verified_readback`` and ``slots`` are always there; every
    other field appears once its step set it (``skipped_reason``: the evidence
    allowed no notch; ``not_uploaded``: the drive has no filter capability;
    ``rolled_back``: ``hilident upload`` put slots back; ``saved``,
    ``saved_with``, ``not_saved``: the store to non-volatile memory).
    """

    written: bool = False
    verified_readback: bool = False
    slots: list[dict] = field(default_factory=list)
    skipped_reason: str | None = None
    not_uploaded: str | None = None
    rolled_back: list[dict] | None = None
    saved: bool | None = None
    saved_with: str | None = None
    not_saved: str | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "written": self.written,
            "verified_readback": self.verified_readback,
            "slots": self.slots,
        }
        out.update(
            _set_fields(self, ("skipped_reason", "not_uploaded", "rolled_back", "saved", "saved_with", "not_saved"))
        )
        return out


@dataclass
class VerificationPart:
    """The verification run's figures (``summary.json["verification"]``), dB; empty without a verification."""

    band_reduction_db: float | None = None
    peak_reduction_db: float | None = None
    band_bandwidths: float | None = None
    resonances: list[dict] = field(default_factory=list)
    loop_after: Any = None  # the response after the notch (plots only, not in summary.json)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"band_reduction_db": self.band_reduction_db, "peak_reduction_db": self.peak_reduction_db}
        if self.band_bandwidths is not None:
            out["band_bandwidths"] = self.band_bandwidths
        out["resonances"] = self.resonances
        return out


@dataclass
class ExcitationPart:
    """What excited the axis, where it entered, in which unit (``summary.json["excitation"]``)."""

    kind: str
    mode: str
    amplitude: Any
    unit: str
    closed_loop: bool
    amplitude_setting: str | None = None
    auto: dict | None = None
    reference: str | None = None

    @classmethod
    def of(cls, e: Any, auto: dict | None) -> ExcitationPart:
        """From ``[excitation]`` and the automatic amplitude's record (None: the amplitude was given)."""
        reference = None
        if e.closed_loop:
            reference = (
                f"the {e.mode} set-point perturbation: the plant (torque to output) is estimated "
                "against it, so noise the drive's loop feeds back does not bias it"
            )
        return cls(
            e.kind,
            e.mode,
            e.amplitude,
            {"velocity": "m/s", "position": "m"}.get(e.mode, "N*m"),
            e.closed_loop,
            "auto" if auto is not None else None,
            auto,
            reference,
        )

    def to_dict(self) -> dict[str, Any]:
        out = {
            "kind": self.kind,
            "mode": self.mode,
            "amplitude": self.amplitude,
            "unit": self.unit,
            "closed_loop": self.closed_loop,
        }
        out.update(_set_fields(self, ("amplitude_setting", "auto", "reference")))
        return out


@dataclass
class DevicePart:
    """The device a command used; ``identity`` (what it reported) only in an upload's summary."""

    driver: str | None
    port: str | None
    emulated: bool
    identity: dict | None = None

    @classmethod
    def reported(cls, driver: str | None, port: str | None, emulated: bool, identity: Any) -> DevicePart:
        """With the device's ``name``, ``firmware``, ``loop_rate_hz`` and ``filter_slots`` (None: not opened)."""
        return cls(
            driver,
            port,
            emulated,
            {key: getattr(identity, key, None) for key in ("name", "firmware", "loop_rate_hz", "filter_slots")},
        )

    def to_dict(self) -> dict[str, Any]:
        return {"driver": self.driver, "port": self.port, "emulated": self.emulated, **(self.identity or {})}


@dataclass
class PlantPart:
    """The plant response's findings: resonances, rejected peaks, fitted model, measurement quality."""

    resonances: list[dict] = field(default_factory=list)
    rejected_peaks: list[dict] = field(default_factory=list)
    plant_model: dict | None = None
    measurement: dict | None = None

    @classmethod
    def of(cls, plant: Any, no_measurement: Any = None) -> PlantPart:
        """From a :class:`hilident.pipeline.plant.PlantResult` (None: the step was not reached)."""
        if plant is None:
            return cls(measurement=no_measurement)
        from hilident.pipeline.records import rejected_peak_records, resonance_records

        return cls(
            resonance_records(plant.resonances),
            rejected_peak_records(plant.rejected),
            plant.model.to_dict() if plant.model else None,
            plant.quality,
        )


@dataclass(frozen=True)
class Failure:
    """The step that failed after earlier ones succeeded, and its error (``failed_step``, ``error``)."""

    step: str
    error: str


def designed_and_stored(summary: dict) -> list[tuple[dict, dict]]:
    """Each of ``summary.json``'s ``notch_filters`` with the ``upload.slots`` record of its slot (``{}`` when it
    was not uploaded), paired by node and slot: a run of several nodes puts each drive's notch in its own slot 0.
    Entries that are not records are left out."""

    def records(value: Any) -> list[dict]:
        return [v for v in value if isinstance(v, dict)] if isinstance(value, list) else []

    upload = summary.get("upload")
    slots = records(upload.get("slots") if isinstance(upload, dict) else None)
    stored = {(slot.get("node"), slot.get("slot")): slot for slot in slots}
    return [(d, stored.get((d.get("node"), d.get("slot")), {})) for d in records(summary.get("notch_filters"))]


def friction_summary(friction: Any) -> dict | None:
    """``summary.json["friction"]`` of a :class:`hilident.pipeline.friction.FrictionResult` (None: no friction test)."""
    if friction is None:
        return None
    p = friction.fit.params
    return {
        "model": friction.model,
        "params": {"Fc": p.Fc, "Fs": p.Fs, "Fv": p.Fv, "vs": p.vs, "delta_v": p.delta_v, "delta_s": p.delta_s},
        "structure": friction.fit.structure or friction.model,
        "aicc": friction.fit.criterion,
        "stderr": friction.fit.stderr,
        "rms_residual_nm": friction.fit.rms_residual,
        "points": len(friction.points.v_mean),
        "ci95": friction.intervals(),
        "extension": friction.extension,
    }


def move_test_summary(results: list) -> dict:
    """``summary.json["move_test"]``: each place's moves and the worst reduction over them (the figure that
    must hold everywhere)."""
    moves = [r.to_dict() for r in results]
    if not moves:
        return {"moves": [], "worst_rms_reduction_db": None, "worst_start_m": None}
    # None: the move with the notch left no vibration at all, an infinite reduction
    worst = min(moves, key=lambda m: float("inf") if m["rms_reduction_db"] is None else m["rms_reduction_db"])
    return {"moves": moves, "worst_rms_reduction_db": worst["rms_reduction_db"], "worst_start_m": worst["start_m"]}


def _notch_filters(designs: list) -> list[dict]:
    from hilident.pipeline.records import notch_records

    return notch_records(designs)


@dataclass
class Summary:
    """One command's ``summary.json``, as typed parts.

    Build it with :meth:`of_run`, :meth:`of_identify` or :meth:`of_upload`;
    :meth:`to_dict` gives the documented layout of its ``command``.
    """

    command: str
    config: str
    elapsed_s: float
    warnings: list[str]
    upload: UploadOutcome
    designs: list = field(default_factory=list)
    plant: PlantPart = field(default_factory=PlantPart)
    friction: dict | None = None
    model: Any = None
    verification: VerificationPart = field(default_factory=VerificationPart)
    stream: StreamStats = field(default_factory=StreamStats)
    device: DevicePart | None = None
    excitation: ExcitationPart | None = None
    extra: dict[str, Any] = field(default_factory=dict)  # the command's own sections (data, source, connect, ...)
    failure: Failure | None = None
    notes: list[str] = field(default_factory=list)

    @classmethod
    def of_run(
        cls,
        *,
        config: str,
        device: DevicePart,
        sample_rate_hz: float,
        excitation: ExcitationPart,
        plant: Any,
        friction: Any,
        designs: list,
        upload: UploadOutcome,
        verification: VerificationPart | None,
        stream: StreamStats,
        connect: dict | None,
        filters_found: list[dict],
        clock: list[dict] | None = None,
        recordings: list[str],
        elapsed_s: float,
        warnings: list[str],
        model: Any = NOT_REACHED,
        workspace_map: list | None = None,
        move_test: list | None = None,
        workspace: dict | None = None,
        notes: list[str] | None = None,
        loop: dict | None = None,
        mimo: dict | None = None,
        shaper_over_travel: dict | None = None,
    ) -> Summary:
        """``hilident run``'s summary (``model``: the grey-box fit, None when not asked for; left out when the
        run failed before it; ``workspace_map``: the ``[map]`` points, left out of a run without ``[map]``;
        ``move_test``: each ``[verification] move`` result, left out of a run without one; ``workspace``: the
        ``[map]``'s joint fit and covering notch; ``notes``: what is worth knowing and needs no action;
        ``loop``: the drive's loop around the plant, left out of a run on a drive without ``[loop]``; ``mimo``: the
        modes of ``[identification] output`` and ``outputs`` together, left out without ``outputs``;
        ``shaper_over_travel``: the fixed and the scheduled input shaper along the mapped travel, which
        ``input_shaper`` then holds as ``over_travel``)."""
        return cls(
            "run",
            config,
            elapsed_s,
            warnings,
            upload,
            designs,
            PlantPart.of(plant),
            friction_summary(friction),
            model,
            verification or VerificationPart(),
            stream,
            device,
            excitation,
            {
                "sample_rate_hz": sample_rate_hz,
                "clock": list(clock or []),
                "connect": connect,
                "filters_found": filters_found,
                "recordings": recordings,
                "map": NOT_REACHED if workspace_map is None else [p.to_dict() for p in workspace_map],
                "workspace": NOT_REACHED if workspace is None else workspace,
                "move_test": NOT_REACHED if move_test is None else move_test_summary(move_test),
                "loop": NOT_REACHED if loop is None else loop,
                "mimo": NOT_REACHED if mimo is None else mimo,
                "shaper_over_travel": shaper_over_travel,
            },
            notes=list(notes or []),
        )

    @classmethod
    def of_identify(
        cls,
        *,
        config: str,
        data: dict,
        plant: Any,
        friction: Any,
        model: Any,
        designs: list,
        notch_skipped_reason: str | None,
        elapsed_s: float,
        warnings: list[str],
        notes: list[str] | None = None,
        mimo: dict | None = None,
    ) -> Summary:
        """``hilident identify``'s summary: no upload or verification, the stream is the data file's rows; with
        several inputs and outputs (``mimo``, :mod:`hilident.pipeline.mimo_identify`) their part."""
        stream = StreamStats(samples=data["samples"], lost_samples=data.get("missing_samples", 0))
        return cls(
            "identify",
            config,
            elapsed_s,
            list(warnings),
            UploadOutcome(),
            designs,
            PlantPart.of(plant, no_measurement={}),
            friction_summary(friction),
            model,
            stream=stream,
            extra={"data": data, "notch_skipped_reason": notch_skipped_reason, **({"mimo": mimo} if mimo else {})},
            notes=list(notes or []),
        )

    @classmethod
    def of_upload(
        cls,
        *,
        config: str,
        source: dict,
        device: DevicePart,
        filters_before: list[dict],
        designs: list,
        upload: UploadOutcome,
        elapsed_s: float,
        warnings: list[str],
    ) -> Summary:
        """``hilident upload``'s summary: the source, the device and what its slots held before and after."""
        return cls(
            "upload",
            config,
            elapsed_s,
            warnings,
            upload,
            designs,
            device=device,
            extra={"command": "upload", "source": source, "filters_before": filters_before},
        )

    def failed(self, step: str, error: str) -> Summary:
        """This summary, naming the step that failed and its error."""
        self.failure = Failure(step, error)
        return self

    def _sections(self) -> dict[str, Any]:
        """Every part by its summary.json key (a command uses those of its layout)."""
        model = self.model.to_dict() if self.model not in (None, NOT_REACHED) else self.model
        return {
            "hilident_version": __version__,
            "config": self.config,
            "device": self.device.to_dict() if self.device else None,
            "excitation": self.excitation.to_dict() if self.excitation else None,
            "resonances": self.plant.resonances,
            "rejected_peaks": self.plant.rejected_peaks,
            "plant_model": self.plant.plant_model,
            "measurement": self.plant.measurement,
            "friction": self.friction,
            "model": model,
            "notch_filters": _notch_filters(self.designs),
            "upload": self.upload.to_dict(),
            "verification": self.verification.to_dict(),
            "stream": self.stream.to_summary(),
            "elapsed_s": self.elapsed_s,
            "warnings": grouped(self.warnings),
            "notes": grouped(self.notes),
            "mimo": NOT_REACHED,  # an identify of several inputs and outputs has it (extra)
            **self.extra,
            "input_shaper": self._input_shaper(),
        }

    def _input_shaper(self) -> Any:
        """The input shaper the resonances favour, and whether it or a notch (:mod:`hilident.pipeline.input_shaper`);
        left out without resonances."""
        from hilident.pipeline.input_shaper import input_shaper_part

        loop = self.extra.get("loop")
        part = input_shaper_part(self.plant.resonances, loop if isinstance(loop, dict) else None)
        if part is None:
            return NOT_REACHED
        over_travel = self.extra.get("shaper_over_travel")
        if over_travel:
            part["over_travel"] = over_travel
        return part

    def to_dict(self) -> dict[str, Any]:
        """The summary in its command's documented layout, ``failed_step`` and ``error`` last when a step failed."""
        sections = self._sections()
        out = {key: sections[key] for key in LAYOUTS[self.command] if sections[key] is not NOT_REACHED}
        if self.failure is not None:
            out.update(failed_step=self.failure.step, error=self.failure.error)
        return out
