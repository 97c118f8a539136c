"""``hilident export --format klipper | marlin | shaper``: the input shaper the measured resonances favour, in the
forms motion firmwares and controllers take.

The modes come from a ``summary.json``: its ``resonances`` (a run or an identify of one input), else the modes
of its ``mimo`` part, each with its 95 % intervals where the summary has them. Every kind of shaper is designed
for them and scored over those intervals (:func:`hilident.motion.input_shapers.choose_shaper`); the file says
which kind was chosen and why, and how the others scored.

* ``klipper``: the ``[input_shaper]`` section of a Klipper ``printer.cfg`` (``shaper_type_<axis>``,
  ``shaper_freq_<axis>``, ``damping_ratio_<axis>``). Klipper shapes one frequency per axis: the strongest
  resonance is shaped, and the others are named in a comment;
* ``marlin``: the ``M593`` command (Marlin's input shaping is ZV: ``F`` the frequency, ``D`` the damping
  ratio) for the strongest resonance;
* ``shaper``: one JSON file with the chosen shaper's impulse times (s) and amplitudes, for any motion
  controller (several resonances: the convolution of one shaper per mode), and every candidate's score; a run
  with ``[map]`` adds the shaper scheduled by position (``scheduled``: its kind and table) and the fixed one
  for the whole travel (``fixed_for_travel``);
* ``shaper-table``: the scheduled shaper as CSV, ``position_m,frequency_hz,damping_ratio`` (a run with
  ``[map]``): a controller designs the shaper of that kind for the mode at the commanded position, linear
  in between the rows and held beyond the ends. In Klipper, ``SET_INPUT_SHAPER SHAPER_FREQ_X=<f>`` from a
  macro before each move does it by move.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from hilident.errors import DataError
from hilident.motion.input_shapers import MIN_RELATIVE_INTERVAL, ShaperChoice, choose_shaper, score_shaper, zv_shaper
from hilident.pipeline.input_shaper import Mode, measured_modes

__all__ = ["SHAPER_FORMATS", "klipper_section", "marlin_command", "shaper_document", "summary_modes", "write_shaper"]

#: ``--format`` choices this module writes, and their default file names.
SHAPER_FORMATS = {
    "klipper": "input_shaper.cfg",
    "marlin": "input_shaper.gcode",
    "shaper": "input_shaper.json",
    "shaper-table": "input_shaper_schedule.csv",
}


def summary_modes(summary: dict) -> list[Mode]:
    """``(frequency_hz, damping_ratio, frequency_ci95_hz, damping_ci95)`` of every mode ``summary`` reports: its
    ``resonances``, else its ``mimo`` modes, strongest first (:func:`hilident.pipeline.input_shaper.measured_modes`).

    Raises
    ------
    DataError
        The summary reports no resonance and no mode.
    """
    records = list(summary.get("resonances") or []) or list((summary.get("mimo") or {}).get("modes") or [])
    modes = measured_modes(records)
    if not modes:
        raise DataError("the summary reports no resonance and no mode: there is nothing to shape")
    return modes


def _comments(choice: ShaperChoice, modes: list[Mode], source: str, mark: str) -> list[str]:
    lines = [f"{mark} input shaper by hilident from {source}"]
    for f, z, fci, zci in modes:
        spread = f" +- {fci:.3g} Hz" if fci else ""
        dspread = f" +- {zci:.3g}" if zci else ""
        lines.append(f"{mark} mode {f:.3f} Hz{spread}, damping ratio {z:.4f}{dspread}")
    lines.append(f"{mark} {choice.reason}")
    for c in choice.candidates:
        accel = "unlimited" if math.isinf(c.max_accel_mps2) else f"{c.max_accel_mps2:.3g} m/s^2"
        lines.append(
            f"{mark}   {c.kind}: worst residual vibration {100 * c.worst_vibration:.1f} %, "
            f"duration {1e3 * c.shaper.duration_s:.2f} ms, max acceleration {accel}"
        )
    return lines


def klipper_section(summary: dict, source: str, axis: str = "x") -> str:
    """The ``[input_shaper]`` section for the strongest mode of ``summary`` (Klipper shapes one per axis); for a
    run with ``[map]``, the one shaper for the mode's whole range over the travel."""
    travel = (summary.get("input_shaper") or {}).get("over_travel")
    if travel:
        return _klipper_over_travel(travel, source, axis)
    modes = summary_modes(summary)
    first = modes[:1]
    choice = choose_shaper(first)
    lines = _comments(choice, first, source, "#")
    for f, _, _, _ in modes[1:]:
        lines.append(f"# not shaped: the mode at {f:.3f} Hz (Klipper shapes one frequency per axis)")
    f, z, _, _ = first[0]
    lines += [
        "[input_shaper]",
        f"shaper_type_{axis}: {choice.chosen.kind}",
        f"shaper_freq_{axis}: {f:.3f}",
        f"damping_ratio_{axis}: {z:.4f}",
    ]
    return "\n".join(lines) + "\n"


