"""The ``[model]`` grey-box model of the axis: fitted on one stretch of data, checked on others."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hilident.config.tables import ModelConfig
from hilident.errors import DataError
from hilident.ident import greybox as ident_greybox
from hilident.ident.validation import overfitting_warning


def greybox_regression(cfg: ModelConfig, torque, position, sample_rate_hz: float):
    """The regression ``[model]`` asks for, every key honoured (asymmetric, min_speed, decimate, input_hold)."""
    force = cfg.c * np.asarray(torque, dtype=float)
    cutoff = cfg.cutoff_hz or sample_rate_hz / 10.0
    if cfg.kind == "mass_spring_damper":
        return ident_greybox.mass_spring_damper_regression(
            force, position, sample_rate_hz, cutoff, decimate=cfg.decimate, input_hold=cfg.input_hold
        )
    return ident_greybox.rigid_axis_regression(
        position,
        force,
        sample_rate_hz,
        cutoff,
        asymmetric=cfg.asymmetric,
        decimate=cfg.decimate,
        min_speed=cfg.min_speed or None,
        input_hold=cfg.input_hold,
    )


@dataclass
class GreyBoxResult:
    """A grey-box model fitted on one stretch of data and checked on others.

    Attributes
    ----------
    fit : LinearFit
        Parameters with standard deviations, from the estimation data.
    estimation : dict
        :func:`~hilident.ident.greybox.validate_fit` on the estimation data.
    validation : dict of str to dict
        The same on each validation record, by name.
    warnings : list of str
    """

    kind: str
    fit: ident_greybox.LinearFit
    estimation: dict
    validation: dict
    warnings: list

    def to_dict(self) -> dict:
        return {"kind": self.kind, **self.fit.to_dict(), "estimation": self.estimation, "validation": self.validation}


def residual_warnings(kind: str, name: str, check: dict) -> list[str]:
    """What failing residual tests of a grey-box fit (:func:`~hilident.ident.greybox.validate_fit`)
    mean and what to change.

    Tests that were not computed (None) say nothing.
    """
    out = []
    p = check.get("ljung_box_p")
    if check.get("residuals_white") is False:
        out.append(
            f"[model] {kind} on {name}: the residuals are not white (Ljung-Box p = "
            f"{'n/a' if p is None else format(p, '.3g')}): "
            "the model leaves dynamics unexplained; try the other input_hold, a lower cutoff_hz, or a model with "
            "more physics (a second mass, friction) before trusting its parameters' standard deviations"
        )
    if check.get("independent_of_input") is False:
        out.append(
            f"[model] {kind} on {name}: the residuals are correlated with the input: part of the input's effect is "
            "missing from the model (a delay, an unmodelled force such as friction, or a wrong kind)"
        )
    return out


def fit_greybox(
    cfg: ModelConfig, torque, position, sample_rate_hz: float, validation_records: dict | None = None
) -> GreyBoxResult:
    """Fit ``[model]`` to torque and position and validate it.

    With no separate validation record, the last ``cfg.holdout`` of the data is
    kept out of the fit and used as one (``"holdout"``).

    Parameters
    ----------
    cfg : ModelConfig
    torque, position : array_like
        Motor torque (N·m; times ``cfg.c`` gives the force) and position (m).
    sample_rate_hz : float
    validation_records : dict of str to (torque, position), optional
        Other records of the same axis.
    """
    torque = np.asarray(torque, dtype=float)
    position = np.asarray(position, dtype=float)
    records = dict(validation_records or {})
    if not records and cfg.holdout > 0:
        cut = int(round(len(torque) * (1.0 - cfg.holdout)))
        records["holdout"] = (torque[cut:], position[cut:])
        torque, position = torque[:cut], position[:cut]
    est = greybox_regression(cfg, torque, position, sample_rate_hz)
    fit = ident_greybox.fit_regression(est)
    warnings = list(fit.warnings)
    estimation = ident_greybox.validate_fit(fit, est)
    if est.low_speed_rows:
        why = "model.min_speed" if cfg.min_speed else "2 % of the RMS speed; model.min_speed sets it"
        warnings.append(
            f"{cfg.kind}: {est.low_speed_rows} of {est.low_speed_rows + estimation['samples']} rows "
            f"slower than {est.min_speed:.3g} ({why}) left out of the fit"
        )
    checked = {}
    warnings += residual_warnings(cfg.kind, "the estimation data", estimation)
    for name, (tq, pos) in records.items():
        try:
            checked[name] = ident_greybox.validate_fit(fit, greybox_regression(cfg, tq, pos, sample_rate_hz))
        except DataError as exc:
            warnings.append(f"{cfg.kind} validation on {name}: {exc}")
            continue
        warnings += residual_warnings(cfg.kind, name, checked[name])
        w = overfitting_warning(estimation["fit_percent"], checked[name]["fit_percent"])
        if w:
            warnings.append(f"{cfg.kind} on {name}: {w}")
    return GreyBoxResult(cfg.kind, fit, estimation, checked, warnings)
