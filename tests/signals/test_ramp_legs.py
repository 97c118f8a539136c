"""The ramp profile's checks accept the speeds as numpy did before they moved out of the generators."""

from __future__ import annotations

import numpy as np
import pytest

from hilident.errors import ConfigError
from hilident.signals import velocity_ramps
from hilident.signals.ramp_legs import ramp_extent

ARGS = dict(hold_s=1.0, accel_mps2=0.5, sample_rate_hz=1000.0, settle_s=0.2)


@pytest.mark.parametrize(
    "speeds",
    [0.05, np.float64(0.05), np.array(0.05), [0.05], (0.05,), np.array([0.05])],
    ids=["float", "np-float", "0-d array", "list", "tuple", "1-d array"],
)
def test_one_speed_in_any_form_gives_the_same_profile(speeds):
    n, travel = ramp_extent(speeds, **ARGS)
    assert (n, travel) == ramp_extent([0.05], **ARGS)
    assert velocity_ramps(speeds, **ARGS).setpoint_mps.size == n


@pytest.mark.parametrize(
    "speeds, message",
    [
        ([], "at least one speed"),
        ([0.01, 0.0], "non-zero"),
        ("fast", "must be a number, got 'fast'"),
        ({"a": 1}, "must be a number, got a table of 1 keys"),
        ([0.01, float("nan")], "must be finite"),
    ],
)
def test_bad_speeds_are_config_errors_keyed_speeds_mps(speeds, message):
    with pytest.raises(ConfigError, match=message) as err:
        ramp_extent(speeds, **ARGS)
    assert err.value.key == "speeds_mps"


def test_the_checks_import_no_numpy():
    import os
    import subprocess
    import sys
    from pathlib import Path

    import hilident

    env = {**os.environ, "PYTHONPATH": str(Path(hilident.__file__).resolve().parents[1])}
    code = "import sys, hilident.signals.ramp_legs; print('numpy' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env)
    assert done.stdout.strip() == "False", done.stderr
