"""The notches of several drives of one axis: each drive notches the modes of the fit over every drive that it
drives and sees.

A drive's notch filters the torque that drive commands, so what it must take down is a mode as that drive drives
and sees it: in the element of the response matrix from its torque to its own output (its own encoder), read at
the lines its own column of a zippered multisine excited (:func:`own_response`). The modes themselves come from
the fit over every input and output at once (``summary.json["mimo"]["modes"]``: poles stable over the model
orders, their 95 % intervals, residues): one estimate of each mode from every drive's record, better than any one
element's peak, which holds the other modes and the anti-resonances between them. A drive gets a notch at a mode
when the mode's own term is at least :data:`~hilident.pipeline.output_modes.SEEN_FRACTION` of its element's
response there (:func:`~hilident.pipeline.output_modes.own_term`, the rule by which an output "sees" a mode), and
when the mode's frequency is known as well as a run of one drive asks
(:func:`~hilident.pipeline.eligibility.interval_eligibility`); the stabilisation over the orders stands for the
local fit a run of one drive checks.

The verification repeats the excitation with the notches in and compares every drive's own element before and
after at its modes (:func:`node_reductions`), as a run of one drive compares its plant.

Pure numerics on responses and summary parts: no device.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from hilident.ident.frequency import FrequencyResponse
from hilident.ident.mimo import MimoResponse
from hilident.ident.resonance import Resonance
from hilident.pipeline.eligibility import interval_eligibility
from hilident.pipeline.output_modes import SEEN_FRACTION, own_term
from hilident.pipeline.verification import band_floor_db, floor_limited, peak_reductions

__all__ = ["NodeResonances", "coherence_of_spread", "node_reductions", "node_resonances", "own_response"]


def own_response(response: MimoResponse, output: int, node: int) -> FrequencyResponse:
    """Drive ``node``'s own element (its torque to output ``output``) at the lines its input excited.

    A zippered estimate interpolates every element between its input's own lines; a resonance is searched and a
    notch verified on measured lines only. Its coherence is the one the element's own spread over the periods
    implies (:func:`coherence_of_spread`), so the verification's noise floor
    (:func:`~hilident.pipeline.verification.band_floor_db`) is the element's own; where the spread is not known
    (a Welch estimate), the output's multiple coherence.
    """
    element = response.element(output, node)
    spread = coherence_of_spread(element.response, response.std[:, output, node], element.n_averages, element.method)
    coherence = np.where(np.isfinite(spread), spread, element.coherence)
    lines = (
        np.ones(element.frequency_hz.size, dtype=bool)
        if response.measured is None
        else np.asarray(response.measured[:, node], dtype=bool)
    )
    return FrequencyResponse(
        frequency_hz=element.frequency_hz[lines],
        response=element.response[lines],
        coherence=coherence[lines],
        n_averages=element.n_averages,
        method=element.method,
    )


def coherence_of_spread(response: np.ndarray, std: np.ndarray, averages: int, method: str) -> np.ndarray:
    """The coherence an estimate's spread implies: the ``g`` for which
    :func:`~hilident.ident.frfquality.estimate_error_std` (``|H| sqrt((1 - g) / (g d))``, ``d`` the periods less
    one for a periodic estimate, else the averages) equals the estimate's complex error, ``sqrt(2)`` times the
    standard deviation ``std`` of each part; NaN where the spread is unknown or ``d`` is 0."""
    dof = averages - 1 if method == "periodic" else averages
    error2 = 2.0 * np.asarray(std, dtype=float) ** 2
    power = np.abs(response) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        # |H|^2 / (|H|^2 + d e^2): no overflow where a notch took the response far below its error
        g = np.maximum(power / (power + dof * error2), np.finfo(float).tiny)
    return np.where(np.isfinite(g) & (dof >= 1), g, np.nan)


@dataclasses.dataclass
class NodeResonances:
    """The modes one drive's notches are designed for, and what the user should know.

    Attributes
    ----------
    resonances : list of Resonance
        The joint modes the drive drives and sees, notchable, as resonances of its own element (peak, coherence).
    warnings : list of str
        Modes the drive sees that are refused a notch, with the reason (the node named).
    notes : list of str
        Modes the drive neither drives nor sees enough for a notch.
    """

    resonances: list[Resonance]
    warnings: list[str]
    notes: list[str]


def node_resonances(
    own: FrequencyResponse, modes: list[dict], output: int, node: int, node_id: int, max_count: int
) -> NodeResonances:
    """The joint modes drive ``node`` may notch, each as a resonance of its own element: of the modes it drives
    and sees, the ``max_count`` largest in its own response, those whose frequency is known well enough.

    Parameters
    ----------
    own : FrequencyResponse
        :func:`own_response` of the node.
    modes : list of dict
        ``summary.json["mimo"]["modes"]``: ``frequency_hz``, ``damping_ratio``, ``pole_rad_per_s``,
        ``residue_real`` and ``residue_imag`` (output by input) and, where known, ``frequency_ci95_hz`` and
        ``damping_ci95``.
    output, node : int
        The node's own output and its input, as indices of the fit's outputs and inputs.
    node_id : int
        The node id, named in the messages.
    max_count : int
        ``[identification] max_resonances``: most modes per drive.
    """
    keep: list[Resonance] = []
    warnings: list[str] = []
    notes: list[str] = []
    if not len(own):
        return NodeResonances(keep, warnings, notes)
    seen: list[Resonance] = []
    for mode in modes:
        line = int(np.argmin(np.abs(own.frequency_hz - mode["frequency_hz"])))
        measured = float(np.abs(own.response[line]))
        share = own_term(mode, output, node) / measured if measured > 0 else 0.0
        f = float(mode["frequency_hz"])
        if not share >= SEEN_FRACTION:
            notes.append(
                f"node {node_id}: mode at {f:.5g} Hz: its own term is {100 * share:.0f} % of the drive's own response "
                f"there (at least {100 * SEEN_FRACTION:g} % for a notch): the drive neither drives nor sees it much"
            )
            continue
        res = Resonance(
            frequency_hz=f,
            damping_ratio=float(mode["damping_ratio"]),
            peak_magnitude_db=float(20.0 * np.log10(measured)),
            coherence=float(own.coherence[line]) if own.coherence is not None else float("nan"),
            method="fit",
            frequency_ci95_hz=_known(mode.get("frequency_ci95_hz")),
            damping_ci95=_known(mode.get("damping_ci95")),
        )
        seen.append(res)
    seen.sort(key=lambda r: -r.peak_magnitude_db)
    for res in seen[max_count:]:
        notes.append(
            f"node {node_id}: mode at {res.frequency_hz:.5g} Hz: beyond identification.max_resonances = {max_count} "
            "(the largest in the drive's own response are notched)"
        )
    for res in seen[:max_count]:
        verdict = interval_eligibility(res)
        if verdict["notchable"]:
            keep.append(res)
        else:
            warnings.append(f"node {node_id}: no notch at {res.frequency_hz:.4g} Hz: {verdict['reason']}")
    return NodeResonances(keep, warnings, notes)


def _known(value) -> float:
    """A summary figure, NaN where it is missing (null)."""
    return float(value) if value is not None else float("nan")


def node_reductions(
    before: FrequencyResponse, after: FrequencyResponse, resonances: list[Resonance], bandwidths: float, node: int
) -> list[dict]:
    """:func:`~hilident.pipeline.verification.peak_reductions` of one drive's own element, each row with its
    ``node``, the record's ``floor_db`` and whether the figure is ``floor_limited``."""
    lo, hi = after.frequency_hz[0], after.frequency_hz[-1]
    if before.frequency_hz[0] < lo or before.frequency_hz[-1] > hi:  # one run read periodically, one by Welch
        within = (before.frequency_hz >= lo) & (before.frequency_hz <= hi)
        before = FrequencyResponse(
            before.frequency_hz[within],
            before.response[within],
            None if before.coherence is None else before.coherence[within],
            before.n_averages,
            before.method,
        )
    rows = peak_reductions(before, after, resonances, bandwidths)
    for row, res in zip(rows, resonances, strict=True):
        floor = band_floor_db(before, after, res, bandwidths)
        row.update(node=node, floor_db=floor, floor_limited=floor_limited(row["band_reduction_db"], floor))
    return rows