def _klipper_over_travel(travel: dict, source: str, axis: str) -> str:
    """The ``[input_shaper]`` section of the fixed shaper for the mapped range, the schedule named in comments."""
    fixed, scheduled = travel["fixed"], travel["scheduled"]
    lo, hi = travel["frequency_range_hz"]
    lines = [
        f"# input shaper by hilident from {source}",
        f"# the mode moves with position: {lo:.3f}-{hi:.3f} Hz over the mapped travel; the one shaper for all of it:",
        f"# {fixed['reason']}",
        f"# worst residual vibration along the travel {100 * fixed['worst_residual']:.1f} %; a shaper following "
        f"the mode ({scheduled['kind']}) leaves {100 * scheduled['worst_residual']:.1f} %:",
        "# hilident export --format shaper-table writes its position -> frequency table, for a macro that sends",
        f"# SET_INPUT_SHAPER SHAPER_FREQ_{axis.upper()}=<f> before each move",
        "[input_shaper]",
        f"shaper_type_{axis}: {fixed['kind']}",
        f"shaper_freq_{axis}: {fixed['frequency_hz']:.3f}",
        f"damping_ratio_{axis}: {fixed['damping_ratio']:.4f}",
    ]
    return "\n".join(lines) + "\n"


def marlin_command(summary: dict, source: str, axis: str = "x") -> str:
    """``M593`` (ZV input shaping) for the strongest mode of ``summary``, with its residual vibration noted."""
    modes = summary_modes(summary)
    f, z, fci, _ = modes[0]
    zv = zv_shaper(f, z)
    band = max(fci or 0.0, MIN_RELATIVE_INTERVAL * f)
    score = score_shaper(zv, (f - band, f + band), (z,))
    lines = [
        f"; input shaper by hilident from {source}: ZV (Marlin's M593) at the strongest mode",
        f"; mode {f:.3f} Hz, damping ratio {z:.4f}; worst residual vibration over {f - band:.2f}-{f + band:.2f} Hz: "
        f"{100 * score.worst_vibration:.1f} %",
        *[f"; not shaped: the mode at {m[0]:.3f} Hz" for m in modes[1:]],
        f"M593 {axis.upper()} F{f:.2f} D{z:.4f}",
    ]
    return "\n".join(lines) + "\n"


def shaper_document(summary: dict, source: str) -> dict:
    """The chosen shaper for every mode of ``summary`` (the convolution of one per mode) and every candidate."""
    modes = summary_modes(summary)
    choice = choose_shaper(modes)
    return {
        "format": "hilident-input-shaper",
        "source": source,
        "modes": [
            {"frequency_hz": f, "damping_ratio": z, "frequency_ci95_hz": fci, "damping_ci95": zci}
            for f, z, fci, zci in modes
        ],
        "chosen": choice.chosen.kind,
        "reason": choice.reason,
        "target_vibration": choice.target_vibration,
        "times_s": choice.shaper.times_s.tolist(),
        "amplitudes": choice.shaper.amplitudes.tolist(),
        "candidates": [c.as_dict() for c in choice.candidates],
        "units": {"times_s": "s", "smoothing_m": "m", "max_accel_mps2": "m/s^2", "worst_vibration": "fraction"},
        **_over_travel(summary),
    }


def _over_travel(summary: dict) -> dict:
    """``scheduled`` and ``fixed_for_travel`` of a run with ``[map]`` (empty otherwise)."""
    travel = (summary.get("input_shaper") or {}).get("over_travel")
    if not travel:
        return {}
    scheduled = travel["scheduled"]
    return {
        "scheduled": {
            "kind": scheduled["kind"],
            "interpolation": "linear in position between the rows, held beyond the ends",
            "table": scheduled["table"],
            "worst_residual": scheduled["worst_residual"],
            "max_accel_mps2": scheduled["max_accel_mps2"],
        },
        "fixed_for_travel": travel["fixed"],
    }


def schedule_table(summary: dict, source: str) -> str:
    """The scheduled shaper's table as CSV (``#`` comment lines first: its kind and where it came from).

    Raises
    ------
    DataError
        The summary has no scheduled shaper (a run without ``[map]``).
    """
    scheduled = _over_travel(summary).get("scheduled")
    if scheduled is None:
        raise DataError(
            f"{source} has no shaper scheduled by position (input_shaper.over_travel): it comes from a run with [map]"
        )
    lines = [
        f"# input shaper scheduled by position, by hilident from {source}",
        f"# kind {scheduled['kind']}: designed for the mode at the commanded position, {scheduled['interpolation']}",
        "position_m,frequency_hz,damping_ratio",
        *(f"{r['position_m']:.6g},{r['frequency_hz']:.6g},{r['damping_ratio']:.6g}" for r in scheduled["table"]),
    ]
    return "\n".join(lines) + "\n"


def write_shaper(fmt: str, summary: dict, source: str, target: Path, axis: str = "x") -> None:
    """Write ``fmt`` (a key of :data:`SHAPER_FORMATS`) for ``summary`` to ``target``."""
    if fmt == "klipper":
        target.write_text(klipper_section(summary, source, axis), encoding="utf-8")
    elif fmt == "marlin":
        target.write_text(marlin_command(summary, source, axis), encoding="utf-8")
    elif fmt == "shaper-table":
        target.write_text(schedule_table(summary, source), encoding="utf-8")
    else:
        target.write_text(json.dumps(shaper_document(summary, source), indent=2) + "\n", encoding="utf-8")
