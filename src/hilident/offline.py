"""``hilident identify``: the identification pipeline on a recording made earlier or elsewhere.

No device is touched. The recording is read and checked
(:mod:`hilident.datafile`: gaps are found, never spliced over; only whole
gap-free excitation periods or the longest gap-free stretch are analysed,
and ``summary.json["data"]`` says which), then the same steps as a bench run
follow:
frequency response with coherence, resonances, notch design for a filter rate
given in the configuration, and, when ``[model].kind`` asks for it, a grey-box
fit with parameter standard deviations and fit %. ``summary.json`` has the same
keys as after ``hilident run`` (upload and verification stay empty).
"""

from __future__ import annotations

import time
from pathlib import Path


from hilident import __version__, pipeline, report
from hilident.config import Config
from hilident.datafile import Dataset, load_dataset
from hilident.errors import ConfigError
from hilident.ident.frfquality import excited_band


def _band(cfg: Config, ds: Dataset) -> tuple[float, float]:
    """``[identification]`` band, or where the input carries power (within 20 dB of its peak)."""
    ic = cfg.identification
    u = ds.signals.get("excitation", ds.signals["torque"])
    segment = min(int(round(ic.segment_s * ds.sample_rate_hz)), len(u) // 2)
    lo, hi = excited_band(u, ds.sample_rate_hz, segment)
    return ic.f_min_hz or max(lo, 2.0 / (len(ds) / ds.sample_rate_hz)), ic.f_max_hz or min(hi, 0.4 * ds.sample_rate_hz)


def fit_model(cfg: Config, ds: Dataset, validation: Dataset | None = None):
    """The grey-box model of ``[model]`` fitted to the data and validated (None for ``kind = "none"``).

    ``validation`` is a separate record of the same axis; without it the last
    ``[model].holdout`` of the data validates the fit.
    """
    if cfg.model.kind == "none":
        return None
    for d, key in ((ds, "data.position"), (validation, "data.position")):
        if d is not None and "position" not in d.signals:
            raise ConfigError(key, f"a {cfg.model.kind} fit needs the position column ({d.source})", cfg.source)
    # a time-domain fit runs its filters along the record: it must not cross a lost block
    ds = ds.longest_segment()
    records = None
    if validation is not None:
        validation = validation.longest_segment()
        records = {Path(validation.source).name: (validation.signals["torque"], validation.signals["position"])}
    return pipeline.fit_greybox(cfg.model, ds.signals["torque"], ds.signals["position"], ds.sample_rate_hz, records)


def identify_recording(cfg: Config, data_path: str | Path, out_dir: str | Path, progress=None,
                       validation_path: str | Path | None = None) -> dict:
    """Identify the plant in ``data_path``; writes ``summary.json`` and plots into ``out_dir``.

    ``validation_path`` is a second recording of the same axis (same ``[data]``
    mapping) on which the grey-box model is validated.
    """
    started = time.monotonic()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    say = progress.step if progress else (lambda message: None)
    ds = load_dataset(data_path, cfg.data, cfg.source)
    validation = load_dataset(validation_path, cfg.data, cfg.source) if validation_path else None
    if validation is not None and abs(validation.sample_rate_hz - ds.sample_rate_hz) > 1e-6 * ds.sample_rate_hz:
        raise ConfigError("data.sample_rate_hz", f"the validation record runs at {validation.sample_rate_hz:g} Hz, "
                          f"the data at {ds.sample_rate_hz:g} Hz", cfg.source)
    warnings = list(ds.notes) + ([f"validation: {n}" for n in validation.notes] if validation is not None else [])
    s = ds.signals
    if cfg.data.closed_loop and "excitation" not in s:
        warnings.append(
            "closed-loop data without an excitation column: the torque-to-output estimate is biased where "
            "the controller feeds noise back (give [data].excitation to use the excitation as reference)"
        )
    used = ds.info.get("used_rows", len(ds))
    rows = ds.info.get("rows", len(ds))
    say(f"{ds.source}: {used} of {rows} samples at {ds.sample_rate_hz:g} Hz"
        + (f" in {ds.info['segments']} gap-free segment(s)" if ds.info.get("segments", 1) > 1 else ""))
    band = _band(cfg, ds)
    plant = pipeline.identify_plant(
        s.get("excitation", s["torque"]), s["torque"], s["output"], s["velocity"], ds.sample_rate_hz,
        cfg.identification, band, period_samples=ds.period_samples,
    )
    warnings += plant.warnings
    slots = list(range(max(cfg.identification.max_resonances, 1)))
    designs = pipeline.design_notches(plant.resonances, cfg.notch, cfg.model.filter_rate_hz, slots) if cfg.notch.enabled else []
    model = fit_model(cfg, ds, validation)
    if model is not None:
        if len(ds.segments) > 1:
            longest = max(b - a for a, b in ds.segments)
            warnings.append(f"{cfg.model.kind} fitted to the longest gap-free stretch ({longest} samples): "
                            "a time-domain fit must not run across a lost block")
        warnings += list(model.warnings)
        if cfg.data.closed_loop:
            warnings.append(
                f"{cfg.model.kind} fitted to closed-loop data: noise fed back through the controller biases "
                "least squares; compare with an open-loop record"
            )
    summary = {
        "hilident_version": __version__,
        "config": cfg.source,
        "data": {"file": ds.source, "samples": len(ds), "sample_rate_hz": ds.sample_rate_hz, **ds.info},
        "resonances": pipeline.resonance_records(plant.resonances),
        "friction": None,
        "model": None if model is None else model.to_dict(),
        "plant_model": plant.model.to_dict() if plant.model else None,
        "measurement": plant.quality,
        "notch_filters": pipeline.notch_records(designs),
        "upload": {"written": False, "verified_readback": False, "slots": []},
        "verification": {"peak_reduction_db": None, "resonances": []},
        "stream": {"samples": len(ds), "lost_frames": 0, "lost_blocks": 0,
                   "lost_samples": ds.info.get("missing_samples", 0), "corrupt_frames": 0, "out_of_order": 0,
                   "underruns": 0, "board_dropped_blocks": 0},
        "elapsed_s": time.monotonic() - started,
        "warnings": warnings,
    }
    report.write_summary(out / "summary.json", summary)
    notch = pipeline.notch_chain_response(designs, plant.plant.frequency_hz)
    report.plot_bode(out / "bode.png", [("plant (input to output)", plant.plant)], resonances=plant.resonances,
                     notch_response=notch, coherence_threshold=cfg.identification.coherence_threshold,
                     **pipeline.bode_extras(plant))
    return summary
