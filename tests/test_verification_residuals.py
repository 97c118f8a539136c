"""Failing residual tests of a grey-box fit are warnings that say what to change."""

import numpy as np
from scipy import signal

from hilident.config.tables import ModelConfig
from hilident.pipeline.greybox import fit_greybox, residual_warnings


def test_residual_warnings_name_the_failed_test():
    ok = {"residuals_white": True, "independent_of_input": True, "ljung_box_p": 0.4}
    assert residual_warnings("rigid_axis", "holdout", ok) == []
    assert residual_warnings("rigid_axis", "holdout", {"residuals_white": None}) == []  # not computed
    (white,) = residual_warnings("rigid_axis", "holdout", dict(ok, residuals_white=False, ljung_box_p=1e-9))
    assert "not white" in white and "1e-09" in white and "input_hold" in white
    (indep,) = residual_warnings("rigid_axis", "holdout", dict(ok, independent_of_input=False))
    assert "correlated with the input" in indep


def test_rigid_axis_fitted_to_a_resonant_axis_warns():
    # the axis has a 5 Hz mode a rigid-axis model cannot hold: its residuals are coloured
    fs = 500.0
    rng = np.random.default_rng(0)
    w0 = 2 * np.pi * 5.0
    den = np.polymul([1.0, 0.0], [2.0, 2 * 0.05 * w0 * 2.0, w0**2 * 2.0])  # an integrator and a 5 Hz mode
    b, a, _ = signal.cont2discrete(([1.0], den), 1 / fs)
    torque = signal.lfilter(*signal.butter(2, 30.0, fs=fs), rng.standard_normal(20_000))
    position = signal.lfilter(np.ravel(b), a, torque)
    result = fit_greybox(ModelConfig(kind="rigid_axis", cutoff_hz=20.0), torque, position, fs)
    assert result.estimation["residuals_white"] is False
    assert any("not white" in w for w in result.warnings)
