"""The sections of ``report.html``, one function each: :class:`ReportInputs` in, HTML out.

Pure: no files are read here (:mod:`hilident.html_report.gather` did that).
Every section is always there; one the command did not produce says so, so a
reader (and a test) finds the same headings in every report. A summary key
that is missing or of an unexpected type leaves its figure as "—".
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any
from urllib.parse import quote

from hilident.html_report.advice import group_warnings
from hilident.html_report.gather import ReportInputs
from hilident.html_report.loop_section import loop
from hilident.html_report.markup import MISSING, esc, figure, key_values, note, num, pm, section, table
from hilident.html_report.mimo_section import mimo
from hilident.io.summary import designed_and_stored

__all__ = ["SECTIONS", "title_of"]


# --------------------------------------------------------------------------- helpers


def _dict(value: Any) -> dict:
    return value if isinstance(value, dict) else {}


def _list(value: Any) -> list:
    return [v for v in value if isinstance(v, dict)] if isinstance(value, list) else []


def _text(value: Any) -> str:
    return MISSING if value in (None, "") else esc(value)


def _yes_no(value: Any) -> str:
    return MISSING if value is None else ("yes" if value else "no")


def _units(section_: dict, defaults: dict[str, str]) -> dict[str, str]:
    """Units of a section's parameters: the summary's own ``units`` table when it has one, else ``defaults``."""
    own = _dict(section_.get("units"))
    return {**defaults, **{k: str(v) for k, v in own.items()}}


def _magnitude_reference(inputs: ReportInputs) -> str:
    """``dB re 1 (m/s)/(N*m)`` when the data say the output and input units, else ``dB``."""
    if inputs.response_units is None:
        return "dB"
    out, into = inputs.response_units
    return f"dB re 1 ({out})/({into})"


def title_of(inputs: ReportInputs) -> str:
    """The page title: the command and what it ran on."""
    s = inputs.summary
    subject = s.get("config") if inputs.kind != "identify" else _dict(s.get("data")).get("file", s.get("config"))
    return f"hilident {inputs.kind}: {subject or inputs.folder.name}"


# --------------------------------------------------------------------------- what was run on what


def _device_pairs(inputs: ReportInputs) -> list[tuple[str, str]]:
    dev = {**_dict(inputs.first_attrs("device")), **_dict(inputs.summary.get("device"))}
    names = (("driver", "driver"), ("name", "device"), ("firmware", "firmware"), ("port", "port"))
    pairs = [(label, _text(dev[key])) for key, label in names if dev.get(key) not in (None, "")]
    if "emulated" in dev:
        pairs.append(("emulated twin", _yes_no(dev["emulated"])))
    if dev.get("loop_rate_hz") is not None:
        pairs.append(("loop rate", num(dev["loop_rate_hz"], "Hz")))
    if dev.get("filter_slots") is not None:
        pairs.append(("filter slots", num(dev["filter_slots"])))
    return pairs


def _excitation_pairs(exc: dict) -> list[tuple[str, str]]:
    if not exc:
        return []
    amp = num(exc.get("amplitude"), str(exc.get("unit", "")), 3)
    auto = " (chosen automatically)" if exc.get("amplitude_setting") == "auto" else ""
    loop = ", closed loop" if exc.get("closed_loop") else ""
    pairs = [("excitation", esc(f"{exc.get('kind')} into {exc.get('mode')}{loop}, amplitude ") + amp + esc(auto))]
    chosen = _dict(exc.get("auto"))
    if chosen.get("reason"):
        pairs.append(("amplitude chosen because", _text(chosen["reason"])))
    return pairs


def _connect_pairs(connect: dict) -> list[tuple[str, str]]:
    if not connect:
        return []
    faults = ", ".join(str(f) for f in connect.get("faults") or []) or "none"
    cleared = " (cleared)" if connect.get("faults_cleared") else ""
    pairs = [
        (
            "at connect",
            esc(
                f"found {connect.get('found_state', '?')}, {connect.get('discarded_frames', 0)} "
                f"stale frame(s) discarded, latched faults: {faults}{cleared}"
            ),
        )
    ]
    if connect.get("device_net"):
        pairs.append(("device-side net", _text(connect["device_net"])))
    return pairs


def run_on_what(inputs: ReportInputs) -> str:
    s = inputs.summary
    pairs: list[tuple[str, str]] = [
        ("command", esc(f"hilident {inputs.kind}")),
        ("configuration", _text(s.get("config"))),
    ]
    if inputs.kind == "identify":
        data = _dict(s.get("data"))
        pairs += [
            ("data file", _text(data.get("file"))),
            ("samples used", f"{num(data.get('used_rows', data.get('samples')))} of {num(data.get('rows'))}"),
            ("sample rate", num(data.get("sample_rate_hz"), "Hz")),
        ]
        if data.get("recorded_experiment"):
            pairs.append(("recorded experiment", esc(f"{data['recorded_experiment']} ({data.get('recorded_mode')})")))
    if inputs.kind == "upload":
        source = _dict(s.get("source"))
        pairs.append(("notches from", esc(f"{source.get('summary', MISSING)} ({source.get('kind', '?')})")))
    pairs += _device_pairs(inputs) or [("device", esc("not recorded in this folder"))]
    if s.get("sample_rate_hz") is not None:
        pairs.append(("sample rate", num(s["sample_rate_hz"], "Hz")))
    pairs += _excitation_pairs(_dict(s.get("excitation"))) + _connect_pairs(_dict(s.get("connect")))
    recorded = inputs.first_attrs("created_utc")
    pairs.append(
        ("date", esc(f"recorded {recorded}; " if recorded else "") + esc(f"summary written {inputs.summary_time_utc}"))
    )
    if s.get("elapsed_s") is not None:
        pairs.append(("duration of the command", num(s["elapsed_s"], "s", 3)))
    pairs.append(("versions", _versions(inputs)))
    body = key_values(pairs)
    if inputs.config_text:
        body += (
            f'<details class="config screen-only"><summary>Configuration ({esc(inputs.config_origin)})</summary>'
            f"<pre>{esc(inputs.config_text)}</pre></details>"
            f'<div class="print-only"><h3>Configuration ({esc(inputs.config_origin)})</h3>'
            f"<pre>{esc(inputs.config_text)}</pre></div>"
        )
    else:
        body += note(
            "The configuration text was not found (neither the file the summary names nor a recording "
            "holding it is here)."
        )
    return section("run", "What was run on what", body)


def _versions(inputs: ReportInputs) -> str:
    recorded = _dict(inputs.first_attrs("versions"))
    parts = []
    if recorded:
        keys = [k for k in ("hilident", "numpy", "scipy", "python") if k in recorded]
        parts.append("recorded with " + ", ".join(f"{k} {recorded[k]}" for k in keys))
    if inputs.summary.get("hilident_version"):
        parts.append(f"analysed by hilident {inputs.summary['hilident_version']}")
    rv = inputs.report_versions
    if rv:
        parts.append("report written with " + ", ".join(f"{k} {v}" for k, v in rv.items()))
    return esc("; ".join(parts)) if parts else MISSING


# --------------------------------------------------------------------------- headline


def _failure(s: dict) -> str:
    if not s.get("failed_step"):
        return ""
    return (
        f'<p class="failed"><strong>The step &ldquo;{esc(s["failed_step"])}&rdquo; failed:</strong> '
        f"{esc(s.get('error', ''))}. The figures below are those of the steps before it.</p>"
    )


def headline(inputs: ReportInputs) -> str:
    s = inputs.summary
    rows: list[tuple[str, str]] = []
    ref = _magnitude_reference(inputs)
    for r in _list(s.get("resonances")):
        rows.append(
            (
                f"resonance at {num(r.get('frequency_hz'), 'Hz')}",
                f"{pm(r.get('frequency_hz'), r.get('frequency_ci95_hz'), 'Hz', 6)} (95 %), damping ratio "
                f"{pm(r.get('damping_ratio'), r.get('damping_ci95'), '', 3)}, peak "
                f"{num(r.get('peak_magnitude_db'), ref, 4)}",
            )
        )
    modes = _list(_dict(s.get("mimo")).get("modes"))
    if "resonances" in s and not _list(s.get("resonances")) and modes:  # a run of several nodes: the joint modes
        found = ", ".join(
            f"{num(m.get('frequency_hz'), 'Hz')} (damping {num(m.get('damping_ratio'), '', 3)})" for m in modes
        )
        rows.append(("modes of all inputs and outputs", found))
    elif "resonances" in s and not _list(s.get("resonances")):
        rows.append(("resonances", esc("none the evidence supports")))
    fr = _dict(s.get("friction"))
    if fr:
        rows.append(("friction", _friction_line(fr)))
    for design, slot in designed_and_stored(s):
        achieved = _dict(slot.get("achieved"))
        rows.append(
            (
                f"notch at {num(design.get('center_hz'), 'Hz')}"
                + (f" on node {design['node']}" if design.get("node") is not None else ""),
                f"designed {num(design.get('depth_db'), 'dB', 3)}, achieved on the device "
                f"{num(achieved.get('attenuation_at_design_center_db'), 'dB', 3)}"
                if achieved
                else f"designed {num(design.get('depth_db'), 'dB', 3)}, not uploaded",
            )
        )
    ver = _dict(s.get("verification"))
    if ver.get("band_reduction_db") is not None or ver.get("peak_reduction_db") is not None:
        rows.append(
            (
                "verification",
                f"largest response near the resonance reduced by "
                f"{num(ver.get('band_reduction_db'), 'dB', 3)}, at the resonance line "
                f"{num(ver.get('peak_reduction_db'), 'dB', 3)}",
            )
        )
    model = _dict(s.get("model"))
    if model:
        est = _dict(model.get("estimation"))
        rows.append(
            (
                f"grey-box model ({model.get('kind', '?')})",
                f"fit {num(est.get('fit_percent'), '%', 3)} on the estimation data",
            )
        )
    stream = _dict(s.get("stream"))
    if stream:
        rows.append(
            (
                "stream",
                esc(
                    f"{stream.get('samples', MISSING)} samples, {stream.get('lost_blocks', 0)} lost "
                    f"blocks, {stream.get('corrupt_frames', 0)} corrupt frames, "
                    f"{stream.get('underruns', 0)} underruns"
                ),
            )
        )
    n = len(s.get("warnings") or [])
    rows.append(("warnings", esc(f"{n}, see below" if n else "none")))
    body = _failure(s) + (key_values(rows) if rows else note("This summary holds no results."))
    return section("headline", "Headline results", body)


# --------------------------------------------------------------------------- warnings


def warnings_section(inputs: ReportInputs) -> str:
    """The warnings by topic, each with what to do; below them, apart, the notes (nothing to act on)."""
    summary = inputs.summary
    return section("warnings", "Warnings", _warning_groups(summary.get("warnings")) + _notes(summary.get("notes")))


def _warning_groups(warnings: Any) -> str:
    if not isinstance(warnings, list) or not warnings:
        return note("No warnings.")
    parts = []
    for g in group_warnings(warnings):
        items = []
        for finding, remedy in g.items:
            todo = f'<br><span class="todo">What to do: {esc(remedy)}</span>' if remedy else ""
            items.append(f'<li><span class="finding">{esc(finding)}</span>{todo}</li>')
        general = ""
        if any(not remedy for _, remedy in g.items):  # the warnings that name no remedy of their own
            general = f'<p class="todo general">What to do about these in general: {esc(g.advice)}</p>'
        parts.append(f'<h3>{esc(g.topic)} ({len(g.items)})</h3>{general}<ul class="warnings">{"".join(items)}</ul>')
    return "".join(parts)


def _notes(notes: Any) -> str:
    """``summary.json["notes"]``: worth knowing, nothing to change (an older summary has none)."""
    if not isinstance(notes, list) or not notes:
        return ""
    items = "".join(f"<li>{esc(str(n))}</li>" for n in notes)
    return f'<h3 class="notes">Notes ({len(notes)}): nothing to change</h3><ul class="notes">{items}</ul>'


# --------------------------------------------------------------------------- plots

#: Captions of the plots hilident writes; any other PNG is shown under its file name.
CAPTIONS = {
    "bode.png": "Frequency response of the plant (magnitude, phase, coherence), the fitted model, the resonances "
    "and the notch.",
    "friction.png": "Friction: the mean force or torque of each constant-speed leg and the fitted curve.",
    "notch.png": "The notches as designed and as the device stores them (read back after the upload), in dB.",
    "model.png": "The grey-box or fitted model simulated against the measurement (fit %), and its residual tests "
    "(autocorrelation and cross-correlation with their 99 % band).",
    "moves.png": "The same move without and with the notch: the load's ringing after the move (the place where "
    "the notch helped least), the dwell shaded, the settling band drawn.",
    "map.png": "The mode over the workspace: the frequency identified at each mapped position with its 95 % interval.",
    "stabilisation.png": "Stabilisation diagram of the modes from all outputs and inputs: each pole by model order and "
    "label, the first singular value of H (right axis), the selected modes.",
    "closed-loop.png": "The closed loop after the gain upload: the velocity set-point's measured response against "
    "its prediction (the multisine's lines) and one period of the velocity steps, measured and predicted.",
}


def plots(inputs: ReportInputs) -> str:
    stale = (
        note(f"Not shown, older than summary.json (an earlier command's): {', '.join(inputs.stale_images)}.")
        if inputs.stale_images
        else ""
    )
    if not inputs.images:
        return section(
            "plots",
            "Plots",
            note("No plots of this command in this folder (an upload draws none; a run with --no-plots neither).")
            + stale,
        )
    figures = [figure(name, data, CAPTIONS.get(name, name)) for name, data in inputs.images]
    return section("plots", "Plots", "".join(figures) + stale)


# --------------------------------------------------------------------------- friction

#: Units of the friction parameters (docs/results.md, "What a run's summary.json holds": force or torque in N*m,
#: speed in m/s).
FRICTION_UNITS = {"Fc": "N*m", "Fs": "N*m", "Fv": "N*m/(m/s)", "vs": "m/s", "delta_v": "1", "delta_s": "1"}
_FRICTION_NAMES = {
    "Fc": "Coulomb level Fc",
    "Fs": "static (stiction) level Fs",
    "Fv": "viscous coefficient Fv",
    "vs": "Stribeck speed vs",
    "delta_v": "viscous exponent delta_v",
    "delta_s": "Stribeck exponent delta_s",
}
_STRUCTURES = {
    "coulomb_viscous": "Coulomb + viscous",
    "stribeck_fixed_exponents": "Stribeck (exponents 1 and 2)",
    "stribeck": "Stribeck (all six parameters)",
}


def _used_parameters(fr: dict) -> list[str]:
    params = _dict(fr.get("params"))
    if fr.get("structure") == "coulomb_viscous":
        return [k for k in ("Fc", "Fv") if k in params]
    if fr.get("structure") == "stribeck_fixed_exponents":
        return [k for k in ("Fc", "Fs", "Fv", "vs") if k in params]
    return list(params)


def _friction_line(fr: dict) -> str:
    units = _units(fr, FRICTION_UNITS)
    params = _dict(fr.get("params"))
    named = ", ".join(f"{esc(k)} {num(params[k], units.get(k, ''), 3)}" for k in _used_parameters(fr))
    return esc(_STRUCTURES.get(str(fr.get("structure")), str(fr.get("structure", fr.get("model", "?"))))) + ": " + named


#: Why the friction test stopped extending itself, as the report says it.
_FRICTION_STOPS = {
    "target": "the target was met",
    "time": "it used its time (friction_test.max_duration_s)",
    "travel": "no further leg fitted the travel allowed",
    "rounds": "it played friction_test.max_rounds rounds",
}


def _friction_extension(ext: dict) -> str:
    """A line on how the friction test extended itself (empty for a fixed test)."""
    if not ext:
        return ""
    widths = _dict(ext.get("half_width_percent"))
    return (
        f"<p>The test ran {num(ext.get('rounds'))} round(s) of legs in {num(ext.get('duration_s'), 's', 3)} to "
        f"bring the 95 % intervals of Fc and Fv within ±{num(ext.get('target_ci_percent'), '%', 3)}: "
        f"Fc ±{num(widths.get('Fc'), '%', 2)}, Fv ±{num(widths.get('Fv'), '%', 2)}; it stopped because "
        f"{esc(_FRICTION_STOPS.get(str(ext.get('stopped_by')), str(ext.get('stopped_by'))))}"
        + (
            "; the configured round's points disagreed with the longer legs after it (begun before the axis "
            "settled: a longer friction_test.settle_s) and were left out"
            if ext.get("first_round_left_out")
            else ""
        )
        + ".</p>"
    )


def friction(inputs: ReportInputs) -> str:
    fr = _dict(inputs.summary.get("friction"))
    if not fr:
        return section(
            "friction", "Friction fit", note("No friction fit (no friction test was run or recorded with these data).")
        )
    units = _units(fr, FRICTION_UNITS)
    params, stderr, ci95 = _dict(fr.get("params")), _dict(fr.get("stderr")), _dict(fr.get("ci95"))
    used = _used_parameters(fr)
    rows = [
        [
            esc(_FRICTION_NAMES.get(k, k)),
            num(v, units.get(k, "")),
            num(stderr.get(k), units.get(k, ""), 2) if k in used else MISSING,
            num(ci95.get(k), units.get(k, ""), 2) if k in used else MISSING,
            esc("fitted" if k in used else "fixed: not part of the chosen structure"),
        ]
        for k, v in params.items()
    ]
    structure = _STRUCTURES.get(str(fr.get("structure")), fr.get("structure"))
    body = (
        f"<p>Structure the points support: <strong>{_text(structure)}</strong> (chosen by the corrected "
        f"Akaike criterion from {num(fr.get('points'))} constant-speed "
        f"points); RMS residual {num(fr.get('rms_residual_nm'), 'N*m', 3)}.</p>"
        + _friction_extension(_dict(fr.get("extension")))
        + table(["parameter", "value", "standard error", "95 % interval ±", ""], rows)
    )
    aicc = _dict(fr.get("aicc"))
    if aicc:
        body += table(
            ["structure", "AICc (lower is better)"],
            [[esc(_STRUCTURES.get(k, k)), num(v, "", 5)] for k, v in aicc.items()],
        )
    return section("friction", "Friction fit", body)


# --------------------------------------------------------------------------- model


def _notchable(r: dict) -> str:
    if r.get("notchable"):
        return esc("yes")
    return _text(r.get("not_notchable") or ("no" if "notchable" in r else None))


def _resonances(s: dict, ref: str) -> str:
    """Every reported resonance with its intervals, coherence, bandwidth and whether a notch may be designed."""
    rows = [
        [
            pm(r.get("frequency_hz"), r.get("frequency_ci95_hz"), "Hz", 6),
            pm(r.get("damping_ratio"), r.get("damping_ci95"), "", 3),
            num(r.get("peak_magnitude_db"), ref, 4),
            num(r.get("coherence"), "", 3),
            num(r.get("half_power_bandwidth_hz"), "Hz", 3),
            _text(r.get("method")),
            _notchable(r),
        ]
        for r in _list(s.get("resonances"))
    ]
    if not rows:
        return ""
    return table(
        [
            "frequency (95 %)",
            "damping ratio (95 %)",
            "peak",
            "coherence",
            "half-power bandwidth",
            "method",
            "a notch may be designed",
        ],
        rows,
        "Resonances of the measured response",
    )


def _plant_model(s: dict, ref: str) -> str:
    pm_ = _dict(s.get("plant_model"))
    if not pm_:
        return _resonances(s, ref) + note("No transfer function was fitted to the frequency response.")
    band = pm_.get("band_hz") if isinstance(pm_.get("band_hz"), list) else None
    pairs = [
        (
            "structure",
            esc(
                f"{pm_.get('n_num', '?')} zeros / {pm_.get('n_den', '?')} poles"
                f" + {pm_.get('integrators', 0)} integrator(s), relative degree "
                f"{pm_.get('relative_degree', '?')}, chosen by {pm_.get('criterion', '?')}"
            ),
        ),
        (
            "fit over the band",
            f"{num(pm_.get('fit_db_rms'), 'dB RMS', 3)} magnitude, {num(pm_.get('phase_rms_deg'), 'deg RMS', 3)} phase",
        ),
        ("band", esc(f"{band[0]:g} to {band[1]:g} Hz") if band and len(band) == 2 else MISSING),
        ("stability", _text(pm_.get("stability", "stable" if pm_.get("stable") else None))),
    ]
    body = _resonances(s, ref) + "<h3>Transfer function fitted to the frequency response</h3>" + key_values(pairs)
    modes = _list(pm_.get("resonances"))
    anti = _list(pm_.get("antiresonances"))
    if modes or anti:
        rows = [
            [
                esc("resonance"),
                num(m.get("frequency_hz"), "Hz"),
                num(m.get("damping_ratio"), "", 3),
                esc("reported" if m.get("reported") else m.get("reason", "")),
            ]
            for m in modes
        ]
        rows += [
            [esc("anti-resonance"), num(m.get("frequency_hz"), "Hz"), num(m.get("damping_ratio"), "", 3), ""]
            for m in anti
        ]
        body += table(["", "frequency", "damping ratio", "note"], rows, "Modes of the fitted model")
    unc = _list(_dict(_dict(s.get("measurement")).get("uncertainty")).get("at_resonances"))
    if unc:
        rows = []
        for u in unc:
            bounds = u.get("magnitude_bounds_db")
            mag = (
                f"{num(bounds[0], '', 3)} / +{num(bounds[1], 'dB', 3)}"
                if isinstance(bounds, list) and len(bounds) == 2
                else MISSING
            )
            rows.append(
                [
                    num(u.get("frequency_hz"), "Hz"),
                    mag,
                    "± " + num(u.get("phase_bound_deg"), "deg", 3),
                    num(u.get("confidence"), "", 2),
                ]
            )
        body += table(
            ["at", "magnitude bounds", "phase bound", "confidence"],
            rows,
            "Uncertainty of the measured response at each resonance",
        )
    rejected = _list(s.get("rejected_peaks"))
    if rejected:
        body += table(
            ["frequency", "peak", "coherence", "why not reported"],
            [
                [
                    num(r.get("frequency_hz"), "Hz"),
                    num(r.get("peak_magnitude_db"), ref, 3),
                    num(r.get("coherence"), "", 3),
                    _text(r.get("reason")),
                ]
                for r in rejected
            ],
            "Peaks not reported",
        )
    return body


#: Units of the grey-box parameters (hilident.ident.greybox: the force is [model] c times the torque, N).
GREYBOX_UNITS = {
    "M": "kg",
    "m": "kg",
    "Fv": "N*s/m",
    "Fv+": "N*s/m",
    "Fv-": "N*s/m",
    "b": "N*s/m",
    "k": "N/m",
    "Fc": "N",
    "Fc+": "N",
    "Fc-": "N",
    "offset": "N",
}


def _validation_rows(model: dict) -> list[list[str]]:
    records = [("estimation data", _dict(model.get("estimation")))]
    records += [(str(name), _dict(v)) for name, v in _dict(model.get("validation")).items()]
    rows = []
    for name, v in records:
        white = v.get("residuals_white")
        white_text = _yes_no(white) + (
            f" (Ljung-Box p = {num(v.get('ljung_box_p'), '', 2)})" if v.get("ljung_box_p") is not None else ""
        )
        rows.append(
            [
                esc(name),
                num(v.get("fit_percent"), "%", 3),
                num(v.get("relative_error"), "", 3),
                white_text,
                _yes_no(v.get("independent_of_input")),
                num(v.get("samples")),
            ]
        )
    return rows


def _greybox(s: dict) -> str:
    model = _dict(s.get("model"))
    if not model:
        return note('No grey-box model was asked for ([model] kind = "none") or its step was not reached.')
    units = _units(model, GREYBOX_UNITS)
    stderr, rel = _dict(model.get("stderr")), _dict(model.get("relative_stderr_percent"))
    rows = [
        [esc(k), num(v, units.get(k, "")), num(stderr.get(k), units.get(k, ""), 2), num(rel.get(k), "%", 2)]
        for k, v in _dict(model.get("params")).items()
    ]
    body = (
        f"<h3>Grey-box model: {esc(model.get('kind', '?'))}</h3>"
        + note("Force = [model] c × torque; parameters in SI units.")
        + table(["parameter", "value", "standard deviation", "relative"], rows)
        + table(
            ["record", "fit", "relative error ‖e‖/‖y‖", "residuals white", "residuals independent of input", "samples"],
            _validation_rows(model),
            "Validation",
        )
    )
    return body


def model_section(inputs: ReportInputs) -> str:
    s = inputs.summary
    if inputs.kind == "upload":
        return section(
            "model",
            "Model, uncertainty and validation",
            note(
                "An upload identifies nothing; the model is in the report of the run or identify the notches came from."
            ),
        )
    return section(
        "model", "Model, uncertainty and validation", _plant_model(s, _magnitude_reference(inputs)) + _greybox(s)
    )


# --------------------------------------------------------------------------- notches


def _slot(record: dict) -> str:
    """A record's slot, with its node in a run of several nodes ("node 2, slot 0")."""
    if record.get("node") is None:
        return num(record.get("slot"))
    return esc(f"node {record['node']}, slot {record.get('slot')}")


