"""``hilident export``: the identified plant, grey-box parameters and notches in forms other tools load.

:func:`export_document` gathers from a ``summary.json`` (of ``run``,
``identify`` or ``upload``)

- the fitted plant model as a transfer function (``num``/``den`` in ``s``,
  rad/s, highest power first) and a state space ``A, B, C, D`` (controllable
  canonical form, :func:`scipy.signal.tf2ss`), continuous and discretised
  with a zero-order hold (:func:`scipy.signal.cont2discrete`) at the drive's
  loop rate;
- the grey-box parameters with their standard deviations;
- the notch biquads as designed and as the device stores them (read back),
  each with its sample rate;
- for an identify with several inputs and outputs (``summary.json["mimo"]``), the
  modal model of every channel as a real state space, continuous and discretised
  likewise (``mimo_model``, :mod:`hilident.io.mimo_export`);

every part with a ``units`` map. :func:`write_json`, :func:`write_mat` and
:func:`write_control` write it; :func:`to_control` gives python-control
objects (an optional extra: ``pip install 'hilident[control]'``).

The continuous forms reproduce ``summary.json``'s model exactly (the same
polynomials; the state space to about 1e-14 relative). The discrete
transfer-function coefficients have their roots crowded near ``z = 1`` at a
loop rate far above the plant's modes, so the polynomial loses about six
digits there: prefer the discrete state space.

Examples
--------
>>> summary = {"plant_model": {"num": [2.0], "den": [1.0, 3.0], "band_hz": [1.0, 10.0]},
...            "notch_filters": [], "upload": {"slots": []}}
>>> doc = export_document(summary, rate_hz=1000.0)
>>> doc["plant"]["continuous"]["ss"]["A"]
[[-3.0]]
>>> doc["plant"]["discrete"]["sample_rate_hz"]
1000.0
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from hilident.errors import DataError, HilidentError, UsageError
from hilident.io.mimo_export import mimo_control_lines, mimo_model_part
from hilident.io.shaper_export import SHAPER_FORMATS, write_shaper

__all__ = [
    "FORMATS",
    "export_document",
    "load_summary",
    "model_response",
    "run_export",
    "to_control",
    "to_mat_layout",
    "control_script",
    "write_control",
    "write_json",
    "write_mat",
]

#: ``--format`` choices and the file each writes by default in the exported folder.
FORMATS = {"json": "model.json", "mat": "model.mat", "python-control": "model_control.py"}

#: Export layout version (bumped when a key changes meaning).
FORMAT_VERSION = 1

#: Units of a recording channel by the suffix of its name.
_CHANNEL_UNITS = {
    "_mps2": "m/s^2",
    "_mps": "m/s",
    "_m": "m",
    "_nm": "N*m",
    "_rad_s": "rad/s",
    "_rad": "rad",
    "_n": "N",
    "_a": "A",
}

#: Units of the grey-box parameters; the force in the regression is ``c * torque``, N.
_GREYBOX_UNITS = {
    "M": "kg",
    "m": "kg",
    "b": "N*s/m",
    "k": "N/m",
    "Fv": "N/(m/s)",
    "Fv+": "N/(m/s)",
    "Fv-": "N/(m/s)",
    "Fc": "N",
    "Fc+": "N",
    "Fc-": "N",
    "offset": "N",
}

_MATLAB_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,62}$")


def load_summary(source: str | Path) -> tuple[dict, Path]:
    """The ``summary.json`` of a run, identify or upload folder (or the file itself), and its path.

    Raises
    ------
    DataError
        No such folder or file, no ``summary.json`` in it, or not a summary's JSON.
    """
    path = Path(source)
    if path.is_dir():
        path = path / "summary.json"
    if not path.is_file():
        raise DataError(f"{source}: no summary.json there (give a run, identify or upload output folder)")
    try:
        summary = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: cannot be read as a summary.json: {exc}") from None
    if not isinstance(summary, dict) or not ({"plant_model", "notch_filters", "upload"} & set(summary)):
        raise DataError(
            f"{path}: not the summary.json of a hilident run, identify or upload "
            "(none of plant_model, notch_filters, upload)"
        )
    return summary, path


def _plant_source(summary: dict, path: Path | None) -> dict | None:
    """The summary holding the plant model: this one, or for an upload the source it names."""
    if summary.get("plant_model"):
        return summary
    source = summary.get("source")
    if isinstance(source, dict) and source.get("summary") and path is not None:
        where = Path(source["summary"])
        where = where if where.is_absolute() else path.parent / where
        try:
            return json.loads(where.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            return None
    return None


def _polynomials(plant_model: dict, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``num``, ``den`` of a summary's ``plant_model``, checked."""
    try:
        num = np.atleast_1d(np.asarray(plant_model["num"], dtype=float))
        den = np.atleast_1d(np.asarray(plant_model["den"], dtype=float))
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"{where}: plant_model.num / plant_model.den are not lists of numbers ({exc})") from None
    if not (num.size and den.size and np.all(np.isfinite(num)) and np.all(np.isfinite(den)) and den[0] != 0):
        raise DataError(f"{where}: plant_model.num / plant_model.den are empty, not finite or den[0] is 0")
    if num.size > den.size:
        raise DataError(
            f"{where}: plant_model is improper (degree of num {num.size - 1} > den {den.size - 1}); "
            "no state space exists"
        )
    return num, den


