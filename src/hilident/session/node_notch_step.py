"""The notch step of a run of several drives of one bus: every drive's slots bypassed while the mechanism is
measured, its notches designed for the modes it drives and sees, uploaded, read back and enabled, and proved by
a second run.

Each node is one drive with its own filter slots, so each goes through what a run of one drive does
(:class:`~hilident.session.slot_bypass.BypassedSlots`, :func:`~hilident.pipeline.notches.design_notches`,
:func:`~hilident.session.upload.upload_designs`), on the modes :func:`hilident.pipeline.node_notches.node_resonances`
gives it. A session that ends before the upload puts every node's bypassed slots back.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hilident.config.tables import Config
from hilident.ident.frequency import FrequencyResponse
from hilident.ident.mimo import MimoResponse
from hilident.io.summary import UploadOutcome, VerificationPart
from hilident.pipeline.node_notches import node_reductions, node_resonances, own_response
from hilident.pipeline.notches import NotchDesign, design_notches
from hilident.pipeline.verification import shortfall_warning
from hilident.progress import Progress
from hilident.session.slot_bypass import BypassedSlots
from hilident.session.upload import upload_designs

__all__ = ["NodeNotchStep"]


@dataclass
class _Node:
    """One drive of the group: its adapter, its place in the fit, its slots and its notches."""

    node_id: int
    adapter: Any  # the node's CanopenDriveAdapter, from the group
    index: int  # its input (its torque), in the fit's order
    slots: BypassedSlots = field(default_factory=BypassedSlots)
    loop: FrequencyResponse | None = None  # its set-point to its own output, before the notches
    designs: list[NotchDesign] = field(default_factory=list)
    uploaded: bool = False  # its slots hold the new notches: nothing of it is put back


class NodeNotchStep:
    """Every node's notches, from the bypass before the identification to the verification after the upload.

    Parameters
    ----------
    cfg : Config
        ``[notch]`` (``enabled``, ``verify``, the design keys) and ``[identification] max_resonances`` (per drive).
    adapters : list
        The group's adapters, in node order (each with ``node_id``, ``identity``, the filter methods).
    progress : Progress
    warnings : list of str
        The run's, appended to.
    """

    def __init__(self, cfg: Config, adapters: list, progress: Progress, warnings: list[str]):
        self.cfg = cfg
        self.nodes = [_Node(a.node_id, a, i) for i, a in enumerate(adapters)]
        self.progress = progress
        self.warnings = warnings
        self.notes: list[str] = []
        self.upload = UploadOutcome()

    @property
    def wanted(self) -> bool:
        return bool(self.cfg.notch.enabled)

    def bypass(self) -> None:
        """Every node's slots read, and those that filter bypassed, so the identification measures the bare
        mechanism."""
        if not self.wanted:
            return
        for node in self.nodes:
            node.slots.read(node.adapter)
            node.slots.bypass(node.adapter, self.progress)

    def restore(self) -> None:
        """What the bypassed slots of every node not yet uploaded to held put back. Never raises."""
        for node in self.nodes:
            if not node.uploaded:
                node.slots.restore(node.adapter, self.warnings)

    @property
    def uploaded(self) -> bool:
        """Some node's slots hold the new notches."""
        return any(node.uploaded for node in self.nodes)

    @property
    def filters_found(self) -> list[dict]:
        """What every node's slots held when the session began, each with its ``node``."""
        return [{"node": node.node_id, **found} for node in self.nodes for found in node.slots.found]

    @property
    def designs(self) -> list[NotchDesign]:
        return [d for node in self.nodes for d in node.designs]

    @property
    def design_nodes(self) -> list[int]:
        """The node of every design of :attr:`designs`, in its order."""
        return [node.node_id for node in self.nodes for _ in node.designs]

    def design_and_upload(self, mimo: dict, response: MimoResponse, own_outputs: list[int], loop: MimoResponse) -> None:
        """Every node's notches for the modes it drives and sees, written, read back, enabled on a match.

        ``response`` is the identification's (inputs: every node's torque, in node order), ``mimo`` its summary
        part, ``own_outputs`` every node's own output among the response's outputs. ``loop`` is every node's
        set-point to every node's own output (inputs and outputs in node order), what the notch filters and the
        verification measures again: the width search predicts on it.
        """
        if not self.wanted:
            return
        nc, most = self.cfg.notch, self.cfg.identification.max_resonances
        for node, output in zip(self.nodes, own_outputs, strict=True):
            own = own_response(response, output, node.index)
            node.loop = own_response(loop, node.index, node.index)
            found = node_resonances(own, mimo["modes"], output, node.index, node.node_id, most)
            self.warnings += found.warnings
            self.notes += found.notes
            resonances = found.resonances
            slots = list(range(node.adapter.identity.filter_slots))
            if not resonances or not slots:
                if resonances:
                    self.warnings.append(f"node {node.node_id}: its driver describes no filter slots; no notch")
                continue
            rate = node.adapter.identity.loop_rate_hz
            node.designs = design_notches(resonances, nc, rate, slots, node.loop)
            self.warnings += [f"node {node.node_id}: {d.warning}" for d in node.designs if d.warning]
        if not self.designs:
            self.upload.skipped_reason = "no mode of the fit over every drive may be notched on any node"
            return
        for node in self.nodes:
            if node.designs:
                self.progress.step(f"node {node.node_id}: notch: uploading {len(node.designs)} filter(s)")
                before = len(self.upload.slots)
                upload_designs(node.adapter, node.designs, self.warnings, self.upload)
                for record in self.upload.slots[before:]:
                    record["node"] = node.node_id
                node.uploaded = True
        self.upload.verified_readback = all(record["matches"] for record in self.upload.slots)

    def verify(self, loop_after: MimoResponse) -> VerificationPart:
        """Every notched node's set-point to own output before and after (``loop_after``: the verification run's,
        as ``loop`` of :meth:`design_and_upload`), at its notched modes."""
        nc = self.cfg.notch
        rows: list[dict] = []
        for node in self.nodes:
            if node.designs and node.loop is not None:
                after = own_response(loop_after, node.index, node.index)
                resonances = [d.resonance for d in node.designs]
                rows += node_reductions(node.loop, after, resonances, nc.verify_band_bandwidths, node.node_id)
        for row in rows:
            short = shortfall_warning(row, nc.verify_band_bandwidths, nc.min_reduction_db, f"node {row['node']}: ")
            if short:
                self.warnings.append(short)
        band = min(r["band_reduction_db"] for r in rows)
        at_peak = min(r["reduction_db"] for r in rows)
        return VerificationPart(band, at_peak, nc.verify_band_bandwidths, rows)