def _coefficients(values: Any) -> str:
    if not isinstance(values, list):
        return MISSING
    return esc(", ".join(f"{v:.9g}" if isinstance(v, (int, float)) else str(v) for v in values))


def notches(inputs: ReportInputs) -> str:
    """The notches: designed and achieved, their biquads, the upload, the slots before, the verification."""
    s = inputs.summary
    pairs = designed_and_stored(s)
    upload = _dict(s.get("upload"))
    body = _skip_reasons(s, upload)
    if not pairs:
        return section("notches", "Notches: designed and achieved", body + note("No notch was designed."))
    body += _designed_and_achieved_table(pairs)
    body += _coefficients_table(pairs)
    extras = _upload_pairs(upload, inputs.kind)
    body += key_values(extras) if extras else ""
    body += _filters_before_table(s)
    body += _verification_table(s, _magnitude_reference(inputs))
    return section("notches", "Notches: designed and achieved", body)


def _skip_reasons(s: dict, upload: dict) -> str:
    """Each reason the summary gives for a notch not designed or not uploaded, a paragraph each."""
    why = [upload.get(k) or s.get(k) for k in ("skipped_reason", "not_uploaded", "notch_skipped_reason")]
    return "".join(f"<p>{esc(w)}</p>" for w in why if w)


