"""The modes every recorded output of one axis sees, and the notch taken from them (``identification.outputs``).

A motor encoder sees a resonance as a peak beside an antiresonance; a load sensor (``load_position_m``, an
accelerometer on the tool) sees the same pole without that zero, and often more strongly. Estimated against
the same net torque from the same periods, the outputs have one set of poles: a polyreference fit over all of
them (:func:`hilident.ident.mimo.modal_analysis`, one input) gives each mode once, with its shape over the
outputs. A mode is *seen* by an output when the mode alone accounts for most of that output's response at the
mode's frequency (:data:`SEEN_FRACTION`); the mode every output sees is the axis's own, and a notch designed for
a resonance of the motor's response takes its centre and damping from it (:func:`notch_resonances`).

What this adds to ``summary.json``: a ``mimo`` part with the layout ``hilident identify`` gives a record of
several outputs (:mod:`hilident.pipeline.mimo_identify`), one input (the net torque), and per mode ``seen_by``
(the outputs that see it); ``notch_modes`` says which resonance took which mode.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from hilident.ident.frequency import FrequencyResponse
from hilident.ident.frfquality import frf_uncertainty
from hilident.ident.mimo import MimoResponse
from hilident.ident.resonance import Resonance
from hilident.pipeline.mimo_identify import Groups, mode_indicator_peaks
from hilident.pipeline.mimo_identify import _median as median
from hilident.pipeline.mimo_identify import _modal_part as modal_part

__all__ = ["JointModes", "SEEN_FRACTION", "joint_output_modes", "notch_resonances", "own_term"]

#: A mode is seen by an output when its own term, ``|R_j| / (zeta w_n)`` at its frequency, is at least this
#: share of that output's measured response there.
SEEN_FRACTION = 0.3


@dataclass
class JointModes:
    """The outputs' joint modal estimate.

    Attributes
    ----------
    part : dict
        ``summary.json["mimo"]``.
    frequency_hz, damping_ratio : list of float
        Each mode's natural frequency (Hz) and damping ratio.
    seen_by : list of list of str
        Per mode, the outputs that see it (:data:`SEEN_FRACTION`).
    outputs : list of str
        Every output, the plant's first.
    response : MimoResponse or None
        The outputs' responses to the net torque the modes were fitted to (for the stabilisation diagram).
    """

    part: dict
    frequency_hz: list[float] = field(default_factory=list)
    damping_ratio: list[float] = field(default_factory=list)
    seen_by: list[list[str]] = field(default_factory=list)
    outputs: list[str] = field(default_factory=list)
    response: MimoResponse | None = None

    def common(self) -> list[int]:
        """Indices of the modes every output sees."""
        return [k for k, seen in enumerate(self.seen_by) if len(seen) == len(self.outputs)]


def _stack(responses: dict[str, FrequencyResponse]) -> MimoResponse:
    """One input, the outputs in order: the response matrix with each element's spread from its coherence."""
    first = next(iter(responses.values()))
    h = np.stack([r.response for r in responses.values()], axis=1)[:, :, None]
    coherence = np.stack([np.clip(r.coherence, 0.0, 1.0) for r in responses.values()], axis=1)
    # one average says nothing of the error (its coherence is 1): no spread, and the fit weighs every line alike
    relative = np.stack(
        [
            frf_uncertainty(r).magnitude_rel_std if r.n_averages >= 2 else np.full(r.frequency_hz.size, np.nan)
            for r in responses.values()
        ],
        axis=1,
    )
    return MimoResponse(
        frequency_hz=first.frequency_hz,
        response=h,
        multiple_coherence=coherence,
        std=(np.abs(h[:, :, 0]) * relative)[:, :, None],
        input_condition=np.ones(first.frequency_hz.size),
        n_averages=first.n_averages,
        method=first.method,
    )


def own_term(mode: dict, output: int, input_: int = 0) -> float:
    """The magnitude of a mode's own term in element (``output``, ``input_``) at its damped frequency,
    ``|R / (j w_d - lambda)| = |R| / sigma``, in the element's unit (a mode of ``summary.json["mimo"]["modes"]``)."""
    sigma = -float(mode["pole_rad_per_s"][0])
    residue = complex(mode["residue_real"][output][input_], mode["residue_imag"][output][input_])
    return abs(residue) / max(sigma, np.finfo(float).tiny)


def _seen_by(part: dict, frf: MimoResponse, names: list[str]) -> list[list[str]]:
    """Per mode of ``part["modes"]``, the outputs whose response at the mode's frequency is mostly its own term
    (:func:`own_term`, at least :data:`SEEN_FRACTION` of it)."""
    out = []
    for mode in part["modes"]:
        line = int(np.argmin(np.abs(frf.frequency_hz - mode["frequency_hz"])))
        measured = np.abs(frf.response[line, :, 0])
        seen = [j for j, b in enumerate(measured) if b > 0 and own_term(mode, j) >= SEEN_FRACTION * b]
        out.append([names[j] for j in seen])
    return out