def model_response(summary: dict, frequency_hz) -> np.ndarray:
    """The complex response of ``summary.json``'s plant model at ``frequency_hz`` (Hz): ``num(jw) / den(jw)``.

    The reference an export must reproduce. Raises :class:`DataError` without a plant model.
    """
    from scipy import signal

    if not summary.get("plant_model"):
        raise DataError("the summary has no plant_model")
    num, den = _polynomials(summary["plant_model"], "summary.json")
    _, h = signal.freqs(num, den, worN=2 * np.pi * np.asarray(frequency_hz, dtype=float))
    return np.asarray(h)


def _loop_rate(summary: dict, plant_summary: dict, rate_hz: float | None) -> tuple[float | None, str]:
    """The rate to discretise at, Hz, and where it came from."""
    if rate_hz is not None:
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise UsageError(f"--rate-hz {rate_hz}: must be a positive number of Hz")
        return float(rate_hz), "given (--rate-hz)"
    for s in (summary, plant_summary):
        device = s.get("device") or {}
        if isinstance(device, dict) and device.get("loop_rate_hz"):
            return float(device["loop_rate_hz"]), "device.loop_rate_hz (the drive's loop rate)"
        for n in s.get("notch_filters") or []:
            if n.get("sample_rate_hz"):
                return float(n["sample_rate_hz"]), "notch_filters[].sample_rate_hz (the drive's filter rate)"
    for s in (summary, plant_summary):
        rate = s.get("sample_rate_hz") or (s.get("data") or {}).get("sample_rate_hz")
        if rate:
            return float(rate), "the recording's sample rate (no drive loop rate in the summary; --rate-hz sets it)"
    return None, "no rate in the summary (--rate-hz sets one)"


def _output_channel(summary: dict) -> tuple[str | None, str | None]:
    """The plant's output channel and its unit, from the summary (or the run's config when it is still there)."""
    data = summary.get("data") or {}
    channel = (data.get("mapping") or {}).get("output")
    unit = (data.get("units") or {}).get("output")
    if channel is None and summary.get("config"):
        try:
            from hilident.config.tables import load_config

            channel = load_config(summary["config"]).identification.output
        except (HilidentError, OSError):  # a moved or changed config loses the output's name, not the export
            channel = None
    if channel and unit is None:
        unit = _suffix_unit(channel)
    return channel, unit


def _suffix_unit(channel: str) -> str | None:
    """The unit a channel's name ends in (``_mps`` m/s, ``_nm`` N*m, ...), None if none."""
    return next(
        (u for suffix, u in sorted(_CHANNEL_UNITS.items(), key=lambda kv: -len(kv[0])) if channel.endswith(suffix)),
        None,
    )


def _channel_unit(channel: str, stated: str | None) -> str:
    """A channel's unit: the one the summary states, else the one its name ends in, else ``"unknown"``."""
    return stated or _suffix_unit(channel) or "unknown"


def _mimo_part(summary: dict, rate_hz: float | None) -> tuple[dict | None, str | None]:
    """The ``mimo_model`` part, the modal state space of every channel, or None and why."""
    if not summary["mimo"].get("modes"):
        return None, "the identify found no mode (summary.json mimo.modes is empty; mimo.modal_notes says why)"
    rate, rate_source = _loop_rate(summary, summary, rate_hz)
    try:
        return mimo_model_part(summary["mimo"], _channel_unit, rate, rate_source), None
    except DataError as exc:  # a summary of an older hilident (no residues), or a damaged one
        return None, str(exc)


