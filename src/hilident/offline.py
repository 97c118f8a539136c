"""``hilident identify``: the identification pipeline on a recording made earlier or elsewhere.

No device is touched. The recording is read and checked
(:mod:`hilident.datafile`), then the same steps as a bench run follow:
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
from hilident.ident import greybox


def _band(cfg: Config, ds: Dataset) -> tuple[float, float]:
    ic = cfg.identification
    lo = ic.f_min_hz or 2.0 / (len(ds) / ds.sample_rate_hz)
    hi = ic.f_max_hz or 0.4 * ds.sample_rate_hz
    return lo, hi


def fit_model(cfg: Config, ds: Dataset):
    """The grey-box model of ``[model]`` fitted to the data (None for ``kind = "none"``)."""
    m = cfg.model
    if m.kind == "none":
        return None
    if "position" not in ds.signals:
        from hilident.errors import ConfigError

        raise ConfigError("data.position", f"a {m.kind} fit needs the position column", cfg.source)
    force = m.c * ds.signals["torque"]
    cutoff = m.cutoff_hz or ds.sample_rate_hz / 10.0
    if m.kind == "mass_spring_damper":
        return greybox.fit_mass_spring_damper(force, ds.signals["position"], ds.sample_rate_hz, cutoff,
                                              input_hold=m.input_hold)
    return greybox.fit_rigid_axis(ds.signals["position"], force, ds.sample_rate_hz, cutoff, input_hold=m.input_hold)


def identify_recording(cfg: Config, data_path: str | Path, out_dir: str | Path, progress=None) -> dict:
    """Identify the plant in ``data_path``; writes ``summary.json`` and plots into ``out_dir``."""
    started = time.monotonic()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    say = progress.step if progress else (lambda message: None)
    ds = load_dataset(data_path, cfg.data, cfg.source)
    warnings = list(ds.notes)
    s = ds.signals
    if cfg.data.closed_loop and "excitation" not in s:
        warnings.append(
            "closed-loop data without an excitation column: the torque-to-output estimate is biased where "
            "the controller feeds noise back (give [data].excitation to use the excitation as reference)"
        )
    say(f"{ds.source}: {len(ds)} samples at {ds.sample_rate_hz:g} Hz")
    band = _band(cfg, ds)
    plant = pipeline.identify_plant(
        s.get("excitation", s["torque"]), s["torque"], s["output"], s["velocity"], ds.sample_rate_hz,
        cfg.identification, band,
    )
    warnings += plant.warnings
    slots = list(range(max(cfg.identification.max_resonances, 1)))
    designs = pipeline.design_notches(plant.resonances, cfg.notch, cfg.model.filter_rate_hz, slots) if cfg.notch.enabled else []
    model = fit_model(cfg, ds)
    if model is not None:
        warnings += list(model.warnings)
        if cfg.data.closed_loop:
            warnings.append(
                f"{cfg.model.kind} fitted to closed-loop data: noise fed back through the controller biases "
                "least squares; compare with an open-loop record"
            )
    summary = {
        "hilident_version": __version__,
        "config": cfg.source,
        "data": {"file": ds.source, "samples": len(ds), "sample_rate_hz": ds.sample_rate_hz},
        "resonances": pipeline.resonance_records(plant.resonances),
        "friction": None,
        "model": None if model is None else {"kind": cfg.model.kind, **model.to_dict()},
        "notch_filters": pipeline.notch_records(designs),
        "upload": {"written": False, "verified_readback": False, "slots": []},
        "verification": {"peak_reduction_db": None, "resonances": []},
        "stream": {"samples": len(ds), "lost_frames": 0, "lost_blocks": 0, "lost_samples": 0, "corrupt_frames": 0,
                   "out_of_order": 0, "underruns": 0, "board_dropped_blocks": 0},
        "elapsed_s": time.monotonic() - started,
        "warnings": warnings,
    }
    report.write_summary(out / "summary.json", summary)
    notch = pipeline.notch_chain_response(designs, plant.plant.frequency_hz)
    report.plot_bode(out / "bode.png", [("plant (input to output)", plant.plant)], resonances=plant.resonances,
                     notch_response=notch, coherence_threshold=cfg.identification.coherence_threshold)
    return summary
