"""``hilident identify``: the identification pipeline on a recording made earlier or elsewhere.

No device is touched. The recording is read and checked
(:mod:`hilident.datafile`: gaps are found, never spliced over; only whole
gap-free excitation periods or the longest gap-free stretch are analysed,
and ``summary.json["data"]`` says which), then the same steps as a bench run
follow:
frequency response with coherence, resonances, notch design for a filter rate
given in the configuration, and, when ``[model].kind`` asks for it, a grey-box
fit with parameter standard deviations, fit % and relative error.
``summary.json`` has the same keys as after ``hilident run`` (upload and
verification stay empty).

A hilident recording describes itself: its attributes hold the run's
configuration, the excitation mode and period and the channels, so
:func:`identify_recording` needs no configuration for it and analyses it as
the run did (the recorded excitation as reference, whole periods, the band of
the run's excitation). A configuration given as well overrides table by table;
``[data]`` keys it leaves out follow the recorded channels.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hilident import html_report
from hilident.config.schema import build_table
from hilident.config.tables import Config, DataConfig, ModelConfig, parse_config, parse_toml
from hilident.datafile import RATE_TOLERANCE, Dataset, RunInfo, load_dataset, read_run_info
from hilident.datafile.mapping import channel_keys
from hilident.errors import ConfigError, DataError, HilidentError, UsageError
from hilident.io.serialise import write_json
from hilident.io.summary import Summary, friction_summary
from hilident.lazy import lazy_module
from hilident.plots import figures as report
from hilident.plots.common import plot_title
from hilident.plots.stabilisation import STABILISATION_PNG, plot_stabilisation
from hilident.units import recorded_units

if TYPE_CHECKING:
    from hilident.ident.frequency import FrequencyResponse
    from hilident.pipeline import friction as pipeline_friction
    from hilident.pipeline import greybox as pipeline_greybox
    from hilident.pipeline import measurement as pipeline_measurement
    from hilident.pipeline import notches as pipeline_notches
    from hilident.pipeline import plant as pipeline_plant
    from hilident.pipeline import plant_model as pipeline_plant_model
else:
    #: The analysis (scipy), imported once a recording has been read: a missing file is reported without it.
    pipeline_friction = lazy_module("hilident.pipeline.friction")
    pipeline_greybox = lazy_module("hilident.pipeline.greybox")
    pipeline_measurement = lazy_module("hilident.pipeline.measurement")
    pipeline_notches = lazy_module("hilident.pipeline.notches")
    pipeline_plant = lazy_module("hilident.pipeline.plant")
    pipeline_plant_model = lazy_module("hilident.pipeline.plant_model")

#: Channel a hilident recording holds for each ``[data]`` signal.
RUN_CHANNELS = {"torque": "torque_nm", "velocity": "velocity_mps", "position": "position_m", "excitation": "excitation"}

#: Excitation lines of a one-period record: within this many dB of the strongest.
_LINE_FLOOR_DB = 40.0
#: A sparser grid of those lines (every 2nd, 3rd or 4th line, e.g. the odd lines of an odd multisine or sweep)
#: is the excitation's when it holds this share of their power: the other lines carry noise, not excitation.
_GRID_POWER_SHARE = 0.99
#: Non-excited lines at most this many lines from an excited one measure its noise.
_NOISE_NEIGHBOURS = 2


# ---------------------------------------------------------------------- configuration


def _explicit(cfg: Config | None, table: str) -> dict:
    """The keys of ``[table]`` the configuration's file sets (an empty dict when none, or no file)."""
    if cfg is None or not cfg.text:
        return {}
    value = parse_toml(cfg.text, cfg.source).get(table, {})
    return value if isinstance(value, dict) else {}