def _designed_and_achieved_row(d: dict, slot: dict) -> list[str]:
    """A designed notch beside what its slot achieved on the device (— where it was not uploaded)."""
    a = _dict(slot.get("achieved"))
    return [
        _slot(d),
        num(d.get("center_hz"), "Hz"),
        num(d.get("width_hz"), "Hz", 3),
        num(d.get("depth_db"), "dB", 3),
        num(d.get("predicted_band_reduction_db"), "dB", 3),
        num(a.get("center_hz"), "Hz") if a else MISSING,
        num(a.get("attenuation_at_design_center_db"), "dB", 3) if a else MISSING,
        num(a.get("realisable_db"), "dB", 3) if a else MISSING,
        (_yes_no(slot.get("matches")) if slot else esc("not uploaded")),
    ]


def _designed_and_achieved_table(pairs: list[tuple[dict, dict]]) -> str:
    """One row per designed notch: its design, what the device achieved, whether it read back as written."""
    return table(
        [
            "slot",
            "centre",
            "width",
            "designed depth",
            "predicted band reduction",
            "achieved: deepest at",
            "achieved at the designed centre",
            "realisable on the device",
            "read back as written",
        ],
        [_designed_and_achieved_row(d, slot) for d, slot in pairs],
    )


def _coefficient_rows(d: dict, slot: dict) -> list[list[str]]:
    """A designed notch's biquad coefficients, and those read back from its slot when it was uploaded."""
    rows = [
        [
            _slot(d),
            esc("designed"),
            _coefficients(d.get("b")),
            _coefficients(d.get("a")),
            num(d.get("sample_rate_hz"), "Hz"),
        ]
    ]
    if slot:
        rows.append(
            [
                _slot(d),
                esc("read back"),
                _coefficients(slot.get("readback_b")),
                _coefficients(slot.get("readback_a")),
                "",
            ]
        )
    return rows


