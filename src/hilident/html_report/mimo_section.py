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
    body = key_values(pairs) + _modes(_dicts(part, "modes"), names) + _mac(part.get("mode_mac") or [])
    notes = "".join(note(str(n)) for n in [*(part.get("warnings") or []), *(part.get("modal_notes") or [])])
    return section("mimo", TITLE, body + notes)


def _dicts(part: dict, key: str) -> list[dict]:
    return [x for x in part.get(key) or [] if isinstance(x, dict)]


def _modes(modes: list[dict], outputs: list[str]) -> str:
    if not modes:
        return note("No mode was stable over the highest model orders.")
    rows = []
    for k, m in enumerate(modes, start=1):
        lo, hi = (m.get("frequency_range_hz") or [None, None])[:2]
        shape = m.get("shape_magnitude") or []
        rows.append(
            [
                str(k),
                num(m.get("frequency_hz"), "Hz", 5),
                num(_percent(m.get("damping_ratio")), "%", 3),
                f"{num(lo, 'Hz', 5)} to {num(hi, 'Hz', 5)}",
                num(m.get("stable_orders")),
                ", ".join(f"{esc(n)} {num(v, '', 2)}" for n, v in zip(outputs, shape, strict=False)) or MISSING,
                ", ".join(num(v, "", 2) for v in m.get("participation_magnitude") or []) or MISSING,
            ]
        )
    header = ["mode", "frequency", "damping", "over the orders", "stable orders", "shape |output|", "participation"]
    return table(header, rows, "Modes from all outputs and inputs at once (polyreference LSCF, LSFD shapes)")


def _percent(value: Any) -> float | None:
    return 100.0 * value if isinstance(value, (int, float)) else None


def _mac(matrix: list) -> str:
    if len(matrix) < 2:
        return ""
    rows = [[str(k), *(num(v, "", 2) for v in row)] for k, row in enumerate(matrix, start=1)]
    return table(["MAC", *(str(k) for k in range(1, len(matrix) + 1))], rows, "MAC between the modes' shapes")