def _leading(poly: np.ndarray) -> float:
    """The first non-zero coefficient of ``poly`` (0 for the zero polynomial)."""
    nonzero = poly[poly != 0]
    return float(nonzero[0]) if nonzero.size else 0.0


def _matrices(ss) -> dict[str, list]:
    return {name: np.atleast_2d(np.asarray(m, dtype=float)).tolist() for name, m in zip("ABCD", ss, strict=True)}


def _plant_part(summary: dict, plant_summary: dict, rate_hz: float | None) -> dict:
    from scipy import signal

    pm = plant_summary["plant_model"]
    num, den = _polynomials(pm, "summary.json")
    channel, out_unit = _output_channel(plant_summary)
    out_unit = out_unit or "unknown"
    ss = signal.tf2ss(num, den)
    part: dict[str, Any] = {
        "input": "torque",
        "input_unit": "N*m",
        "output": channel,
        "output_unit": out_unit,
        "band_hz": pm.get("band_hz"),
        "fit_db_rms": pm.get("fit_db_rms"),
        "phase_rms_deg": pm.get("phase_rms_deg"),
        "n_num": pm.get("n_num"),
        "n_den": pm.get("n_den"),
        "integrators": pm.get("integrators"),
        "continuous": {
            "tf": {"num": num.tolist(), "den": den.tolist()},
            "ss": _matrices(ss),
            "zpk": {
                "zeros_rad_s": pm.get("zeros_rad_s"),
                "poles_rad_s": pm.get("poles_rad_s"),
                "gain": _leading(num) / float(den[0]),
            },
        },
        "units": {
            "response": f"({out_unit})/(N*m)",
            "s": "rad/s",
            "tf": "num, den: polynomials in s (rad/s), highest power first",
            "ss": "x' = A x + B u, y = C x + D u; u torque N*m, y output, t in s",
            "zpk": "zeros, poles: rows [re, im], rad/s; gain: leading coefficient of num over that of den",
            "discrete": "x[k+1] = A x[k] + B u[k]; num, den polynomials in z^-1 order (scipy), dt_s s",
            "band_hz": "Hz",
            "fit_db_rms": "dB",
            "phase_rms_deg": "degree",
        },
    }
    rate, rate_source = _loop_rate(summary, plant_summary, rate_hz)
    if rate is None:
        part["discrete"] = None
        part["discrete_reason"] = rate_source
        return part
    dt = 1.0 / rate
    num_d, den_d, _ = signal.cont2discrete((num, den), dt, method="zoh")
    a, b, c, d, _ = signal.cont2discrete(ss, dt, method="zoh")
    part["discrete"] = {
        "sample_rate_hz": rate,
        "dt_s": dt,
        "method": "zoh",
        "rate_source": rate_source,
        "tf": {"num": np.ravel(num_d).tolist(), "den": np.ravel(den_d).tolist()},
        "ss": _matrices((a, b, c, d)),
    }
    return part


def _greybox_part(summary: dict) -> dict | None:
    model = summary.get("model")
    if not isinstance(model, dict) or not model.get("params"):
        return None
    params = model["params"]
    return {
        "kind": model.get("kind"),
        "params": params,
        "stderr": model.get("stderr", {}),
        "relative_stderr_percent": model.get("relative_stderr_percent", {}),
        "fit_percent": model.get("fit_percent"),
        "units": {
            **{name: _GREYBOX_UNITS.get(name, "unknown") for name in params},
            "stderr": "as the parameter",
            "relative_stderr_percent": "%",
            "fit_percent": "%",
        },
    }


def _node(record: dict) -> dict:
    """``{"node": N}`` for a record of a run of several nodes, else nothing."""
    return {"node": record["node"]} if record.get("node") is not None else {}


def _node_key(records: list[dict]) -> tuple[str, ...]:
    """``("node",)`` where the records are of several nodes (the MATLAB struct gets a ``node`` column)."""
    return ("node",) if any("node" in r for r in records) else ()