def _coefficients_table(pairs: list[tuple[dict, dict]]) -> str:
    """The biquad coefficients of every designed notch, each followed by its slot's read-back."""
    rows = [row for d, slot in pairs for row in _coefficient_rows(d, slot)]
    return table(["slot", "", "b (b0, b1, b2)", "a (1, a1, a2)", "filter rate"], rows, "Biquad coefficients")


def _upload_pairs(upload: dict, kind: str) -> list[tuple[str, str]]:
    """What the upload did: written, read back, stored, slots put back (identify uploads nothing)."""
    if not upload:
        return []
    if kind == "identify":
        return [("uploaded", esc("no: identify uploads nothing (hilident upload --from this folder does)"))]
    pairs = [
        ("written and enabled", _yes_no(upload.get("written"))),
        ("every slot read back as written", _yes_no(upload.get("verified_readback"))),
    ]
    if upload.get("saved") is not None:
        pairs.append(("stored in non-volatile memory", _yes_no(upload.get("saved"))))
    if upload.get("not_saved"):
        pairs.append(("not stored", _text(upload["not_saved"])))
    for rb in _list(upload.get("rolled_back")):
        pairs.append((f"slot {rb.get('slot')} put back", _yes_no(rb.get("restored"))))
    return pairs


def _filters_before_table(s: dict) -> str:
    """What the device's filter slots held before the command, and whether each was put back ("" when unknown)."""
    before = _list(s.get("filters_found")) or _list(s.get("filters_before"))
    if not before:
        return ""
    return table(
        ["slot", "enabled", "b", "a", "bypassed for the measurement", "put back"],
        [
            [
                _slot(f),
                _yes_no(f.get("enabled")),
                _coefficients(f.get("b")),
                _coefficients(f.get("a")),
                _yes_no(bool(f.get("bypassed"))),
                _yes_no(f.get("restored")),
            ]
            for f in before
        ],
        "What the filter slots held before",
    )


