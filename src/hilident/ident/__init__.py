"""Identification numerics: the methods of the lecture and the thesis, on numpy arrays.

Pure functions; no files, devices or clocks.

- ``preprocess``: validation, detrending, zero-phase Butterworth filters, differences
- ``derivatives``: state-variable-filter derivatives (same filter on input and output)
- ``friction``: Coulomb, viscous, Stribeck friction; fits from constant-velocity tests
- ``greybox``: linear-in-parameters least squares with parameter statistics,
  rigid-axis inverse dynamics, torque-to-force constant
- ``blackbox``: continuous-time ODE order search
- ``arx``: ARX fitting, prediction, simulation, order search
- ``discretize``: ZOH, Euler, Tustin and back; controllability and observability
- ``frequency``: ETFE, H1 with coherence, closed-loop and periodic frequency responses
- ``tffit``: transfer functions fitted to a frequency response (Levy, Sanathanan-Koerner,
  Levenberg-Marquardt on the complex error), modal form, order selection, which roots the
  data support; a package of ``model``, ``fit``, ``order`` and ``roots``
- ``filtering``: first-order RC low-pass, moving average, anti-aliased decimation
- ``kalman``: steady-state and time-varying Kalman filters, pole-placement observers
- ``resonance``: resonances of a frequency response by local rational fits
- ``decay``: poles from a free-vibration record
- ``drift``: a fleet axis's resonance trend over days, its uncertainty and drift verdict
- ``validation``: fit %, residual analysis, overfitting warning

May import ``errors`` only (pure).
"""

from hilident.ident.arx import (
    ArxModel,
    OrderCandidate,
    OrderSearch,
    arx_order_search,
    arx_to_ba,
    fit_arx,
    predict,
    simulate,
)
from hilident.ident.blackbox import OdeCandidate, ode_order_search, select_order
from hilident.ident.decay import DampedMode, DecayFit, decay_poles
from hilident.ident.derivatives import (
    finite_difference_derivatives,
    settling_samples,
    state_variable_filter,
    svf_sections,
)
from hilident.ident.discretize import (
    DiscreteStateSpace,
    StateSpace,
    c2d_tf,
    controllability_matrix,
    d2c_tf,
    d2c_tustin,
    d2c_zoh,
    forward_euler,
    is_controllable,
    is_observable,
    observability_matrix,
    sampling_advice,
    second_order_poles,
    tustin,
    zoh,
)
from hilident.ident.drift import DriftTrend, SeriesTrend, axis_drifts, drift_trend
from hilident.ident.filtering import (
    decimate,
    decimation_filter,
    moving_average,
    rc_alpha,
    rc_lowpass,
)
from hilident.ident.frequency import (
    FrequencyResponse,
    etfe,
    frf_from_reference,
    h1_estimate,
    periodic_frf,
)
from hilident.ident.friction import (
    FrictionFit,
    SteadyStatePoints,
    StribeckParams,
    compensate,
    fit_coulomb_viscous,
    fit_stribeck,
    steady_state_points,
    stribeck,
)
from hilident.ident.greybox import (
    LinearFit,
    check_excitation,
    fit_dc_motor_speed,
    fit_linear,
    fit_mass_spring_damper,
    fit_rigid_axis,
    fit_torque_constant,
)
from hilident.ident.kalman import (
    KalmanFilter,
    check_observable,
    observer_gain_by_pole_placement,
    run_observer,
    steady_state_kalman,
    two_mass_discrete,
    two_mass_model,
)
from hilident.ident.preprocess import (
    bandpass,
    central_difference,
    check_signals,
    detrend,
    highpass,
    lowpass,
    remove_drift,
)
from hilident.ident.resonance import Resonance, find_resonances, fit_local_mode
from hilident.ident.tffit import (
    ModalModel,
    TfFit,
    TfOrderCandidate,
    fit_transfer_function,
    modal_form,
)
from hilident.ident.tffit import select_order as select_tf_order
from hilident.ident.validation import (
    ResidualAnalysis,
    fit_percent,
    overfitting_warning,
    residual_analysis,
)

__all__ = [
    "ArxModel",
    "DampedMode",
    "DecayFit",
    "DiscreteStateSpace",
    "DriftTrend",
    "FrequencyResponse",
    "FrictionFit",
    "KalmanFilter",
    "LinearFit",
    "ModalModel",
    "OdeCandidate",
    "OrderCandidate",
    "OrderSearch",
    "ResidualAnalysis",
    "Resonance",
    "SeriesTrend",
    "StateSpace",
    "SteadyStatePoints",
    "StribeckParams",
    "TfFit",
    "TfOrderCandidate",
    "arx_order_search",
    "arx_to_ba",
    "axis_drifts",
    "bandpass",
    "c2d_tf",
    "central_difference",
    "check_excitation",
    "check_observable",
    "check_signals",
    "compensate",
    "controllability_matrix",
    "d2c_tf",
    "d2c_tustin",
    "d2c_zoh",
    "decay_poles",
    "decimate",
    "decimation_filter",
    "detrend",
    "drift_trend",
    "etfe",
    "find_resonances",
    "finite_difference_derivatives",
    "fit_arx",
    "fit_coulomb_viscous",
    "fit_dc_motor_speed",
    "fit_linear",
    "fit_local_mode",
    "fit_mass_spring_damper",
    "fit_percent",
    "fit_rigid_axis",
    "fit_stribeck",
    "fit_torque_constant",
    "fit_transfer_function",
    "forward_euler",
    "frf_from_reference",
    "h1_estimate",
    "highpass",
    "is_controllable",
    "is_observable",
    "lowpass",
    "modal_form",
    "moving_average",
    "observability_matrix",
    "observer_gain_by_pole_placement",
    "ode_order_search",
    "overfitting_warning",
    "periodic_frf",
    "predict",
    "rc_alpha",
    "rc_lowpass",
    "remove_drift",
    "residual_analysis",
    "run_observer",
    "sampling_advice",
    "second_order_poles",
    "select_order",
    "select_tf_order",
    "settling_samples",
    "simulate",
    "state_variable_filter",
    "steady_state_kalman",
    "steady_state_points",
    "stribeck",
    "svf_sections",
    "tustin",
    "two_mass_discrete",
    "two_mass_model",
    "zoh",
]