def resolve_config(cfg: Config | None, data_path: str | Path) -> tuple[Config, RunInfo | None]:
    """The configuration ``identify`` runs with, and the recording's run attributes (None: not a hilident run).

    Without ``cfg`` the recording must be a hilident run file holding its
    configuration. With both, the tables ``cfg``'s file sets win and the
    others come from the recording's configuration.

    Raises
    ------
    UsageError
        No configuration and none in the file.
    DataError
        No such file, or an empty one.
    """
    if not Path(data_path).is_file():
        raise DataError(f"{data_path}: no such file")
    if Path(data_path).stat().st_size == 0:  # before guessing its format: an empty file is no format at all
        raise DataError(f"{data_path}: empty file (0 bytes): nothing was recorded")
    fmt = cfg.data.format if cfg is not None else "auto"
    info = read_run_info(data_path, fmt)
    if info is None or not info.config_toml.strip():
        if cfg is None:
            what = "holds no stored configuration" if info is not None else "is not a hilident recording"
            raise UsageError(f"{data_path} {what}: give --config with a [data] table naming its columns and rate")
        return cfg, info
    source = f"{data_path} (config_toml attribute)"
    if cfg is None:
        return parse_config(info.config_toml, source), info
    if not cfg.text:
        return cfg, info
    merged = {**parse_toml(info.config_toml, source), **parse_toml(cfg.text, cfg.source)}
    return dataclasses.replace(build_table(Config, merged, "", cfg.source), source=cfg.source, text=cfg.text), info


def model_for(cfg: Config, info: RunInfo | None) -> ModelConfig:
    """``[model]`` for this recording: ``input_hold = "zoh"`` for a hilident open-loop torque run unless set
    (see :func:`model_for_mode`)."""
    return model_for_mode(cfg, info.mode if info is not None else "")


def model_for_mode(cfg: Config, mode: str) -> ModelConfig:
    """``[model]`` for a run in ``mode``: ``input_hold = "zoh"`` for an open-loop torque run unless the file sets it.

    Measured data are point samples (``sample``, the default); in an
    open-loop torque run the recorded torque is the command the drive held
    over each sample period.
    """
    if mode == "torque" and "input_hold" not in _explicit(cfg, "model"):
        return dataclasses.replace(cfg.model, input_hold="zoh")
    return cfg.model


def data_mapping(cfg: Config, info: RunInfo | None) -> DataConfig:
    """``[data]`` for this recording: the run's channels for keys not set, and ``[identification].output`` honoured.

    The response column is ``data.output`` when set; else the channel (or
    the ``[data]`` signal: ``position``, ``velocity``) ``[identification]
    output`` names when the recording holds it or the configuration sets
    it; else the velocity.
    """
    explicit = _explicit(cfg, "data")
    data = cfg.data
    channels = set(info.channels) if info is not None else None
    if info is not None and channels is not None:
        fill: dict[str, Any] = {
            key: (ch if ch in channels else "") for key, ch in RUN_CHANNELS.items() if key not in explicit
        }
        defaults = {"format": "hilident", "closed_loop": info.mode not in ("", "torque")}  # a loop held the axis
        fill.update({key: value for key, value in defaults.items() if key not in explicit})
        data = dataclasses.replace(data, **fill)
    if data.output:
        return data
    out = cfg.identification.output
    set_here = "output" in _explicit(cfg, "identification") or (channels is not None and out in channels)
    if not set_here:
        return data
    if out in ("position", "velocity"):
        column = getattr(data, out)
        if not column:
            raise ConfigError("identification.output", f"is {out!r} but data.{out} names no column", cfg.source)
        return dataclasses.replace(data, output=column, output_scale=getattr(data, f"{out}_scale"))
    if out in (data.velocity, data.position):
        key = "velocity" if out == data.velocity else "position"
        return dataclasses.replace(data, output=out, output_scale=getattr(data, f"{key}_scale"))
    return dataclasses.replace(data, output=out)


# ---------------------------------------------------------------------- analysis