def _verification_table(s: dict, ref: str) -> str:
    """Each resonance before and after the notch, levels in ``ref`` ("" when nothing was verified)."""
    vres = _list(_dict(s.get("verification")).get("resonances"))
    if not vres:
        return ""
    return table(
        ["resonance", "before", "after", "reduction at the line", "band", "band reduction", "noise floor"],
        [
            [
                num(r.get("frequency_hz"), "Hz")
                if r.get("node") is None
                else esc(f"node {r['node']}: ") + num(r.get("frequency_hz"), "Hz"),
                num(r.get("before_db"), ref, 3),
                num(r.get("after_db"), ref, 3),
                num(r.get("reduction_db"), "dB", 3),
                esc(_band(r.get("band_hz"))),
                num(r.get("band_reduction_db"), "dB", 3),
                _floor(r),
            ]
            for r in vres
        ],
        "Verification: the same excitation before and after the notch",
    )


def _band(value: Any) -> str:
    if isinstance(value, list) and len(value) == 2 and all(isinstance(v, (int, float)) for v in value):
        return f"{value[0]:.4g} to {value[1]:.4g} Hz"
    return MISSING


# --------------------------------------------------------------------------- stream and recordings

_STREAM_NAMES = {
    "samples": "samples",
    "lost_frames": "lost frames",
    "lost_blocks": "lost blocks",
    "lost_samples": "lost samples",
    "corrupt_frames": "corrupt frames",
    "out_of_order": "out-of-order blocks",
    "underruns": "underruns",
    "board_dropped_blocks": "blocks the board dropped",
    "clipped_blocks": "samples at the limit of their format",
    "setpoints_skipped": "set-points skipped (never sent late)",
}