def _notch_parts(summary: dict) -> dict:
    designed = [
        {
            **_node(n),
            "slot": n.get("slot"),
            "center_hz": n.get("center_hz"),
            "width_hz": n.get("width_hz"),
            "depth_db": n.get("depth_db"),
            "sample_rate_hz": n.get("sample_rate_hz"),
            "b": n.get("b"),
            "a": n.get("a"),
        }
        for n in summary.get("notch_filters") or []
    ]
    rate_of_slot = {(n.get("node"), n["slot"]): n["sample_rate_hz"] for n in designed}
    device_rate = (summary.get("device") or {}).get("loop_rate_hz")
    stored = [
        {
            **_node(s),
            "slot": s.get("slot"),
            "sample_rate_hz": rate_of_slot.get((s.get("node"), s.get("slot")), device_rate),
            "b": s.get("readback_b"),
            "a": s.get("readback_a"),
            "matches": s.get("matches"),
        }
        for s in (summary.get("upload") or {}).get("slots") or []
        if s.get("readback_b") is not None
    ]
    return {
        "designed": designed,
        "stored": stored,
        "units": {
            "b": "numerator (b0, b1, b2) in z^-1, scipy convention, dimensionless",
            "a": "denominator (1, a1, a2) in z^-1",
            "sample_rate_hz": "Hz",
            "center_hz": "Hz",
            "width_hz": "Hz",
            "depth_db": "dB",
            "slot": "filter slot index",
            "node": "CANopen node of the slot (a run of several nodes)",
        },
    }


def export_document(summary: dict, rate_hz: float | None = None, path: Path | None = None) -> dict:
    """Everything ``hilident export`` writes, as plain JSON types.

    Parameters
    ----------
    summary : dict
        A ``summary.json`` of ``run``, ``identify`` or ``upload``.
    rate_hz : float, optional
        Rate to discretise the plant at, Hz (default: the drive's loop rate the summary names).
    path : Path, optional
        Where the summary was read; an upload's summary finds its source's plant model through it.

    Returns
    -------
    dict
        ``plant`` (None without a plant model), ``greybox`` (None without a ``[model]`` fit), ``notches``,
        and where they came from; for a summary with ``mimo`` also ``mimo_model`` (None, and
        ``mimo_model_reason`` why, without modes or without their residues).
    """
    kind = summary.get("command") or ("identify" if "data" in summary else "run")
    plant_summary = _plant_source(summary, path)
    doc = {
        "format": "hilident-model-export",
        "format_version": FORMAT_VERSION,
        "hilident_version": summary.get("hilident_version"),
        "source": str(path) if path else None,
        "source_kind": kind,
        "plant": _plant_part(summary, plant_summary, rate_hz) if plant_summary else None,
        "greybox": _greybox_part(summary) or (_greybox_part(plant_summary) if plant_summary else None),
        "notches": _notch_parts(summary),
    }
    if isinstance(summary.get("mimo"), dict):
        doc["mimo_model"], reason = _mimo_part(summary, rate_hz)
        if reason is not None:
            doc["mimo_model_reason"] = reason
    return doc


def write_json(doc: dict, out: Path) -> None:
    """The export as one JSON file (layout: docs/export.md)."""
    from hilident.io.serialise import write_json as _write

    try:
        _write(out, doc)
    except DataError as exc:
        raise UsageError(f"--out {out}: {exc}") from None


