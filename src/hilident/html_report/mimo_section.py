"""The report's section on a record of several inputs and outputs: ``summary.json["mimo"]``.

``hilident identify`` with ``[data] inputs`` and ``outputs`` (:mod:`hilident.pipeline.mimo_identify`): how
well all inputs together explain each output, whether the inputs could be told apart, the modes found from
all outputs and inputs at once with their shapes, and the MAC between those shapes.
"""

from __future__ import annotations

from typing import Any

from hilident.html_report.gather import ReportInputs
from hilident.html_report.markup import MISSING, esc, key_values, note, num, section, table

__all__ = ["mimo"]

TITLE = "Several inputs and outputs"
#: The stabilisation diagram ``hilident identify`` draws (:mod:`hilident.plots.stabilisation`).
STABILISATION_PNG = "stabilisation.png"


def mimo(inputs: ReportInputs) -> str:
    """``summary.json["mimo"]``, or a note that the record had one input."""
    part = inputs.summary.get("mimo")
    if not isinstance(part, dict):
        return section("mimo", TITLE, note("One input: no multi-input estimate ([data] inputs, outputs)."))
    outputs = [o for o in part.get("outputs") or [] if isinstance(o, dict)]
    names = [str(o.get("column", "?")) for o in outputs]
    labels = [f"{n} [{o.get('unit')}]" if o.get("unit") else n for n, o in zip(names, outputs, strict=True)]
    coherence = zip(names, part.get("multiple_coherence_median") or [], strict=False)
    band = part.get("band_hz") or [None, None]
    pairs = [
        ("inputs", esc(", ".join(str(i.get("column", "?")) for i in _dicts(part, "inputs")))),
        ("outputs", esc(", ".join(labels))),
        ("band", f"{num(band[0], 'Hz')} to {num(band[-1], 'Hz')}, lines every {num(part.get('resolution_hz'), 'Hz')}"),
        ("segments averaged", num(part.get("n_averages"))),
        ("multiple coherence, median", ", ".join(f"{esc(n)} {num(c, '', 3)}" for n, c in coherence)),
        ("input condition, median", num(part.get("input_condition_median"), "", 3) + " (1: independent inputs)"),
        ("mode indicator peaks", ", ".join(num(p.get("frequency_hz"), "Hz") for p in _dicts(part, "indicator_peaks"))),
    ]
    modes = _dicts(part, "modes")
    body = key_values(pairs) + _modes(modes) + _shapes(modes, names) + _mac(part.get("mode_mac") or [])
    body += _figure(inputs)
    notes = "".join(note(str(n)) for n in [*(part.get("warnings") or []), *(part.get("modal_notes") or [])])
    return section("mimo", TITLE, body + notes)


def _dicts(part: dict, key: str) -> list[dict]:
    return [x for x in part.get(key) or [] if isinstance(x, dict)]


def _modes(modes: list[dict]) -> str:
    """One row per mode: frequency and damping with their 95 % intervals, their spread over the orders."""
    if not modes:
        return note("No mode was stable over the highest model orders.")
    rows = []
    for k, m in enumerate(modes, start=1):
        lo, hi = (m.get("frequency_range_hz") or [None, None])[:2]
        rows.append(
            [
                str(k),
                num(m.get("frequency_hz"), "Hz", 5),
                _plus_minus(m.get("frequency_ci95_hz"), "Hz"),
                num(_percent(m.get("damping_ratio")), "%", 3),
                _plus_minus(_percent(m.get("damping_ci95")), "%"),
                f"{num(lo, 'Hz', 5)} to {num(hi, 'Hz', 5)}",
                num(m.get("stable_orders")),
                ", ".join(num(v, "", 2) for v in m.get("participation_magnitude") or []) or MISSING,
            ]
        )
    header = ["mode", "frequency", "95 %", "damping", "95 %", "over the orders", "stable orders", "participation"]
    return table(header, rows, "Modes from all outputs and inputs at once (polyreference LSCF, LSFD shapes)")


def _plus_minus(half_width: Any, unit: str) -> str:
    """``± half_width unit``, or a dash when the interval could not be estimated."""
    text = num(half_width, unit, 2)
    return MISSING if text == MISSING else f"± {text}"


def _shapes(modes: list[dict], outputs: list[str]) -> str:
    """The mode shapes: one row per output, one column per mode, magnitude (largest 1) and phase."""
    if not modes:
        return ""
    header = ["output", *(f"mode {k} ({num(m.get('frequency_hz'), 'Hz', 4)})" for k, m in enumerate(modes, 1))]
    rows = []
    for j, name in enumerate(outputs):
        cells = [esc(name)]
        for m in modes:
            magnitude, phase = _entry(m.get("shape_magnitude"), j), _entry(m.get("shape_phase_deg"), j)
            phase = phase + 0.0 if isinstance(phase, float) else phase  # -0.0 shows as 0
            cells.append(MISSING if magnitude is None else f"{num(magnitude, '', 3)} ∠ {num(phase, 'deg', 3)}")
        rows.append(cells)
    return table(header, rows, "Mode shapes over the outputs: magnitude (largest 1) and phase")


def _entry(values: Any, index: int) -> Any:
    return values[index] if isinstance(values, list) and index < len(values) else None


def _figure(inputs: ReportInputs) -> str:
    """Where the stabilisation diagram is, when the folder holds it."""
    if not any(name == STABILISATION_PNG for name, _ in inputs.images):
        return ""
    return (
        f'<p>The stabilisation diagram ({esc(STABILISATION_PNG)}, under <a href="#plots">Plots</a>): every pole of '
        "every model order by how it compares with the order below, the first singular value of H, the orders the "
        "modes were selected over and the modes.</p>"
    )


def _percent(value: Any) -> float | None:
    return 100.0 * value if isinstance(value, (int, float)) else None


def _mac(matrix: list) -> str:
    if len(matrix) < 2:
        return ""
    rows = [[str(k), *(num(v, "", 2) for v in row)] for k, row in enumerate(matrix, start=1)]
    return table(["MAC", *(str(k) for k in range(1, len(matrix) + 1))], rows, "MAC between the modes' shapes")