def workspace(inputs: ReportInputs) -> str:
    """``[map]``: the mode at each mapped position."""
    points = _list(inputs.summary.get("map"))
    if not points:
        return section(
            "workspace",
            "Workspace map",
            note("No [map] in this command: the resonance was identified at one position."),
        )
    rows = [
        [
            num(p.get("position_m"), "m"),
            num(p.get("target_m"), "m"),
            pm(p.get("frequency_hz"), p.get("frequency_ci95_hz"), "Hz"),
            num(p.get("damping_ratio")),
            num(p.get("coherence"), "", 3),
            _text(p.get("recording")),
        ]
        for p in points
    ]
    found = [p["frequency_hz"] for p in points if isinstance(p.get("frequency_hz"), (int, float))]
    spread = (
        note(
            f"The mode moves over {min(found):.4g} .. {max(found):.4g} Hz "
            f"({100 * (max(found) - min(found)) / min(found):.1f} % of its lowest)."
        )
        if found
        else ""
    )
    body = (
        table(
            ["position", "asked", "mode frequency (95 %)", "damping ratio", "coherence", "recording"],
            rows,
            "The mode identified at each position",
        )
        + spread
    )
    ws = _dict(inputs.summary.get("workspace"))
    verified = _dict(ws.get("verification"))
    measured = _map_verification(verified) if verified else ""
    return section(
        "workspace",
        "Workspace map",
        body + _joint_fit(_dict(ws.get("joint_fit"))) + _covering(_dict(ws.get("covering_notch"))) + measured,
    )


def _map_verification(verified: dict) -> str:
    """The reduction measured again at every mapped position: on what the notches do to the plant (command to
    output) and on the loop (excitation to output)."""
    on_plant = verified.get("measured_on") == "filtered_plant"
    rows = [
        [
            num(r.get("position_m"), "m"),
            num(r.get("frequency_hz"), "Hz"),
            num(r.get("band_reduction_db"), "dB", 3),
            num(r.get("reduction_db"), "dB", 3),
            num(r.get("predicted_band_reduction_db"), "dB", 3),
            _floor(r),
            num(r.get("loop_band_reduction_db"), "dB", 3),
            num(r.get("periods")),
            _text(", ".join(str(n) for n in r.get("recordings") or [r.get("recording")])),
        ]
        for r in verified.get("positions") or []
        if isinstance(r, dict)
    ]
    head = (
        "band figure, command to output" if on_plant else "band figure, excitation to output",
        "at the line",
        "predicted on the map's response",
        "noise floor",
        "band figure of the loop",
        "periods",
        "recordings",
    )
    why = note(
        "The first two figures are on the filter slots and the plant together, as an open-loop torque run "
        "measures them; the loop's figure is what a torque disturbance at the held cart sees, smaller because "
        "the notch also takes away the damping the holding loop gave the mode."
        if on_plant
        else "The device records no filter input (driver channel filter_input): the figures are the loop's, "
        "excitation to output."
    ) + note(
        "The noise floor is the largest band figure the record's own noise lets it show (marked where the figure "
        "lies within 6 dB of it: there it measures the floor more than the notch). Where the floor hid the target, "
        "a second, longer record was made at the position and the figures are over all its periods."
    )
    worst = key_values(
        [
            (
                "band figure at every mapped position, worst",
                f"{num(verified.get('worst_band_reduction_db'), 'dB', 3)} at "
                f"{num(verified.get('worst_position_m'), 'm')}",
            )
        ]
    )
    return worst + table(["position", "mode", *head], rows, "Measured again with the notches enabled") + why