def _matlab_name(key: str) -> str:
    """``key`` as a valid MATLAB identifier (``Fv+`` -> ``Fv_pos``)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", key.replace("+", "_pos").replace("-", "_neg"))
    if not name[:1].isalpha():
        name = "x_" + name
    return name[:63]


def _mat_value(value: Any) -> Any:
    """A JSON value as savemat lays it out for MATLAB: dicts as structs, numbers as doubles, null as ``[]``."""
    if value is None:
        return np.zeros((0, 0))
    if isinstance(value, dict):
        return {_matlab_name(str(k)): _mat_value(v) for k, v in value.items()}
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
        return [_mat_value(v) for v in value]  # savemat writes a cell array of structs
    if isinstance(value, list) and value and all(isinstance(v, str) for v in value):
        return np.array(value, dtype=object)  # a cell array of char
    if isinstance(value, list):
        return np.asarray(value, dtype=float) if value else np.zeros((0, 0))  # None in a list becomes NaN
    return value


def _records_struct(records: list[dict], vector_keys: tuple[str, ...], scalar_keys: tuple[str, ...]) -> dict:
    """A list of notch records as one struct of arrays: ``b``, ``a`` n-by-3, the rest n-by-1."""
    out: dict[str, Any] = {}
    for key in vector_keys:
        out[key] = np.array([r[key] for r in records], dtype=float).reshape(len(records), 3)
    for key in scalar_keys:
        out[key] = np.array([np.nan if r.get(key) is None else float(r[key]) for r in records], dtype=float).reshape(
            len(records), 1
        )
    return out


def to_mat_layout(doc: dict) -> dict[str, Any]:
    """The export as MATLAB variables: ``plant``, ``greybox``, ``notches_designed``, ``notches_stored``, ``info``
    and, with a modal model of several channels, ``mimo_model`` (names and units as cell arrays of char).

    Structs of doubles with valid MATLAB names; a notch list is a struct of arrays (``b``, ``a`` n-by-3; ``slot``,
    ``sample_rate_hz``, ... n-by-1); complex roots as n-by-2 ``[re, im]``; units as char fields of a ``units``
    struct; a key that is no MATLAB name is renamed (``Fv+`` -> ``Fv_pos``, ``Fc-`` -> ``Fc_neg``).
    """
    notches = doc["notches"]
    out: dict[str, Any] = {
        "info": _mat_value(
            {k: doc[k] for k in ("format", "format_version", "hilident_version", "source", "source_kind")}
        ),
        "notches_designed": {
            **_records_struct(
                notches["designed"],
                ("b", "a"),
                (*_node_key(notches["designed"]), "slot", "center_hz", "width_hz", "depth_db", "sample_rate_hz"),
            ),
            "units": _mat_value(notches["units"]),
        },
        "notches_stored": {
            **_records_struct(
                notches["stored"], ("b", "a"), (*_node_key(notches["stored"]), "slot", "sample_rate_hz", "matches")
            ),
            "units": _mat_value(notches["units"]),
        },
    }
    if doc["plant"] is not None:
        out["plant"] = _mat_value(doc["plant"])
    if doc["greybox"] is not None:
        out["greybox"] = _mat_value(doc["greybox"])
    if doc.get("mimo_model") is not None:
        out["mimo_model"] = _mat_value(doc["mimo_model"])
    return out


def write_mat(doc: dict, out: Path) -> None:
    """The export as a MATLAB ``.mat`` file (v5, :func:`scipy.io.savemat`)."""
    from scipy.io import savemat

    try:
        savemat(out, to_mat_layout(doc), oned_as="row", long_field_names=True)
    except OSError as exc:
        raise UsageError(f"--out {out}: cannot write it: {exc}") from None


def _control():
    try:
        import control
    except ImportError:
        raise UsageError("the python-control form needs the optional extra: pip install 'hilident[control]'") from None
    return control


def to_control(summary: dict, rate_hz: float | None = None, path: Path | None = None) -> dict[str, Any]:
    """The plant model as python-control objects.

    Returns
    -------
    dict
        ``tf`` (:class:`control.TransferFunction`, s in rad/s), ``ss`` (:class:`control.StateSpace`), and at the
        drive's loop rate ``tf_discrete``, ``ss_discrete`` (zero-order hold; ``dt`` in s; absent without a rate).
        For a summary with modes of several inputs and outputs: ``mimo_ss`` (and ``mimo_ss_discrete``), the modal
        state space with the inputs, outputs and states named (``mimo_model`` of :func:`export_document`).

    Raises
    ------
    UsageError
        python-control is not installed (``pip install 'hilident[control]'``).
    DataError
        The summary has no plant model and no modal model of several channels.
    """
    control = _control()
    doc = export_document(summary, rate_hz, path)
    plant, mimo = _models(doc)
    out = {}
    if plant is not None:
        cont, disc = plant["continuous"], plant["discrete"]
        out = {"tf": control.tf(cont["tf"]["num"], cont["tf"]["den"]), "ss": control.ss(*_abcd(cont["ss"]))}
        if disc is not None:
            out["tf_discrete"] = control.tf(disc["tf"]["num"], disc["tf"]["den"], disc["dt_s"])
            out["ss_discrete"] = control.ss(*_abcd(disc["ss"]), disc["dt_s"])
    if mimo is not None:
        out.update(_mimo_control(control, mimo))
    return out


def _models(doc: dict) -> tuple[dict | None, dict | None]:
    """The document's ``plant`` and ``mimo_model``; DataError when it has neither."""
    plant, mimo = doc["plant"], doc.get("mimo_model")
    if plant is None and mimo is None:
        why = f"; no modal model of several channels: {doc['mimo_model_reason']}" if "mimo_model_reason" in doc else ""
        raise DataError(f"the summary has no plant_model to export (and no source summary with one){why}")
    return plant, mimo


