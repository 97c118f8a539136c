"""``hilident run`` on several drives of one CANopen bus (``[device.canopen] node_ids``): every node excited at
once, one SYNC, one recording, the modes from all of them.

Each node plays its own column of a zippered multisine (:func:`hilident.ident.mimo.zippered_multisine`: every
node owns every ``n``-th line of the band, so at its lines the responses are that node's alone); the nodes are
armed together before the first SYNC and switched off together on every ending
(:class:`~hilident.adapters.canopen.group.NodeGroup`). The recording holds every node's channels, named
``<channel>_node<id>``; the identification reads every node's torque as an input and every node's
``[identification] output`` (and ``outputs``, where recorded) as outputs, all at once
(:func:`hilident.pipeline.mimo_identify.identify_channels`): the frequency-response matrix, the modes with their
intervals, shapes over the outputs and participation from each drive, the stabilisation diagram. The record is
read at every node's own lines where it holds the zipper as designed; a set-point a node held for a late host
(counted, ``setpoints_skipped``) leaks a little of its input onto the other nodes' lines, and the record is then
read as the recorded torques are (the multi-input H1 estimate, which needs no zipper). The notches are judged on
every node's set-point to its own output, read at the lines as designed (:func:`designed_lines`) in both runs.

Every node's filter slots are bypassed while the mechanism is measured; each node then gets notches at the modes
it drives and sees, uploaded, read back and enabled, and the same excitation played again proves them on every
node's own response (:class:`~hilident.session.node_notch_step.NodeNotchStep`). A run of one node's friction
test, loop analysis and gain tuning are not done for several nodes; the summary says so.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from hilident import endings, html_report
from hilident.config.tables import Config, node_ids
from hilident.errors import ArmingRefused, ConfigError
from hilident.io.serialise import write_json
from hilident.io.summary import DevicePart, ExcitationPart, Summary
from hilident.plots.common import plot_title
from hilident.plots.stabilisation import STABILISATION_PNG, plot_stabilisation
from hilident.progress import Progress
from hilident.session.connection import DeviceConnection
from hilident.session.experiment import ExperimentRecorder
from hilident.session.node_notch_step import NodeNotchStep
from hilident.session.plan import PlannedExperiment, RunPlan
from hilident.signals.excitation import Excitation

__all__ = ["NodesSession", "designed_lines", "nodes_excitation"]

#: What a run of several nodes does not do that a run of one node does, as the summary says it.
NOT_DONE = (
    "several nodes ([device.canopen] node_ids): the modes of all drives at once, every drive's notches for the "
    "modes it drives and sees; no friction test, loop analysis or gain tuning (a run of one node does those)"
)


def nodes_excitation(cfg: Config, n_nodes: int) -> Excitation:
    """Every node's column of one zippered multisine of ``[excitation]`` (peak ``amplitude_nm`` each).

    Whole periods of ``period_s`` filling ``duration_s``, at least three (the first is the lead-in the
    analysis skips).

    Raises
    ------
    ConfigError
        ``excitation.kind`` is not ``multisine``, ``excitation.mode`` not ``torque``, or ``amplitude_nm`` is
        ``"auto"``: the key and the file are named.
    """
    from hilident.ident.mimo import zippered_multisine

    e, fs = cfg.excitation, cfg.run.sample_rate_hz
    if e.kind != "multisine":
        raise ConfigError(
            "excitation.kind", f"is {e.kind!r}: several nodes are excited at once by a zippered multisine", cfg.source
        )
    if e.mode != "torque":
        raise ConfigError("excitation.mode", f"is {e.mode!r}: several nodes are excited in torque", cfg.source)
    if e.amplitude_auto:
        raise ConfigError("excitation.amplitude_nm", "is 'auto': give several nodes a number, N*m", cfg.source)
    period = int(round(e.period_s * fs))
    periods = max(3, int(e.duration_s // e.period_s))
    one, lines = zippered_multisine(n_nodes, period, fs, (e.f_min_hz, e.f_max_hz), seed=cfg.run.seed or 0)
    one = one / np.max(np.abs(one), axis=0) * float(e.amplitude)
    return Excitation(np.tile(one, (periods, 1)), period, (e.f_min_hz, e.f_max_hz), np.sort(np.concatenate(lines)))


def designed_lines(excitation: Excitation, period: int | None) -> list | None:
    """Every node's own lines of the zippered multisine as designed (None for a record that is not whole periods).

    The set-points are read at them whatever the record shows, so the runs before and after the notches are read
    alike: a set-point a node held for a late host (counted, ``setpoints_skipped``) leaks a little of its input
    onto the other nodes' lines, and no lines would be found in such a record.
    """
    from hilident.ident.mimo import zippered_lines

    return zippered_lines(excitation.samples, period) if period else None


class NodesSession(DeviceConnection):
    """A bench run of every node of ``[device.canopen] node_ids`` at once.

    Parameters
    ----------
    cfg : Config
    out_dir : path
        Where the recording, the plots and ``summary.json`` go.
    progress : Progress, optional
    confirm : callable, optional
        ``confirm(plan) -> bool``: the user's go-ahead on a real bus (the emulator needs none).
    dry_run : bool
        Connect, check and plan; move nothing.
    plots : bool
    """

    def __init__(
        self,
        cfg: Config,
        out_dir: str | Path,
        progress: Progress | None = None,
        confirm: Callable[[RunPlan], bool] | None = None,
        dry_run: bool = False,
        plots: bool = True,
    ):
        cfg.bench_limits  # noqa: B018 - the ConfigError of a config without [limits] before anything starts
        self.cfg = cfg
        self.out = Path(out_dir)
        self.progress = progress or Progress(enabled=False)
        self.confirm = confirm
        self.dry_run = dry_run
        self.plots = plots
        self.warnings: list[str] = []
        self.plan: RunPlan | None = None
        self.plan_identity = None  # the drives' identity, read when they were opened
        self.summary: dict = {}
        self.notches: NodeNotchStep | None = None

    def run(self) -> dict:
        """Connect every node, play the excitation on all at once, identify; notch every node and prove it; the
        summary (also written)."""
        cfg = self.cfg
        nodes = node_ids(cfg.device)
        excitation = nodes_excitation(cfg, len(nodes))
        started = time.monotonic()
        verification = None
        try:
            device = self.open_device()
            lim = cfg.bench_limits
            self.adapter.set_limits(lim.torque_nm, lim.velocity_mps, lim.position_min_m, lim.position_max_m)
            self.plan = self._plan(excitation)
            self.plan_identity = self.adapter.identity
            if self.dry_run:
                return {"dry_run": True, "plan": self.plan.to_dict()}
            if not cfg.uses_emulator and (self.confirm is None or not self.confirm(self.plan)):
                raise ArmingRefused("the run was not confirmed; nothing moved")
            self.out.mkdir(parents=True, exist_ok=True)
            notches = self.notches = NodeNotchStep(cfg, self.adapter.adapters, self.progress, self.warnings)
            notches.bypass()
            recorder = ExperimentRecorder(device, self.out, self.progress, self.warnings)
            recordings = [self._record(recorder, "identification", excitation)]
            mimo, response, own_outputs = self._identify(recordings[0].samples, nodes, excitation)
            if notches.wanted:
                loop = self._set_point_response(recordings[0].samples, nodes, excitation)
                notches.design_and_upload(mimo, response, own_outputs, loop)
            if notches.uploaded and cfg.notch.verify:
                recordings.append(self._record(recorder, "verification", excitation))
                verification = notches.verify(self._set_point_response(recordings[1].samples, nodes, excitation))
        except BaseException:
            with endings.shielded():
                self.safe_stop()
                if self.notches is not None:
                    self.notches.restore()
            raise
        finally:
            with endings.shielded():
                self.close()
        endings.raise_pending()
        summary = Summary.of_run(
            config=cfg.source,
            device=DevicePart.reported(cfg.device.driver, self.plan.port, cfg.uses_emulator, self.plan_identity),
            sample_rate_hz=cfg.run.sample_rate_hz,
            excitation=ExcitationPart.of(cfg.excitation, None),
            plant=None,
            friction=None,
            designs=notches.designs,
            upload=notches.upload,
            verification=verification,
            stream=recorder.totals,
            connect=None,
            filters_found=notches.filters_found,
            clock=recorder.clocks,
            recordings=[exp.path.name for exp in recordings],
            elapsed_s=time.monotonic() - started,
            warnings=self.warnings + mimo["warnings"],
            notes=[NOT_DONE, *recorder.notes, *notches.notes],
            mimo=mimo,
        )
        self.summary = summary.to_dict()
        for record, node in zip(self.summary["notch_filters"], notches.design_nodes, strict=True):
            record["node"] = node
        write_json(self.out / "summary.json", self.summary)
        if self.plots:
            self._plot(response)
        html_report.write_report_quietly(self.out)
        return self.summary

    def _record(self, recorder: ExperimentRecorder, name: str, excitation: Excitation):
        """One run of the zippered excitation on every node (``identification`` or ``verification``)."""
        return recorder.record(self.cfg, name, "torque", excitation.samples, period_samples=excitation.period_samples)

    def _plan(self, excitation: Excitation) -> RunPlan:
        """What the run will do, for the go-ahead and ``--dry-run``."""
        cfg, group = self.cfg, self.adapter
        fs = cfg.run.sample_rate_hz
        e, lim = cfg.excitation, cfg.bench_limits
        peak = float(np.max(np.abs(excitation.samples)))
        return RunPlan(
            device=group.identity.name,
            port=group.port,
            limits=dataclasses.asdict(lim),
            experiments=[
                PlannedExperiment(
                    name="identification",
                    description=f"zippered multisine {e.f_min_hz:g}-{e.f_max_hz:g} Hz on nodes "
                    + ", ".join(map(str, group.node_ids)),
                    mode="torque",
                    duration_s=len(excitation.samples) / fs,
                    samples=len(excitation.samples),
                    peak_torque_nm=peak,
                    peak_speed_mps=None,
                    travel_m=None,
                )
            ],
        )

    def _identify(self, samples: dict[str, np.ndarray], nodes: list[int], excitation: Excitation):
        """Every node's torque against every node's outputs, at once: the ``mimo`` part, the response, and
        every node's own output (its ``[identification] output``) among the response's outputs."""
        from hilident.adapters.canopen.group import node_channel
        from hilident.pipeline.mimo_identify import identify_channels
        from hilident.protocol.canopen_profile import CHANNEL_UNITS

        ic = self.cfg.identification
        inputs = [node_channel("torque_nm", n) for n in nodes]
        wanted = [ic.output, *ic.outputs]
        recorded = [(name, n) for name in wanted for n in nodes if node_channel(name, n) in samples]
        outputs = [node_channel(name, n) for name, n in recorded]
        missing = [name for name in wanted if not any(node_channel(name, n) in samples for n in nodes)]
        if missing:
            self.warnings.append(
                f"identification.outputs: {', '.join(missing)} not recorded on any node (run.channels): left out"
            )
        units = [CHANNEL_UNITS.get(name, "") for name, _ in recorded]  # what a CiA 402 drive's channels carry
        data = dataclasses.replace(
            self.cfg.data, inputs=inputs, outputs=outputs, input_scales=[], output_scales=[], output_units=units
        )
        cfg = dataclasses.replace(self.cfg, data=data)
        u = np.column_stack([samples[c] for c in inputs])
        y = np.column_stack([samples[c] for c in outputs])
        keep, period = self._gap_free(samples["sample_index"], excitation.period_samples)
        fs = self.cfg.run.sample_rate_hz
        mimo, response = identify_channels(u[keep], y[keep], fs, cfg, "identification.h5", period)
        return mimo, response, [outputs.index(node_channel(ic.output, n)) for n in nodes]

    def _set_point_response(self, samples: dict[str, np.ndarray], nodes: list[int], excitation: Excitation):
        """Every node's set-point (``excitation_node<id>``) to every node's own output, in node order: what a
        notch filters, before and after it (:func:`hilident.pipeline.mimo_identify.estimate_channels`)."""
        from hilident.adapters.canopen.group import node_channel
        from hilident.pipeline.mimo_identify import estimate_channels

        ic = self.cfg.identification
        u = np.column_stack([samples[node_channel("excitation", n)] for n in nodes])
        y = np.column_stack([samples[node_channel(ic.output, n)] for n in nodes])
        keep, period = self._gap_free(samples["sample_index"], excitation.period_samples)
        fs = self.cfg.run.sample_rate_hz
        return estimate_channels(
            u[keep], y[keep], fs, ic, "the set-points", period, designed_lines(excitation, period)
        ).response

    def _gap_free(self, index: np.ndarray, period: int | None) -> tuple[slice, int | None]:
        """The rows analysed: all of them when no sample is missing; else the longest run of consecutive
        samples (a record with holes is never read as if it had none, nor filled), not periodic any more,
        with a warning."""
        index = np.asarray(index, dtype=np.int64)
        breaks = np.flatnonzero(np.diff(index) != 1) + 1
        if not len(breaks):
            return slice(None), period
        edges = np.concatenate([[0], breaks, [len(index)]])
        longest = int(np.argmax(np.diff(edges)))
        a, b = int(edges[longest]), int(edges[longest + 1])
        fs = self.cfg.run.sample_rate_hz
        self.warnings.append(
            f"identification: {int(index[-1]) + 1 - len(index)} sample(s) lost in {len(breaks)} gap(s): the modes "
            f"come from the longest gap-free stretch, {(b - a) / fs:.2f} s of {(int(index[-1]) + 1) / fs:.2f} s "
            "(a machine less busy, or a lower run.sample_rate_hz, loses none)"
        )
        return slice(a, b), None

    def _plot(self, response) -> None:
        """The stabilisation diagram of the modes, on the response's first singular value."""
        if not (self.summary.get("mimo") or {}).get("stabilisation"):
            return
        plot_stabilisation(
            self.out / STABILISATION_PNG,
            self.summary["mimo"],
            response.frequency_hz,
            response.response,
            title=plot_title(Path(self.cfg.source).name, what="Stabilisation, every node"),
        )