def _floor(row: dict) -> str:
    """A verification record's noise floor, marked where the band figure lies within 6 dB of it."""
    floor = num(row.get("floor_db"), "dB", 3)
    return floor + esc(" (figure at the floor)") if row.get("floor_limited") else floor


def _polynomial(poly: dict) -> str:
    """``c0 ± s0 + c1 ± s1 p + ...`` of a joint-fit polynomial (its units per power of p in m)."""
    terms = [
        f"({pm(c, s, '', 5)}){'' if j == 0 else ' p' if j == 1 else f' p^{j}'}"
        for j, (c, s) in enumerate(zip(poly.get("coefficients") or [], poly.get("std") or [], strict=False))
    ]
    return " + ".join(terms) if terms else MISSING


def _joint_fit(fit: dict) -> str:
    if not fit:
        return note("No joint fit (see the warnings).")
    return key_values(
        [
            ("stiffness k(p), N/m (p in m)", _polynomial(_dict(fit.get("k_n_per_m")))),
            ("damping d(p), N*s/m", _polynomial(_dict(fit.get("d_ns_per_m")))),
            ("cart mass m1", pm(fit.get("m1_kg"), fit.get("m1_std_kg"), "kg")),
            ("load mass m2", pm(fit.get("m2_kg"), fit.get("m2_std_kg"), "kg")),
            ("cart viscous friction b", pm(fit.get("b_ns_per_m"), fit.get("b_std_ns_per_m"), "N*s/m")),
            ("torque-to-force constant c", num(fit.get("torque_constant_n_per_nm"), "N/(N*m)")),
        ]
    )


def _covering(cover: dict) -> str:
    if not cover:
        return note("No covering notch (no notch was designed, see the warnings).")
    lo_hi = cover.get("range_hz") or [None, None]
    return key_values(
        [
            ("range the mode moves through", f"{num(lo_hi[0], 'Hz')} .. {num(lo_hi[1], 'Hz')}"),
            ("what the device got", _text(cover.get("used"))),
            (
                "worst attenuation over that range",
                f"{num(cover.get('worst_attenuation_db'), 'dB', 3)} at {num(cover.get('worst_frequency_hz'), 'Hz')}",
            ),
            ("target", num(cover.get("target_attenuation_db"), "dB", 3)),
            ("design", _text(cover.get("message"))),
        ]
    )


def _above_rest(move: dict) -> str:
    """The reduction above the vibration at rest, or that the move with the notch left none above it."""
    if move.get("rms_reduction_above_standstill_db") is None and move.get("standstill_rms_m") is not None:
        return esc("none left above rest")
    return num(move.get("rms_reduction_above_standstill_db"), "dB", 3)


def _mode_excitation(move: dict) -> str:
    """``V`` without / with the notch at each mode where the move ends, with the mode's frequency."""
    parts = []
    for m in _list(move.get("modes")):
        m = _dict(m)
        with_notch = m.get("excitation_with_notch")
        parts.append(
            f"{num(m.get('excitation'), '', 3)} / {'-' if with_notch is None else num(with_notch, '', 2)} "
            f"at {num(m.get('frequency_hz'), 'Hz')}"
        )
    return "; ".join(parts) if parts else esc("-")


def moves(inputs: ReportInputs) -> str:
    """``[verification] move``: the ringing after the same move without and with the notch."""
    test = _dict(inputs.summary.get("move_test"))
    results = _list(test.get("moves"))
    if not results:
        return section("moves", "Move test", note("No [verification] move in this command."))
    rows = []
    for r in results:
        without, with_notch = _dict(r.get("without")), _dict(r.get("with_notch"))
        rows.append(
            [
                num(r.get("start_m"), "m"),
                num(r.get("distance_m"), "m"),
                _text(r.get("notch_in")),
                _text(r.get("signal")),
                _mode_excitation(r),
                num(without.get("rms_m"), "m", 3),
                num(with_notch.get("rms_m"), "m", 3),
                num(r.get("rms_reduction_db"), "dB", 3),
                num(r.get("peak_to_peak_reduction_db"), "dB", 3),
                num(r.get("standstill_rms_m"), "m", 3),
                num(r.get("rest_limit_db"), "dB", 3),
                _above_rest(r),
                num(without.get("settling_time_s"), "s", 3),
                num(with_notch.get("settling_time_s"), "s", 3),
            ]
        )
    body = (
        key_values(
            [
                ("worst RMS reduction", num(test.get("worst_rms_reduction_db"), "dB", 3)),
                ("where", num(test.get("worst_start_m"), "m")),
            ]
        )
        + table(
            [
                "from",
                "distance",
                "notch in",
                "measured",
                "mode excitation V without / with",
                "RMS without",
                "RMS with",
                "RMS reduction",
                "peak-to-peak reduction",
                "RMS at rest",
                "rest limit",
                "reduction above rest",
                "settling without",
                "settling with",
            ],
            rows,
            "Residual vibration over the dwell after each move",
        )
        + note(
            "V: the ringing the move's set-point leaves at the mode where it ends, in steps of its peak "
            "acceleration (a trapezoid gives 0 to 4). Below 1 the move hardly excites the mode, and its "
            "reduction measures the vibration at rest more than the notch. The rest limit is the largest "
            "RMS reduction the vibration at rest lets the move show."
        )
    )
    return section("moves", "Move test", body + _shaped_moves(results))