def _mimo_control(control, mimo: dict) -> dict[str, Any]:
    """``mimo_ss`` and, with a rate, ``mimo_ss_discrete``: python-control state spaces with named signals."""
    names = {"inputs": mimo["inputs"], "outputs": mimo["outputs"], "states": mimo["state_names"]}
    out = {"mimo_ss": control.ss(*_abcd(mimo["continuous"]["ss"]), name="mimo_model", **names)}
    disc = mimo["discrete"]
    if disc is not None:
        out["mimo_ss_discrete"] = control.ss(*_abcd(disc["ss"]), disc["dt_s"], name="mimo_model_discrete", **names)
    return out


def _abcd(ss: dict) -> tuple[np.ndarray, ...]:
    return tuple(np.asarray(ss[name], dtype=float) for name in "ABCD")


def control_script(doc: dict) -> str:
    """A small Python script that rebuilds the python-control objects of :func:`to_control` from the numbers
    in ``doc`` (floats written by ``repr``: exact); running it defines ``tf``, ``ss`` and, with a rate,
    ``tf_discrete``, ``ss_discrete``; with a modal model of several channels ``mimo_ss`` (and
    ``mimo_ss_discrete``) with named inputs, outputs and states."""
    plant, mimo = _models(doc)
    lines = _plant_script(doc, plant) if plant is not None else _mimo_script_head(doc)
    if mimo is not None:
        lines += mimo_control_lines(mimo)
    return "\n".join(lines) + "\n"


def _mimo_script_head(doc: dict) -> list[str]:
    return [
        '"""The modal model hilident identified from several inputs and outputs, as python-control objects',
        "(written by hilident export).",
        "",
        f"Source: {doc['source']}",
        "s in rad/s; dt in s; inputs, outputs and their units as named below.",
        '"""',
        "",
        "import control",
    ]


def _plant_script(doc: dict, plant: dict) -> list[str]:
    cont, disc = plant["continuous"], plant["discrete"]
    lines = [
        '"""The plant model hilident identified, as python-control objects (written by hilident export).',
        "",
        f"Source: {doc['source']}",
        f"Input: torque, N*m; output: {plant['output'] or 'the plant output'}, {plant['output_unit']}; "
        "s in rad/s; dt in s.",
        '"""',
        "",
        "import control",
        "",
        f"tf = control.tf({cont['tf']['num']!r}, {cont['tf']['den']!r})",
        "ss = control.ss({A!r}, {B!r}, {C!r}, {D!r})".format(**cont["ss"]),
    ]
    if disc is not None:
        lines += [
            f"dt = {disc['dt_s']!r}  # s: {disc['sample_rate_hz']!r} Hz, {disc['rate_source']}",
            f"tf_discrete = control.tf({disc['tf']['num']!r}, {disc['tf']['den']!r}, dt)",
            "ss_discrete = control.ss({A!r}, {B!r}, {C!r}, {D!r}, dt)".format(**disc["ss"]),
        ]
    return lines


def write_control(doc: dict, out: Path) -> None:
    """The python-control form as a script (:func:`control_script`); refused without python-control."""
    _control()
    script = control_script(doc)
    try:
        out.write_text(script)
    except OSError as exc:
        raise UsageError(f"--out {out}: cannot write it: {exc}") from None


def run_export(
    source: str | Path, fmt: str, out: str | Path | None = None, rate_hz: float | None = None, axis: str = "x"
) -> Path:
    """``hilident export SOURCE --format FMT [--out FILE] [--rate-hz RATE] [--axis AXIS]``; returns the file
    written.

    The default file is ``model.json``, ``model.mat`` or ``model_control.py`` beside the summary; the input
    shaper formats (:mod:`hilident.io.shaper_export`) write ``input_shaper.cfg``, ``.gcode``, ``.json`` or
    ``input_shaper_schedule.csv`` for ``axis``.
    """
    formats = {**FORMATS, **SHAPER_FORMATS}
    if fmt not in formats:
        raise UsageError(f"--format {fmt}: one of {', '.join(formats)}")
    summary, path = load_summary(source)
    target = Path(out) if out else path.parent / formats[fmt]
    if target.is_dir():
        raise UsageError(f"--out {target}: is a folder; give a file name")
    if fmt in SHAPER_FORMATS:
        write_shaper(fmt, summary, str(path), target, axis)
        return target
    doc = export_document(summary, rate_hz, path)
    if fmt == "python-control":
        write_control(doc, target)
    elif fmt == "json":
        write_json(doc, target)
    else:
        write_mat(doc, target)
    return target
