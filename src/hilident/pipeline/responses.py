"""Frequency responses of records through the drive: the loop, pooled records, the filter slots with the plant.

Every signal of a ratio is conditioned alike (:func:`condition_signal`), so
the ratio is left intact; whole periods of a periodic excitation are averaged
without leakage, anything else by Welch's method.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from hilident.config.tables import IdentificationConfig
from hilident.errors import DataError
from hilident.ident import gapped_periods
from hilident.ident.frequency import FrequencyResponse, h1_estimate, periodic_frf
from hilident.ident.preprocess import check_signals, lowpass, remove_drift


def condition_signal(
    x: np.ndarray,
    cfg: IdentificationConfig,
    sample_rate_hz: float,
    period_samples: int | None,
    present: np.ndarray | None = None,
) -> np.ndarray:
    """Optional zero-phase low-pass, then the mean and a slow drift removed
    (:func:`~hilident.ident.preprocess.remove_drift`).

    The same filter on every signal of a ratio leaves the ratio intact. A
    record that misses samples (``present``) is not low-passed (a filter
    cannot run across what does not exist; :func:`gapped_warnings` says so) and
    comes back NaN where they are missing.
    """
    if present is not None:
        return remove_drift(x, period_samples, present=present)
    if cfg.lowpass_hz:
        x = lowpass(x, cfg.lowpass_hz, sample_rate_hz)
    return remove_drift(x, period_samples)


def missing_samples(present) -> np.ndarray | None:
    """``present`` as a bool array when some sample is missing, else None (a whole record)."""
    if present is None:
        return None
    present = np.asarray(present, dtype=bool)
    return None if present.all() else present


def mean_period(x: np.ndarray, present: np.ndarray, period_samples: int) -> np.ndarray:
    """One period of the periodic ``x``: each sample the mean over the periods that have it."""
    shape = (len(x) // period_samples, period_samples)
    n = shape[0] * period_samples
    return gapped_periods.mean_period(x[:n].reshape(shape), present[:n].reshape(shape))


def gapped_warnings(cfg: IdentificationConfig, present: np.ndarray, period_samples: int | None) -> list[str]:
    """What a record that misses samples changes in its analysis; DataError when it cannot be analysed."""
    if not period_samples or len(present) < 2 * period_samples:
        raise DataError(
            f"{int((~present).sum())} samples are missing and the excitation is not periodic (or holds fewer than "
            "two periods): only whole periods can be read around missing samples"
        )
    notes = [
        f"{int((~present).sum())} of {len(present)} samples missing (cycles skipped or frames lost): each period "
        "read by least squares on the samples it has"
    ]
    if cfg.lowpass_hz:
        notes.append("identification.lowpass_hz not applied: the record misses samples")
    return notes


def averaged_period(n: int, period_samples: int | None) -> int | None:
    """The period, samples, when a record of ``n`` samples holds two whole periods to average; else None."""
    return period_samples if period_samples and n >= 2 * period_samples else None


def welch_segment(
    n: int, cfg: IdentificationConfig, sample_rate_hz: float, period_samples: int | None, warnings: list[str]
) -> int:
    """Welch segment length for a record of ``n`` samples that does not hold two whole periods."""
    if period_samples:
        warnings.append("fewer than two whole excitation periods recorded: Welch averaging used instead")
    seg = int(round(cfg.segment_s * sample_rate_hz))
    if seg > n // 2:
        seg = n // 2
        warnings.append(f"identification.segment_s longer than half the record: {seg / sample_rate_hz:g} s used")
    return seg


def loop_response(
    excitation,
    output,
    sample_rate_hz: float,
    cfg: IdentificationConfig,
    period_samples: int | None = None,
    excited_bins=None,
    present=None,
) -> tuple[FrequencyResponse, list[str]]:
    """Excitation-to-output response through the drive, as :func:`~hilident.pipeline.plant.identify_plant`
    computes its ``loop``.

    This is all a verification run needs: no friction model, no resonance search. ``present`` (bool per
    sample) marks the samples that exist in whole periods that miss some.
    """
    gaps = missing_samples(present)
    warnings: list[str] = [] if gaps is None else gapped_warnings(cfg, gaps, period_samples)
    if gaps is not None:
        excitation, output = (np.where(gaps, x, 0.0) for x in (excitation, output))
    s = check_signals({"excitation": excitation, "output": output}, copy=False)
    r, y = (condition_signal(x, cfg, sample_rate_hz, period_samples, gaps) for x in (s["excitation"], s["output"]))
    averaged = averaged_period(len(r), period_samples)
    if averaged is not None:
        frf = periodic_frf(r, y, averaged, sample_rate_hz, skip_periods=0, bins=excited_bins, present=gaps)
        return frf, warnings
    return h1_estimate(
        r, y, sample_rate_hz, welch_segment(len(r), cfg, sample_rate_hz, period_samples, warnings)
    ), warnings


def periods_response(samples: dict, output, excitation, sample_rate_hz: float, cfg: IdentificationConfig):
    """:func:`loop_response` from a record's selected ``samples`` (their ``excitation`` and ``present``) to
    ``output`` (one of them, or another signal of the same samples), for the ``excitation`` it played."""
    return loop_response(
        samples["excitation"],
        output,
        sample_rate_hz,
        cfg,
        excitation.period_samples,
        excitation.excited_bins,
        present=samples.get("present"),
    )


def pooled_loop_response(
    excitations, outputs, sample_rate_hz: float, cfg: IdentificationConfig, period_samples: int, excited_bins=None
) -> FrequencyResponse:
    """:func:`loop_response` over several records of one periodic excitation, their periods averaged together.

    Each record (whole steady-state periods, its lead-in dropped:
    :func:`~hilident.pipeline.selection.select_gap_free`) is conditioned on its own, since its drift is its own,
    and then every period of every record is one average of
    :func:`~hilident.ident.frequency.periodic_frf`. A record whose length is no whole number of periods is
    an error, because splicing it would leak.
    """
    pairs = list(zip(excitations, outputs, strict=True))
    if not pairs:
        raise DataError("no records to pool")
    for r, _ in pairs:
        if len(r) % period_samples or len(r) < period_samples:
            raise DataError(f"a record of {len(r)} samples holds no whole number of {period_samples}-sample periods")
    r = np.concatenate(
        [condition_signal(np.asarray(x, dtype=float), cfg, sample_rate_hz, period_samples) for x, _ in pairs]
    )
    y = np.concatenate(
        [condition_signal(np.asarray(x, dtype=float), cfg, sample_rate_hz, period_samples) for _, x in pairs]
    )
    return periodic_frf(r, y, period_samples, sample_rate_hz, skip_periods=0, bins=excited_bins)


def filtered_plant_response(to_output: FrequencyResponse, to_command: FrequencyResponse) -> FrequencyResponse:
    """The filter slots and the plant together, ``N G``, measured in closed loop: command to output.

    The excitation enters ahead of the filter slots while a loop holds the axis, so the command
    entering the slots (controller output plus injection) and the output both respond to it:
    ``to_output = y/r = N G S`` and ``to_command = u/r = S`` (both :func:`loop_response` of one
    record), and their ratio is ``N G`` whatever the loop adds (the indirect method of
    :func:`hilident.ident.frequency.frf_from_reference`). It is what an open-loop torque run
    measures, so a band figure on it compares with one of a single-position run. The coherence is
    the product of the two responses' coherences.
    """
    # u/r is never zero on an excited line: the excitation itself is part of the command
    return replace(
        to_output,
        response=to_output.response / to_command.response,
        coherence=to_output.coherence * to_command.coherence,
    )