def _shaped_moves(results: list) -> str:
    """The moves with input shapers beside the same move without shaping and with the notch ('' when none)."""
    names = sorted({_text(m.get("name")) for r in results for m in _list(_dict(r).get("shapers"))})
    if not names:
        return ""
    rows = []
    for r in results:
        r = _dict(r)
        by_name = {_text(m.get("name")): _dict(m) for m in _list(r.get("shapers"))}
        without, with_notch = _dict(r.get("without")), _dict(r.get("with_notch"))
        row = [
            num(r.get("start_m"), "m"),
            num(without.get("rms_m"), "m", 3),
            f"{num(with_notch.get('rms_m'), 'm', 3)} ({num(r.get('rms_reduction_db'), 'dB', 3)}), "
            f"+{num(r.get('added_delay_s'), 's', 3)}",
        ]
        for name in names:
            m = by_name.get(name, {})
            residual = _dict(m.get("residual"))
            row.append(
                f"{_text(m.get('kind'))} {num(m.get('frequency_hz'), 'Hz')}: {num(residual.get('rms_m'), 'm', 3)} "
                f"({num(m.get('rms_reduction_db'), 'dB', 3)}), +{num(m.get('added_delay_s'), 's', 3)}, "
                f"settles {num(residual.get('settling_time_s'), 's', 3)}, "
                f"max accel {num(m.get('max_accel_mps2'), 'm/s²')}"
            )
        row.append(num(r.get("standstill_rms_m"), "m", 3))
        rows.append(row)
    return table(
        ["from", "RMS without shaping", "with the notch (reduction), added time", *names, "RMS at rest"],
        rows,
        "The same move without shaping, with the notch and with each input shaper",
    ) + note(
        "Each shaper's cell: its kind and the frequency it acts at where the move ends, the RMS left over the dwell "
        "(its reduction against the move without shaping), how much later the move ends, the settling time to the "
        "band of the move without shaping, and the largest acceleration whose smoothing stays within Klipper's "
        "target (its suggested max_accel). The shapers' moves run with the drive's notch out of the way."
    )


def stream_section(inputs: ReportInputs) -> str:
    st = _dict(inputs.summary.get("stream"))
    if not st:
        return section("stream", "Stream statistics", note("No stream in this command (an upload streams nothing)."))
    rows = [(_STREAM_NAMES.get(k, k), num(v, "", 12)) for k, v in st.items()]
    return section("stream", "Stream statistics", key_values(rows) + _clock_table(inputs.summary.get("clock")))


def _clock_table(clocks: Any) -> str:
    """CANopen streamed runs: who kept the bus clock of each recording, its jitter and its histogram."""
    clocks = [c for c in _list(clocks) if isinstance(c, dict)]
    if not clocks:
        return ""
    rows = []
    for c in clocks:
        hist = _dict(c.get("histogram_us"))
        edges, counts = _list(hist.get("edges_us")), _list(hist.get("counts"))
        spread = ", ".join(f"≥{e:g} µs: {n}" for e, n in zip(edges, counts, strict=False) if n)
        rows.append(
            [
                esc(c.get("run", MISSING)),
                esc(c.get("source", MISSING)),
                num(c.get("period_s"), "s", 6),
                num(_scaled(c.get("jitter_p50_s"), 1e6), "µs", 3),
                num(_scaled(c.get("jitter_p99_s"), 1e6), "µs", 3),
                num(_scaled(c.get("jitter_max_s"), 1e6), "µs", 3),
                num(c.get("outside_window"), "", 12),
                num(c.get("setpoints_skipped"), "", 12),
                esc(spread or MISSING),
            ]
        )
    header = ["run", "SYNC from", "period", "jitter p50", "p99", "max", "outside window", "skipped", "jitter histogram"]
    why = "; ".join(f"{c.get('run')}: {c.get('why')}" for c in clocks if c.get("why"))
    return table(header, rows, caption="Bus clock (who produced SYNC, measured from the SYNC instants)") + (
        note(esc(why)) if why else ""
    )


def _scaled(value: Any, factor: float) -> Any:
    return value * factor if isinstance(value, int | float) else value


def _size(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 1e5 else f"{n / 1e3:.0f} kB"


def recordings(inputs: ReportInputs) -> str:
    if not inputs.recordings:
        return section("recordings", "Recordings", note("No recordings (.h5) in this folder."))
    rows = []
    for rec in inputs.recordings:
        a = rec.attrs
        name = (
            f'<a href="{esc(quote(rec.name))}">{esc(rec.name)}</a>'
            if rec.in_folder
            else esc(f"{rec.name} (the data file, outside this folder)")
        )
        rate, n = a.get("sample_rate_hz"), a.get("n_samples", a.get("flushed_samples"))
        duration = (
            num(n / rate, "s", 4)
            if isinstance(n, (int, float)) and isinstance(rate, (int, float)) and rate
            else MISSING
        )
        status = _text(a.get("status")) + (f": {esc(a['reason'])}" if a.get("reason") else "")
        rows.append(
            [
                name,
                _text(a.get("experiment")),
                _text(a.get("mode")),
                num(n),
                duration,
                status,
                num(a.get("events")),
                esc(_size(rec.size_bytes)) + (f" ({esc(rec.error)})" if rec.error else ""),
            ]
        )
    return section(
        "recordings",
        "Recordings",
        table(["file", "experiment", "mode", "samples", "duration", "status", "events", "size"], rows),
    )


#: The sections in page order: (anchor, title, writer).
SECTIONS: tuple[tuple[str, str, Callable[[ReportInputs], str]], ...] = (
    ("run", "What was run on what", run_on_what),
    ("headline", "Headline results", headline),
    ("warnings", "Warnings", warnings_section),
    ("plots", "Plots", plots),
    ("friction", "Friction fit", friction),
    ("model", "Model, uncertainty and validation", model_section),
    ("mimo", "Several inputs and outputs", mimo),
    ("notches", "Notches: designed and achieved", notches),
    ("loop", "The drive's loop", loop),
    ("workspace", "Workspace map", workspace),
    ("moves", "Move test", moves),
    ("stream", "Stream statistics", stream_section),
    ("recordings", "Recordings", recordings),
)