def joint_output_modes(
    responses: dict[str, FrequencyResponse],
    band_hz: tuple[float, float],
    units: dict[str, str] | None = None,
    groups: list[dict[str, FrequencyResponse]] | None = None,
) -> JointModes | None:
    """The modes of the outputs ``responses`` (name to net-torque response, the plant's output first).

    Parameters
    ----------
    responses : dict of str to FrequencyResponse
        At least two, on one frequency grid (one record, one estimator).
    band_hz : (float, float)
        The band searched for resonances, Hz.
    units : dict of str to str, optional
        Each output channel's unit, as recorded (reported; the responses are per N·m of torque).
    groups : list of dict of str to FrequencyResponse, optional
        The same responses estimated on disjoint blocks of the record (:func:`hilident.pipeline.mimo_identify.
        interval_blocks`): the modes' 95 % intervals (:func:`hilident.ident.mimo.modal_intervals`). None or
        empty: no intervals, and a note says why.

    Returns
    -------
    JointModes or None
        None for fewer than two outputs.
    """
    if len(responses) < 2:
        return None
    names = list(responses)
    frf = _stack(responses)
    in_band = (frf.frequency_hz >= band_hz[0]) & (frf.frequency_hz <= band_hz[1])
    part: dict = {
        "inputs": [{"column": "torque_nm", "scale": 1.0}],
        "outputs": [{"column": n, "scale": 1.0, "unit": (units or {}).get(n, "")} for n in names],
        "method": frf.method,
        "n_averages": frf.n_averages,
        "resolution_hz": float(np.min(np.diff(frf.frequency_hz))) if len(frf) > 1 else 0.0,
        "band_hz": [float(band_hz[0]), float(band_hz[1])],
        "multiple_coherence_median": [median(frf.multiple_coherence[in_band, j]) for j in range(len(names))],
        "input_condition_median": 1.0,
        "elements": [],
        "indicator_peaks": mode_indicator_peaks(frf, in_band),
        "warnings": [],
    }
    found = Groups([_stack({n: g[n] for n in names}) for g in groups]) if groups else Groups([])
    part.update(modal_part(frf, band_hz, found))
    seen = _seen_by(part, frf, names)
    for mode, s in zip(part["modes"], seen, strict=True):
        mode["seen_by"] = s
    return JointModes(
        part,
        frequency_hz=[m["frequency_hz"] for m in part["modes"]],
        damping_ratio=[m["damping_ratio"] for m in part["modes"]],
        seen_by=seen,
        outputs=names,
        response=frf,
    )


def notch_resonances(resonances: list[Resonance], joint: JointModes | None) -> tuple[list[Resonance], list[str]]:
    """Each resonance with the frequency and damping of the mode every output sees within its half-power band.

    Returns the resonances (those without such a mode unchanged) and one note per resonance saying which mode
    it took or that no output but the plant's sees it. ``joint.part["notch_modes"]`` records the pairs.
    """
    if joint is None or not joint.frequency_hz:
        return resonances, []
    common = joint.common()
    out, notes, pairs = [], [], []
    for res in resonances:
        half_band = max(res.frequency_hz * res.damping_ratio, joint.part["resolution_hz"])
        near = [k for k in common if abs(joint.frequency_hz[k] - res.frequency_hz) <= half_band]
        if not near:
            out.append(res)
            notes.append(
                f"resonance at {res.frequency_hz:.4g} Hz: no mode within its half-power band is seen by every "
                f"output ({', '.join(joint.outputs)}); its notch keeps the plant output's estimate"
            )
            continue
        k = min(near, key=lambda i: abs(joint.frequency_hz[i] - res.frequency_hz))
        f, zeta = joint.frequency_hz[k], joint.damping_ratio[k]
        out.append(dataclasses.replace(res, frequency_hz=f, damping_ratio=zeta))
        pairs.append({"resonance_hz": res.frequency_hz, "mode": k, "frequency_hz": f, "damping_ratio": zeta})
        notes.append(
            f"resonance at {res.frequency_hz:.5g} Hz (zeta {res.damping_ratio:.3g}): its notch is designed for "
            f"the mode every output sees, {f:.5g} Hz (zeta {zeta:.3g}), fitted over {', '.join(joint.outputs)}"
        )
    joint.part["notch_modes"] = pairs
    taken = {p["mode"] for p in pairs}
    notes += [
        f"mode at {joint.frequency_hz[k]:.5g} Hz (zeta {joint.damping_ratio[k]:.3g}) is seen by every output but "
        "no resonance of the plant output was notched there"
        for k in common
        if k not in taken
    ]
    return out, notes