def _band(cfg: Config, ds: Dataset) -> tuple[float, float]:
    """``[identification]`` band, or where the input carries power (within 20 dB of its peak)."""
    ic = cfg.identification
    u = ds.signals.get("excitation", ds.signals["torque"])
    segment = min(int(round(ic.segment_s * ds.sample_rate_hz)), len(u) // 2)
    if ds.period_samples and len(u) >= ds.period_samples:
        segment = ds.period_samples
    from hilident.ident.frfquality import excited_band

    lo, hi = excited_band(u, ds.sample_rate_hz, segment)
    return ic.f_min_hz or max(lo, 2.0 / (len(ds) / ds.sample_rate_hz)), ic.f_max_hz or min(hi, 0.4 * ds.sample_rate_hz)


def _run_excitation(cfg: Config, info: RunInfo | None, ds: Dataset):
    """The excitation the recorded run played (band and excited lines), None when it cannot be rebuilt."""
    if info is None or info.experiment not in ("identification", "verification") or not info.config_toml:
        return None
    if abs(cfg.run.sample_rate_hz - ds.sample_rate_hz) > RATE_TOLERANCE * ds.sample_rate_hz:
        return None
    from hilident.session.excitation import build_excitation

    try:
        exc = build_excitation(cfg)
    except HilidentError:
        return None
    if exc.period_samples == ds.period_samples:
        return exc
    if not ds.period_samples:  # analysed as a stretch (too few whole periods): the band still holds
        return dataclasses.replace(exc, excited_bins=None)
    return None  # the stored configuration describes another excitation than the one recorded


def run_friction(cfg: Config, info: RunInfo | None, data_path: str | Path, warnings: list[str]):
    """The friction the run removed from the torque: refitted from ``friction.h5`` beside the recording.

    None when the recording is not a hilident identification or verification
    run, or no friction test was recorded beside it (a note says so when one
    should have been).
    """
    if info is None or info.experiment not in ("identification", "verification"):
        return None
    path = Path(data_path).with_name("friction.h5")
    test = read_run_info(path) if path.is_file() else None
    if test is None or test.experiment != "friction":
        if cfg.friction_test.enabled:
            warnings.append(
                f"no friction test recorded beside {Path(data_path).name} (friction.h5): the torque "
                "is used as recorded, with friction in it (the run removed its friction fit)"
            )
        return None
    try:
        from hilident.session.friction_test import refit_recordings  # every round the run played, pooled

        result = refit_recordings(path, cfg.friction_test.model)
        warnings += result.warnings
        return result
    except HilidentError as exc:
        warnings.append(f"friction test {path}: {exc}; the torque is used as recorded")
        return None


def friction_record(friction) -> dict | None:
    """``summary.json["friction"]`` as :class:`hilident.session.run.Session` writes it."""
    return friction_summary(friction)


def excitation_lines(power: np.ndarray) -> tuple[np.ndarray, int]:
    """The DFT lines a periodic excitation holds, from the power of one period's DFT.

    Lines within :data:`_LINE_FLOOR_DB` of the strongest (DC excluded); of
    those, the sparsest grid of every ``m``-th line (``m`` = 2, 3, 4, any
    offset) that holds :data:`_GRID_POWER_SHARE` of their power, when one
    does. A measured input has noise, transients and distortion at the lines
    the design leaves out (the even lines of an odd multisine), so a
    threshold alone takes them for excitation.

    Parameters
    ----------
    power : ndarray
        ``|DFT|^2`` of one period of the reference, lines 0 .. N/2.

    Returns
    -------
    (ndarray of int, int)
        The excited lines and their spacing, in lines (the greatest common
        divisor of their differences; 1: no line left out between them).
    """
    power = np.array(power, dtype=float)
    power[0] = 0.0
    k = np.flatnonzero(power > power.max() * 10 ** (-_LINE_FLOOR_DB / 10))
    best = k
    for m in (2, 3, 4):
        for offset in range(m):
            on = k[k % m == offset]
            if on.size < best.size and power[on].sum() >= _GRID_POWER_SHARE * power[k].sum():
                best = on
    return best, int(np.gcd.reduce(np.diff(best))) if best.size > 1 else 1


def line_coherence(U: np.ndarray, Y: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Coherence of ``Y / U`` at the excited lines ``k``, from the noise at the non-excited lines beside them.

    With ``N_U``, ``N_Y`` the mean power of the non-excited lines within
    :data:`_NOISE_NEIGHBOURS` lines of line ``k``, the scatter of ``H`` is
    ``var H = (N_Y + |H|^2 N_U) / |U|^2`` and the coherence is ``S / (S +
    N_Y + |H|^2 N_U)`` with ``S = |Y|^2 - N_Y`` the output power without
    its noise: the value whose Welch variance formula gives that scatter for
    one average. Those lines also hold transients and distortion, so it is a
    lower bound.

    Returns
    -------
    ndarray
        One value per line in ``k``; all NaN when some excited line has no
        non-excited line that close (every line excited).
    """
    quiet = np.setdiff1d(np.arange(1, len(U)), k)
    near = np.abs(k[:, None] - quiet[None, :]) <= _NOISE_NEIGHBOURS
    count = near.sum(axis=1)
    if k.size == 0 or not count.all():
        return np.full(k.size, np.nan)
    noise_u = (near * np.abs(U[quiet]) ** 2).sum(axis=1) / count
    noise_y = (near * np.abs(Y[quiet]) ** 2).sum(axis=1) / count
    # |Y|^2 holds the output noise too: take it out of the signal, which would otherwise be biased up by it
    signal = np.maximum(np.abs(Y[k]) ** 2 - noise_y, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        h2 = np.abs(Y[k] / U[k]) ** 2
        return np.nan_to_num(signal / (signal + noise_y + h2 * noise_u), nan=0.0)


def _one_period_plant(r, u, y, sample_rate_hz: float, period: int, cfg, band_hz) -> pipeline_plant.PlantResult:
    """A record of exactly one excitation period: the full-record DFT at the excited lines.

    A periodic excitation in steady state does not leak, so the DFT of one
    whole period is exact at its lines. With a single period there is no
    average; when the excitation leaves lines out between its lines, their
    noise gives each line a coherence (:func:`line_coherence`) and the
    resonances and model are judged by it as after a run; otherwise
    resonances are taken on prominence alone.
    """
    from hilident.ident.frequency import FrequencyResponse

    n = len(r) // period * period
    R, U, Y = (np.fft.rfft(np.asarray(x[:n], float) - np.mean(x[:n])) for x in (r, u, y))
    k, step = excitation_lines(np.abs(R) ** 2)
    f = k * sample_rate_hz / n
    coherence, loop_coherence = line_coherence(U, Y, k), line_coherence(R, Y, k)
    with np.errstate(divide="ignore", invalid="ignore"):
        plant = FrequencyResponse(f, Y[k] / U[k], coherence, 1, "periodic")
        loop = FrequencyResponse(f, Y[k] / R[k], loop_coherence, 1, "periodic")
    grid = f" (one line in {step})" if step > 1 else ""
    head = (
        f"one excitation period ({period} samples) recorded: its DFT at the {k.size} excited lines{grid} is "
        "leakage-free but has no average"
    )
    if np.isfinite(coherence).all():
        # how the lines were judged, with nothing to change: a note
        notes = [
            head + "; the noise of each line is taken from the non-excited lines beside it (coherence "
            "from that, a lower bound where they hold transients or distortion too)"
        ]
        screened = pipeline_plant.resonances_and_model(plant, cfg, band_hz)
        resonances, rejected, model = screened.resonances, screened.rejected, screened.model
        warnings = list(screened.warnings)
        notes += screened.notes
    else:
        warnings = [
            head + ", so no coherence; resonances are judged on prominence alone (record two or more "
            "periods to judge the noise)"
        ]
        resonances, rejected, model = _prominent_resonances(plant, cfg, band_hz, warnings)
        notes = []
    antires = [hz for hz, _ in model.roots.antiresonances] if model else []
    quality, more, sampling_notes = pipeline_measurement.measurement_quality(
        plant, resonances, r, sample_rate_hz, band_hz, period, antires
    )
    quality["one_period"] = {
        "excited_lines": int(k.size),
        "line_step": step,
        "noise_from_non_excited_lines": bool(np.isfinite(coherence).all()),
    }
    return pipeline_plant.PlantResult(
        plant=plant,
        loop=loop,
        resonances=resonances,
        warnings=warnings + more,
        model=model,
        quality=quality,
        rejected=rejected,
        notes=notes + sampling_notes,
    )


def _prominent_resonances(plant: FrequencyResponse, cfg, band_hz, warnings: list[str]):
    """Resonances on prominence alone and the transfer-function fit, for a response without coherence."""
    from hilident.ident.resonance import find_resonances

    resonances = find_resonances(
        plant,
        coherence_threshold=None,
        min_prominence_db=cfg.min_prominence_db,
        max_count=max(cfg.max_resonances, 1),
        band_hz=band_hz,
    )
    model = None
    if cfg.model_max_order:
        try:
            model = pipeline_plant_model.fit_plant_model(
                plant,
                band_hz,
                cfg.model_max_order,
                0.0,
                cfg.model_order,
                cfg.model_relative_degree,
                cfg.model_integrators,
                cfg.model_criterion,
            )
        except (DataError, ConfigError) as exc:
            warnings.append(f"transfer-function fit: {exc}")
    return resonances, [], model


def _identify(cfg: Config, ds: Dataset, band, excited_bins, friction=None) -> pipeline_plant.PlantResult:
    s = ds.signals
    r = s.get("excitation", s["torque"])
    velocity = s.get("velocity", s["output"])
    period = ds.period_samples
    if period and period <= len(ds) < 2 * period:
        return _one_period_plant(r, s["torque"], s["output"], ds.sample_rate_hz, period, cfg.identification, band)
    return pipeline_plant.identify_plant(
        r,
        s["torque"],
        s["output"],
        velocity,
        ds.sample_rate_hz,
        cfg.identification,
        band,
        friction=friction.fit.params if friction is not None else None,
        velocity_deadband_mps=cfg.friction_test.velocity_deadband_mps,
        friction_slowest_mps=friction.slowest_mps if friction is not None else 0.0,
        period_samples=period,
        excited_bins=excited_bins,
    )


# ---------------------------------------------------------------------- grey box


def fit_model(cfg: Config, ds: Dataset, validation: Dataset | None = None):
    """The grey-box model of ``[model]`` fitted to the data and validated (None for ``kind = "none"``).

    ``validation`` is a separate record of the same axis; without it the last
    ``[model].holdout`` of the data validates the fit.
    """
    if cfg.model.kind == "none":
        return None
    for d in (ds, validation):
        if d is not None and "position" not in d.signals:
            raise ConfigError(
                "data.position", f"a {cfg.model.kind} fit needs the position column ({d.source})", cfg.source
            )
    # a time-domain fit runs its filters along the record: it must not cross a lost block
    ds = ds.longest_segment()
    records = None
    if validation is not None:
        validation = validation.longest_segment()
        records = {Path(validation.source).name: (validation.signals["torque"], validation.signals["position"])}
    return pipeline_greybox.fit_greybox(
        cfg.model, ds.signals["torque"], ds.signals["position"], ds.sample_rate_hz, records
    )


# ---------------------------------------------------------------------- the command


def _check_validation_rate(ds: Dataset, validation: Dataset) -> float:
    """Relative difference of the two records' rates; refused above :data:`RATE_TOLERANCE`."""
    spread = abs(validation.sample_rate_hz - ds.sample_rate_hz) / ds.sample_rate_hz
    if spread > RATE_TOLERANCE:

        def where(d):
            return ", ".join(d.info.get("sample_rates_hz", {})) or "the file"

        raise DataError(
            f"{validation.source} runs at {validation.sample_rate_hz:.9g} Hz (from {where(validation)}), "
            f"{ds.source} at {ds.sample_rate_hz:.9g} Hz (from {where(ds)}): they differ by {spread:.2g} "
            f"(relative; {RATE_TOLERANCE:g} is accepted as one clock); if both were sampled at one "
            "nominal rate, set [data] sample_rate_hz to it"
        )
    return spread


@dataclasses.dataclass
class Analysis:
    """What :func:`analyse_recording` found: ``summary.json`` and what the plots are drawn from.

    Attributes
    ----------
    summary : dict
        ``summary.json`` of ``identify``; with ``failed_step`` and ``error`` when a step failed.
    error : HilidentError or None
        The error of the step that failed after the data were read (None: every step succeeded).
    cfg : Config
        The configuration the recording was analysed with (``[data]`` and ``[model]`` resolved).
    data, validation : Dataset
        The records read (``validation``: None without one).
    state : dict
        The steps' results: ``plant``, ``designs``, ``model``, ``friction``, ``band_hz``.
    """

    summary: dict
    error: HilidentError | None
    cfg: Config
    data: Dataset
    validation: Dataset | None
    state: dict


def analyse_recording(
    cfg: Config | None, data_path: str | Path, progress=None, validation_path: str | Path | None = None
) -> Analysis:
    """The identification of ``data_path`` as ``hilident identify`` does it, writing nothing.

    Errors before the data are read (no such file, no configuration, a
    damaged file) are raised; an error of a later step is returned in
    :attr:`Analysis.error`, with the summary of the steps that succeeded.
    :func:`identify_recording` writes its result; ``hilident batch`` keeps
    its figures.
    """
    started = time.monotonic()
    say = progress.step if progress else (lambda message: None)
    cfg, info = resolve_config(cfg, data_path)
    data_cfg = data_mapping(cfg, info)
    cfg = dataclasses.replace(cfg, data=data_cfg, model=model_for(cfg, info))
    ds = load_dataset(data_path, data_cfg, cfg.source)
    validation = (
        load_dataset(validation_path, data_mapping(cfg, read_run_info(validation_path, data_cfg.format)), cfg.source)
        if validation_path
        else None
    )
    warnings = list(ds.notes) + ([f"validation: {n}" for n in validation.notes] if validation is not None else [])
    data_info = {
        "file": ds.source,
        "samples": len(ds),
        "sample_rate_hz": ds.sample_rate_hz,
        **ds.info,
        "mapping": {
            k: getattr(data_cfg, k)
            for k in ("torque", "velocity", "position", "output", "excitation")
            if getattr(data_cfg, k)
        },
    }
    if info is not None:
        unit = recorded_units(dict(zip(info.channels, info.units, strict=False)), {"mode": info.mode})
        data_info["units"] = {key: unit[col] for key, col in data_info["mapping"].items() if unit.get(col)}
        data_info.update(
            recorded_mode=info.mode,
            recorded_experiment=info.experiment,
            configuration="stored in the recording" if cfg.source.endswith("(config_toml attribute)") else cfg.source,
        )
    if data_cfg.inputs:
        data_info["mapping"] = _channel_mapping(data_cfg)
        say(f"{ds.source}: {len(ds)} samples at {ds.sample_rate_hz:g} Hz, {len(data_cfg.inputs)} inputs")
        return _analyse_channels(cfg, ds, data_info, warnings, started)
    if validation is not None:
        data_info["validation_rate_difference"] = _check_validation_rate(ds, validation)
    if data_cfg.closed_loop and "excitation" not in ds.signals:
        warnings.append(
            "closed-loop data without an excitation column: the torque-to-output estimate is biased where "
            "the controller feeds noise back (give [data].excitation to use the excitation as reference)"
        )
    say(
        f"{ds.source}: {ds.info.get('used_rows', len(ds))} of {ds.info.get('rows', len(ds))} samples at "
        f"{ds.sample_rate_hz:g} Hz"
        + (f" in {ds.info['segments']} gap-free segment(s)" if ds.info.get("segments", 1) > 1 else "")
    )
    state: dict = {"plant": None, "designs": [], "model": None, "friction": None, "data_path": data_path}
    error: HilidentError | None = None
    try:
        _steps(cfg, ds, validation, info, state, warnings)
    except HilidentError as exc:
        error = exc
    summary = _summary(cfg, data_info, state, warnings, started)
    if error is not None:
        summary.update(failed_step=state["step"], error=str(error))
    return Analysis(summary, error, cfg, ds, validation, state)


def _channel_mapping(d) -> dict[str, str]:
    """``inputs[i]`` / ``outputs[j]`` -> column, as ``summary.json["data"]["mapping"]`` lists a mapping."""
    inputs, outputs = channel_keys(d)
    return dict(zip([*inputs, *outputs], [*d.inputs, *d.outputs], strict=True))


def _analyse_channels(cfg: Config, ds: Dataset, data_info: dict, warnings: list[str], started: float) -> Analysis:
    """Several inputs and outputs: their frequency responses at once (:mod:`hilident.pipeline.mimo_identify`);
    no single-input plant, notch or grey-box model."""
    state: dict = {"plant": None, "designs": [], "model": None, "friction": None, "step": "identification"}
    error: HilidentError | None = None
    part = None
    from hilident.pipeline.mimo_identify import identify_channels  # scipy: only once the data are read

    try:
        inputs, outputs = channel_keys(cfg.data)
        u = np.column_stack([ds.signals[k] for k in inputs])
        y = np.column_stack([ds.signals[k] for k in outputs])
        part, state["mimo_response"] = identify_channels(u, y, ds.sample_rate_hz, cfg, ds.source, ds.period_samples)
        warnings += part["warnings"]
    except HilidentError as exc:
        error = exc
    summary = Summary.of_identify(
        config=cfg.source,
        data=data_info,
        plant=None,
        friction=None,
        model=None,
        designs=[],
        notch_skipped_reason="several inputs and outputs ([data] inputs, outputs): no single-input notch design",
        elapsed_s=time.monotonic() - started,
        warnings=warnings,
        mimo=part,
    ).to_dict()
    if error is not None:
        summary.update(failed_step=state["step"], error=str(error))
    return Analysis(summary, error, cfg, ds, None, state)


def identify_recording(
    cfg: Config | None,
    data_path: str | Path,
    out_dir: str | Path,
    progress=None,
    validation_path: str | Path | None = None,
) -> dict:
    """Identify the plant in ``data_path``; writes ``summary.json`` and plots into ``out_dir``.

    ``cfg`` may be None for a hilident recording (its stored configuration is
    used). ``validation_path`` is a second recording of the same axis (same
    ``[data]`` mapping) on which the grey-box model is validated. Once the
    data are read, ``summary.json`` is written whatever step fails after;
    it then names the step (``failed_step``) and the error, and the error is
    raised.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    a = analyse_recording(cfg, data_path, progress, validation_path)
    summary = a.summary
    write_json(out / "summary.json", summary)
    if a.error is not None:
        html_report.write_report_quietly(out)
        raise a.error
    if "mimo" in summary:  # several inputs and outputs: the stabilisation diagram, no single-input plots
        _plot_channels(out, summary, a.state.get("mimo_response"))
        html_report.write_report_quietly(out)
        return summary
    cfg, ds, validation, state = a.cfg, a.data, a.validation, a.state
    plant, designs = state["plant"], state["designs"]
    model = state["model"]
    report.plot_identify(
        out,
        summary,
        plant,
        designs,
        band_hz=state.get("band_hz"),
        coherence_threshold=cfg.identification.coherence_threshold,
        friction=state["friction"],
        model=model,
        model_cfg=cfg.model,
        data=ds.longest_segment() if model else None,
        validation=validation.longest_segment() if model and validation is not None else None,
    )
    html_report.write_report_quietly(out)
    return summary


def _plot_channels(out: Path, summary: dict, response) -> None:
    """``stabilisation.png`` of a record with several inputs and outputs (when the modal estimate gave one):
    the diagram of ``summary["mimo"]`` with the first singular value of the measured ``response``."""
    if not (summary["mimo"] or {}).get("stabilisation"):
        return
    name = Path(str((summary.get("data") or {}).get("file") or "recording")).name
    plot_stabilisation(
        out / STABILISATION_PNG,
        summary["mimo"],
        None if response is None else response.frequency_hz,
        None if response is None else response.response,
        title=plot_title(f"identify {name}", what="Stabilisation"),
    )


def _steps(cfg: Config, ds: Dataset, validation: Dataset | None, info, state: dict, warnings: list[str]) -> None:
    """Frequency response and resonances, notch design, grey-box model; ``state`` keeps what succeeded."""
    state["step"] = "friction"
    state["friction"] = run_friction(cfg, info, state["data_path"], warnings)
    state["step"] = "identification"
    run = _run_excitation(cfg, info, ds)
    ic = cfg.identification
    band = (ic.f_min_hz or run.band_hz[0], ic.f_max_hz or run.band_hz[1]) if run is not None else _band(cfg, ds)
    plant = _identify(cfg, ds, band, run.excited_bins if run is not None else None, state["friction"])
    state["band_hz"] = band
    warnings += plant.warnings
    state["plant"] = plant
    state["step"] = "notch design"
    if cfg.notch.enabled:
        slots = list(range(max(ic.max_resonances, 1)))
        # the same decision as a run's upload; the amplitude advice only for a run's own recording
        e = cfg.excitation
        amplitude = e.amplitude if info is not None and isinstance(e.amplitude, (int, float)) else None
        decision = pipeline_notches.notch_decision(plant, ic.coherence_threshold, e.amplitude_key, amplitude)
        warnings += decision.warnings
        state["notch_skipped_reason"] = decision.skipped_reason
        state["designs"] = pipeline_notches.design_notches(
            decision.resonances, cfg.notch, cfg.model.filter_rate_hz, slots, response=plant.loop
        )
    state["step"] = "model"
    model = fit_model(cfg, ds, validation)
    if model is not None:
        if len(ds.segments) > 1:
            longest = max(b - a for a, b in ds.segments)
            warnings.append(
                f"{cfg.model.kind} fitted to the longest gap-free stretch ({longest} samples): "
                "a time-domain fit must not run across a lost block"
            )
        warnings += list(model.warnings)
        if cfg.data.closed_loop:
            warnings.append(
                f"{cfg.model.kind} fitted to closed-loop data: noise fed back through the controller "
                "biases least squares; compare with an open-loop record"
            )
        state["model"] = model


def _summary(cfg: Config, data_info: dict, state: dict, warnings: list[str], started: float) -> dict:
    return Summary.of_identify(
        config=cfg.source,
        data=data_info,
        plant=state["plant"],
        friction=state["friction"],
        model=state["model"],
        designs=state["designs"],
        notch_skipped_reason=state.get("notch_skipped_reason"),
        elapsed_s=time.monotonic() - started,
        warnings=warnings,
        notes=state["plant"].notes if state["plant"] is not None else [],
    ).to_dict()
