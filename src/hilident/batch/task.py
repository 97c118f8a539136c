"""One recording in, one table row out: the task a Dask worker (or the plain loop) runs. It never raises.

A row is a plain dict of strings, floats and ints (:data:`hilident.batch.table.COLUMNS`
lists them with their types): the recording's identity, the figures of its
identification, and for a failure the error. Only the path travels to the
worker, so a task holds one recording at a time.
"""

from __future__ import annotations

import json
import math
import os
import socket
import sys
import time
from typing import Any

from hilident import __version__
from hilident.batch.identity import recording_identity

NAN = math.nan

#: Friction columns: column -> the parameter of ``summary.json["friction"]["params"]``.
FRICTION_COLUMNS = {
    "friction_fc_nm": "Fc",
    "friction_fs_nm": "Fs",
    "friction_fv_nm_per_mps": "Fv",
    "friction_vs_mps": "vs",
}


def blank_row(path: str, content_sha256: str, config_sha256: str) -> dict[str, Any]:
    """The row of a recording nothing is known of yet: NaN figures, empty texts, status ``"failed"``."""
    return {
        "path": str(path),
        "content_sha256": content_sha256,
        "config_sha256": config_sha256,
        "status": "failed",
        "error": "",
        "error_type": "",
        "failed_step": "",
        "axis": "",
        "device_name": "",
        "device_serial": "",
        "time_utc": "",
        "time_source": "",
        "sample_rate_hz": NAN,
        "duration_s": NAN,
        "n_resonances": 0,
        "frequency_hz": NAN,
        "frequency_ci95_hz": NAN,
        "damping_ratio": NAN,
        "damping_ci95": NAN,
        "resonances_json": "[]",
        "friction_model": "",
        **dict.fromkeys(FRICTION_COLUMNS, NAN),
        "model_fit_percent": NAN,
        "warnings": "[]",
        "n_warnings": 0,
        "hilident_version": __version__,
        "elapsed_s": NAN,
        "worker": "",
        "worker_peak_rss_mib": NAN,
    }


def peak_rss_mib() -> float:
    """The peak resident memory of this process so far, MiB (NaN where the system does not say)."""
    try:
        import resource
    except ImportError:  # not on Windows
        return NAN
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0  # bytes on macOS, KiB on Linux


def _number(value: Any) -> float:
    """A float, NaN for None or anything that is not a number."""
    try:
        return NAN if value is None or isinstance(value, bool) else float(value)
    except (TypeError, ValueError):
        return NAN


def summary_figures(summary: dict) -> dict[str, Any]:
    """The row's figures from an ``identify`` summary (complete, or up to a failed step).

    ``duration_s`` is the whole recording's (its rows over the rate). The
    resonance columns are those of the lowest resonance found (NaN: none);
    ``resonances_json`` holds all of them as ``summary.json`` does;
    ``model_fit_percent`` is the ``[model]`` grey-box fit on the estimation
    data (NaN without one).
    """
    data = summary.get("data") or {}
    rate = _number(data.get("sample_rate_hz"))
    samples = _number(data.get("rows", data.get("samples")))  # the whole recording, not only the part analysed
    resonances = sorted(summary.get("resonances") or [], key=lambda r: _number(r.get("frequency_hz")))
    lowest = resonances[0] if resonances else {}
    friction = summary.get("friction") or {}
    params = friction.get("params") or {}
    model = summary.get("model") or {}
    warnings = [str(w) for w in summary.get("warnings") or []]
    return {
        "sample_rate_hz": rate,
        "duration_s": samples / rate if rate > 0 else NAN,
        "n_resonances": len(resonances),
        **{
            key: _number(lowest.get(key))
            for key in ("frequency_hz", "frequency_ci95_hz", "damping_ratio", "damping_ci95")
        },
        "resonances_json": json.dumps(resonances, allow_nan=True, default=str),
        "friction_model": str(friction.get("model") or ""),
        **{column: _number(params.get(name)) for column, name in FRICTION_COLUMNS.items()},
        "model_fit_percent": _number((model.get("estimation") or {}).get("fit_percent")),
        "warnings": json.dumps(warnings),
        "n_warnings": len(warnings),
        "failed_step": str(summary.get("failed_step") or ""),
    }


def fail(row: dict[str, Any], exc: BaseException) -> dict[str, Any]:
    """``row`` marked failed with ``exc``: a hilident error's own text; for any other, its type and text."""
    from hilident.errors import HilidentError

    typed = isinstance(exc, HilidentError)
    row.update(
        status="failed", error_type=type(exc).__name__, error=str(exc) if typed else f"{type(exc).__name__}: {exc}"
    )
    return row


def identify_task(
    path: str, content_sha256: str, config_text: str | None, config_source: str, config_sha256: str
) -> tuple[dict[str, Any], dict | None]:
    """Identify the recording at ``path`` as ``hilident identify`` does (no plots, no files): its row and summary.

    Parameters
    ----------
    path : str
        The recording, as the worker sees it.
    content_sha256, config_sha256 : str
        The keys of the row (computed by the caller, which skips rows the table holds).
    config_text, config_source : str or None, str
        The ``--config`` file's text and name (None: the recording's own configuration).

    Returns
    -------
    (dict, dict or None)
        The row, ``status`` ``"ok"``, or ``"failed"`` with ``error`` and ``error_type`` (and the figures
        of the steps that succeeded); and the ``identify`` summary (None when the data could not be
        read). It never raises.
    """
    started = time.monotonic()
    row = blank_row(path, content_sha256, config_sha256)
    summary = None
    try:
        row.update(recording_identity(path))
        from hilident.config.tables import parse_config
        from hilident.session.offline import analyse_recording

        cfg = parse_config(config_text, config_source) if config_text is not None else None
        analysis = analyse_recording(cfg, path)
        summary = analysis.summary
        row.update(summary_figures(summary))
        if analysis.error is not None:
            fail(row, analysis.error)
        else:
            row.update(status="ok")
    except Exception as exc:  # one recording must never stop the batch: whatever went wrong becomes its row
        fail(row, exc)
    row["elapsed_s"] = time.monotonic() - started
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    row["worker_peak_rss_mib"] = peak_rss_mib()
    return row, summary


def identify_row(
    path: str, content_sha256: str, config_text: str | None, config_source: str, config_sha256: str
) -> dict[str, Any]:
    """The row of :func:`identify_task` alone."""
    return identify_task(path, content_sha256, config_text, config_source, config_sha256)[0]
