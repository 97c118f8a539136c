"""Typed run configuration, loaded from TOML with every key validated.

Each TOML table maps onto one frozen dataclass below; unknown keys, wrong types
and out-of-range values raise :class:`~hilident.errors.ConfigError` naming the
dotted key and the file (the mechanism is :mod:`hilident.config.schema`, shared with
the driver files). Transport settings live in sub-tables: ``[device.canopen]``,
``[device.modbus]``, ``[emulator.faults.serial]``,
``[emulator.faults.canopen]``, ``[emulator.faults.modbus]``; their flat keys of
earlier releases are still read, with a deprecation warning. The
configuration reference of the documentation (docs/, generated from these specs) lists every key.

Whatever a file holds, loading it gives a Config or a ConfigError, before
anything is allocated or moved: files are at most :data:`MAX_FILE_BYTES` of
UTF-8; numbers are finite and within :data:`~hilident.config.schema.FLOAT_MAX`; integers fit
:data:`~hilident.config.schema.INT_RANGE` unless their key says otherwise; lists hold at most
:data:`~hilident.config.schema.MAX_LIST_ITEMS` (or their key's ``max_items``); strings at most
:data:`~hilident.config.schema.MAX_STRING_CHARS` printable characters. Across keys, every experiment
(excitation, friction ramps) is sized without building it and refused above
``MAX_SAMPLES`` (2**25 samples), a multisine period must fit the run, fades must
fit the excitation, the friction test must stay inside half the position window,
and a pyserial port URL that writes a file (``spy://...?file=``) is refused.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
import urllib.parse
from dataclasses import dataclass, field
from pathlib import Path

from hilident.config.schema import (
    MAX_FILE_BYTES,
    build_table,
    moved_keys_readable,
)
from hilident.config.schema import spec as _spec
from hilident.errors import ConfigError
from hilident.signals._checks import MAX_SAMPLES, show
from hilident.signals.ramp_legs import ramp_extent


def _check_object_address(value: str, key: str, source: str) -> None:
    """An object address ``"0x3100"`` or ``"0x3100:2"`` (or empty: none)."""
    if value.strip():
        from hilident.protocol.canopen_types import parse_address

        parse_address(value, key, source)


def _check_distinct_ids(value: list[int], key: str, source: str) -> None:
    """Node ids named once each."""
    repeated = sorted({i for i in value if value.count(i) > 1})
    if repeated:
        raise ConfigError(key, f"names node {repeated[0]} twice; each node of the bus once", source)


# --- device and run -------------------------------------------------------------------


@dataclass(frozen=True)
class CanopenDeviceConfig:
    """``[device.canopen]``: how the host reaches a CANopen drive."""

    can_interface: str = _spec(
        "socketcan", doc="python-can interface (socketcan, pcan, kvaser, socketcand, virtual, ...)"
    )
    node_id: int = _spec(1, ge=1, le=127, doc="node id of the drive")
    node_ids: list[int] = _spec(
        [],
        ge=1,
        le=127,
        max_items=8,
        check=_check_distinct_ids,
        doc="the nodes of one session on this bus, same driver, node_id first (several drives of one axis); "
        "empty: node_id alone",
    )
    trace: str = _spec(
        "", choices=("", "asc", "blf"), doc='write a CAN trace of each run next to its recording: "", "asc" or "blf"'
    )
    sync_source: str = _spec(
        "auto",
        choices=("auto", "drive", "interface", "host"),
        doc="who produces SYNC in a streamed run: the drive (its [canopen.sync] producer), the CAN interface's "
        "own cyclic transmit (SocketCAN's broadcast manager, hardware), or the host's Python loop; auto: the "
        "first of these the drive and the interface offer",
    )


@dataclass(frozen=True)
class ModbusDeviceConfig:
    """``[device.modbus]``: how the host addresses a Modbus drive."""

    device_id: int = _spec(1, ge=0, le=247, doc="device (unit/slave) id")
    parity: str = _spec("E", choices=("N", "E", "O"), doc="RTU: parity")
    stopbits: int = _spec(1, ge=1, le=2, doc="RTU: stop bits")


@moved_keys_readable
@dataclass(frozen=True)
class DeviceConfig:
    #: Flat keys of earlier releases and the sub-table each moved to (read with a DeprecationWarning).
    moved_keys: typing.ClassVar[dict[str, str]] = {
        "can_interface": "canopen",
        "node_id": "canopen",
        "trace": "canopen",
        "device_id": "modbus",
        "parity": "modbus",
        "stopbits": "modbus",
    }

    driver: str = _spec("myrio-board", doc="driver name (folder in drivers/) or path to a driver folder")
    port: str = _spec(
        "emulator",
        doc='"emulator"; serial board: a device path, COMx or pyserial URL (socket://, '
        "rfc2217://); CANopen: the python-can channel (can0, PCAN_USBBUS1, ...); "
        'Modbus: "tcp://HOST:PORT" for Modbus TCP, else the RTU serial port or pyserial URL',
    )
    baudrate: int = _spec(0, ge=0, doc="serial or RTU line rate in baud, or CAN bit rate; 0 uses the driver's default")
    timeout_s: float = _spec(2.0, gt=0, doc="how long to wait for an answer from the device")
    driver_paths: list[str] = _spec([], max_items=32, doc="extra folders searched for driver descriptions")
    acquisition: str = _spec(
        "auto",
        choices=("auto", "streamed", "buffered", "recorder"),
        doc="streamed: the host sends set-points each cycle; buffered: the drive plays a "
        "stored table and captures into its buffer; recorder: the drive's own generator "
        "plays and its recorder records; auto: the driver's choice",
    )
    allow_fault_reset: bool = _spec(
        False,
        doc="clear a fault the device has latched (a limit trip, a watchdog, "
        "a drive fault) when connecting; without it such a device is refused "
        "(hilident run --clear-fault sets it for one run)",
    )
    host_timeout_s: float = _spec(
        0.5,
        gt=0,
        le=60,
        doc="how long the device may go without hearing from the host "
        "before it stops the axis on its own: CANopen heartbeat consumer (0x1016), Modbus "
        "the driver's communication-timeout parameter; the serial board's watchdog is "
        "fixed by the board (PROTOCOL.md section 8)",
    )
    canopen: CanopenDeviceConfig = _spec(CanopenDeviceConfig(), doc="CANopen drives")
    modbus: ModbusDeviceConfig = _spec(ModbusDeviceConfig(), doc="Modbus drives")


@dataclass(frozen=True)
class RunConfig:
    sample_rate_hz: float = _spec(1000.0, gt=0, le=1e6, doc="recorded sample rate; must divide the loop rate")
    seed: int = _spec(1, ge=0, le=2**32 - 1, doc="seed of every random excitation")
    channels: list[str] = _spec([], max_items=64, doc="channels to stream; empty: the driver's default set")


@dataclass(frozen=True)
class LimitsConfig:
    torque_nm: float = _spec(gt=0, le=1e5, doc="largest torque command allowed; crossing it stops the axis")
    velocity_mps: float = _spec(gt=0, le=100, doc="largest speed allowed")
    position_min_m: float = _spec(ge=-1e3, le=1e3, doc="lower end of the allowed position window")
    position_max_m: float = _spec(ge=-1e3, le=1e3, doc="upper end of the allowed position window")


@dataclass(frozen=True)
class FrictionTestConfig:
    enabled: bool = _spec(True, doc="run the constant-velocity friction test before the identification")
    speeds_mps: list[float] = _spec(
        [0.005, 0.01, 0.02, 0.05, 0.1, 0.2], max_items=64, doc="constant test speeds, each run both ways"
    )
    hold_s: float = _spec(1.0, gt=0, doc="time at each constant speed")
    settle_s: float = _spec(0.4, ge=0, doc="part of the hold not used for averaging")
    accel_mps2: float = _spec(2.0, gt=0, doc="acceleration between speeds")
    model: str = _spec(
        "stribeck",
        choices=("stribeck", "coulomb_viscous"),
        doc="friction model fitted to the test: stribeck (the structure the points support: Coulomb + viscous, "
        "Stribeck with fixed exponents, or all six parameters) or coulomb_viscous",
    )
    velocity_deadband_mps: float = _spec(0.0, ge=0, doc="no friction compensation below this speed")
    target_ci_percent: float = _spec(
        5.0,
        ge=0,
        lt=100,
        doc="extend the test with further rounds of legs until the 95 % intervals of the Coulomb level Fc and "
        "the viscous level Fv are within this share of their values, %; 0: only the configured legs",
    )
    max_duration_s: float = _spec(
        300.0, gt=0, doc="longest the whole test may take with its extensions (the legs played, ramps included)"
    )
    max_rounds: int = _spec(8, ge=1, le=64, doc="most rounds of legs, the configured round included")


#: Where an excitation can enter, and the key of its amplitude (N·m, m/s, m).
AMPLITUDE_KEY_OF_MODE = {
    "torque_injection": "amplitude_nm",
    "torque": "amplitude_nm",
    "velocity": "amplitude_mps",
    "position": "amplitude_m",
}
EXCITATION_MODES = tuple(AMPLITUDE_KEY_OF_MODE)
#: Modes whose excitation is a set-point perturbation of a loop the drive closes.
SETPOINT_MODES = ("velocity", "position")
#: Why amplitude_mps / amplitude_m refuse "auto".
AUTO_SETPOINT_REFUSED = (
    '"auto" chooses a torque amplitude (excitation.amplitude_nm, modes torque and '
    "torque_injection); a set-point perturbation's size must be given as a number"
)
#: amplitude_nm = "auto": share of the band's excited lines that must reach the coherence target.
AUTO_BAND_SHARE = 0.9
#: amplitude_nm = "auto" without a friction test or auto_start_nm: the first trial's share of the ceiling.
AUTO_START_SHARE = 0.05


@dataclass(frozen=True)
class ExcitationConfig:
    kind: str = _spec(
        "multisine",
        choices=("sine", "square", "chirp", "noise", "prbs", "multisine", "step"),
        doc="the signal played: multisine, chirp, noise, prbs, sine, square or step",
    )
    mode: str = _spec(
        "torque_injection",
        choices=EXCITATION_MODES,
        doc="where the excitation enters: torque_injection (added to the torque of a loop holding the "
        "axis), torque (open loop), velocity or position (a set-point perturbation in closed loop)",
    )
    amplitude_nm: float | str = _spec(
        1.0,
        gt=0,
        auto=True,
        doc="peak torque of the excitation (noise: rms), modes torque and "
        'torque_injection; "auto": chosen by short trials before the run (multisine)',
    )
    amplitude_mps: float = _spec(
        0.0, ge=0, auto=AUTO_SETPOINT_REFUSED, doc="peak velocity set-point perturbation (noise: rms), mode velocity"
    )
    amplitude_m: float = _spec(
        0.0, ge=0, auto=AUTO_SETPOINT_REFUSED, doc="peak position set-point perturbation (noise: rms), mode position"
    )
    f_min_hz: float = _spec(1.0, gt=0, doc="lower end of the excited band (multisine, chirp, noise)")
    f_max_hz: float = _spec(
        100.0, gt=0, doc="upper end of the excited band; below the Nyquist frequency of run.sample_rate_hz"
    )
    frequency_hz: float = _spec(10.0, gt=0, doc="sine and square")
    duration_s: float = _spec(20.0, gt=0, doc="length of one identification run")
    period_s: float = _spec(2.0, gt=0, doc="multisine period (whole periods are played)")
    chirp_method: str = _spec("logarithmic", choices=("linear", "logarithmic"), doc="chirp: how its frequency sweeps")
    register_length: int = _spec(10, ge=2, le=32, doc="PRBS shift-register length")
    clock_divider: int = _spec(1, ge=1, doc="PRBS samples per bit")
    fade_s: float = _spec(0.1, ge=0, doc="raised-cosine fade in and out")
    auto_coherence: float = _spec(
        0.0,
        ge=0,
        lt=1,
        doc='amplitude_nm = "auto": coherence the run must reach at '
        "AUTO_BAND_SHARE of the excited lines of the band; 0: "
        "identification.coherence_threshold + 0.15, at most 0.95",
    )
    auto_trial_periods: int = _spec(2, ge=2, le=16, doc="auto: multisine periods of each trial (plus one lead-in)")
    auto_max_trials: int = _spec(4, ge=1, le=16, doc="auto: most trials before the run")
    auto_start_nm: float = _spec(
        0.0,
        ge=0,
        doc="auto: first trial's amplitude, N*m; 0: the multisine whose rms is "
        "the friction test's Fs / auto_nonlinear_share, without one AUTO_START_SHARE of the "
        "ceiling",
    )
    auto_max_nm: float = _spec(0.0, ge=0, doc="auto: largest amplitude auto may choose, N*m; 0: limits.torque_nm")
    auto_safety: float = _spec(1.5, ge=1, le=10, doc="auto: factor on the amplitude the trials predict is needed")
    auto_nonlinear_share: float = _spec(
        0.1,
        gt=0,
        le=1,
        doc="auto: largest share of nonlinear distortion the run "
        "may carry: the fitted friction's nonlinear part (Coulomb and Stribeck) over "
        "the excitation (rms), or without a friction test the change of the measured "
        "response between two trials, scaled to the higher amplitude; stick-slip "
        "repeats every period, so coherence does not see the distortion it causes",
    )

    @property
    def amplitude_auto(self) -> bool:
        """Whether the torque amplitude is chosen by trials before the run (``amplitude_nm = "auto"``)."""
        return self.mode in ("torque", "torque_injection") and self.amplitude_nm == "auto"

    @property
    def amplitude_key(self) -> str:
        """The key that holds the amplitude for :attr:`mode`."""
        return AMPLITUDE_KEY_OF_MODE[self.mode]

    @property
    def amplitude(self) -> float | str:
        """The amplitude in the unit of :attr:`mode` (N·m, m/s or m), or ``"auto"`` (see :attr:`amplitude_auto`)."""
        return getattr(self, self.amplitude_key)

    @property
    def amplitude_value(self) -> float:
        """The amplitude as a number in the unit of :attr:`mode`; 0.0 while ``"auto"`` has not been chosen yet."""
        value = self.amplitude
        return 0.0 if isinstance(value, str) else float(value)

    @property
    def closed_loop(self) -> bool:
        """Whether the excitation perturbs a set-point of a closed loop (the FRF's reference is that set-point)."""
        return self.mode in SETPOINT_MODES


@dataclass(frozen=True)
class IdentificationConfig:
    output: str = _spec("velocity_mps", doc="output channel of the measured frequency response")
    outputs: list[str] = _spec(
        [],
        max_items=16,
        doc="further recorded channels identified together with output (a load sensor: load_position_m): "
        "the modes every one of them sees, each with its shape; a notch takes its centre from such a mode",
    )
    coherence_threshold: float = _spec(
        0.8, ge=0, le=1, doc="lowest coherence accepted around a peak; lines below it are not trusted"
    )
    segment_s: float = _spec(2.0, gt=0, doc="Welch segment length (frequency resolution 1/segment_s)")
    lowpass_hz: float = _spec(0.0, ge=0, doc="zero-phase low-pass before the FRF; 0 disables")
    f_min_hz: float = _spec(0.0, ge=0, doc="band searched for resonances; 0: the excitation band")
    f_max_hz: float = _spec(0.0, ge=0, doc="upper end of the band searched for resonances; 0: the excitation band")
    max_resonances: int = _spec(
        2, ge=0, le=16, doc="most resonances reported (further peaks are listed in rejected_peaks)"
    )
    min_prominence_db: float = _spec(6.0, ge=0, doc="least prominence of a peak over its surroundings")
    model_max_order: int = _spec(
        4,
        ge=0,
        le=12,
        doc="highest denominator order of the transfer function fitted "
        "to the plant response (modal form in summary.json); 0: no fit",
    )
    model_order: str = _spec(
        "auto",
        choices=("auto",) + tuple(str(n) for n in range(1, 13)),
        doc="denominator degree of the fitted transfer function, integrators included, as a "
        'string ("3"); auto: chosen by model_criterion up to model_max_order',
    )
    model_relative_degree: str = _spec(
        "auto",
        choices=("auto",) + tuple(str(n) for n in range(0, 7)),
        doc='denominator minus numerator degree, as a string ("1"); auto: chosen by model_criterion (0 to 3)',
    )
    model_integrators: str = _spec(
        "auto",
        choices=("auto", "0", "1", "2"),
        doc='poles at s = 0 (rigid-body modes), as a string ("1"); auto: chosen by model_criterion',
    )
    model_criterion: str = _spec(
        "mdl",
        choices=("mdl", "aic", "validation"),
        doc="what picks the structure: mdl (minimum description length on the coherence-"
        "weighted complex error), aic, or validation (error on held-out frequency lines)",
    )


@dataclass(frozen=True)
class TuningConfig:
    enabled: bool = _spec(True, doc="propose loop gains on a drive whose driver describes its loop ([loop])")
    preset: str = _spec(
        "medium",
        choices=("stiff", "medium", "soft"),
        doc="stability targets: stiff GM 8 dB, PM 45 deg, Ms 2; medium GM 10 dB, PM 50 deg, Ms 1.7; "
        "soft GM 12 dB, PM 60 deg, Ms 1.4",
    )
    gain_margin_db: float | None = _spec(None, gt=0, doc="smallest gain margin, dB (default: the preset's)")
    phase_margin_deg: float | None = _spec(
        None, gt=0, lt=90, doc="smallest phase margin, degrees (default: the preset's)"
    )
    sensitivity_peak: float | None = _spec(None, gt=1, doc="largest sensitivity peak Ms, 1 (default: the preset's)")
    upload: bool = _spec(
        False,
        doc="write the proposed gains into the drive (with the notches when they were uploaded), read them back, "
        "prove them by a closed-loop run in velocity mode and put the old ones back when it differs from the "
        "prediction; refused when the gains would leave the loop unstable on the identified plant",
    )
    tolerance_db: float = _spec(
        2.0, gt=0, doc="largest difference of the measured closed loop from the prediction that keeps the gains, dB"
    )
    tolerance_deg: float = _spec(
        10.0, gt=0, doc="largest phase difference of the measured closed loop from the prediction, degrees"
    )
    step_tolerance_percent: float = _spec(
        10.0,
        gt=0,
        doc="largest rms difference of the measured velocity steps from the prediction that keeps the gains, % of "
        "the step (plus what the plant's uncertainty moves the prediction by)",
    )


@dataclass(frozen=True)
class NotchConfig:
    enabled: bool = _spec(True, doc="design notch filters at the resonances and upload them")
    depth_db: float = _spec(30.0, gt=0, doc="depth of each notch at its centre")
    width_factor: float = _spec(1.0, gt=0, doc="notch width relative to the resonance's half-power bandwidth")
    min_width_ratio: float = _spec(0.15, ge=0, lt=1, doc="smallest notch width as a fraction of its centre frequency")
    verify: bool = _spec(True, doc="run the excitation again with the notches enabled")
    min_reduction_db: float = _spec(
        20.0,
        ge=0,
        doc="warn when the verification shows less reduction (band figure); "
        "the notch width is chosen to reach it where the plant allows",
    )
    verify_band_bandwidths: float = _spec(
        2.0,
        gt=0,
        le=50,
        doc="verification band figure: largest response within "
        "this many half-power bandwidths either side of the mode, before vs after",
    )
    max_width_ratio: float = _spec(
        1.0, gt=0, lt=2, doc="widest notch the width search may choose, as a fraction of its centre frequency"
    )
    target_attenuation_db: float = _spec(
        20.0,
        gt=0,
        doc="least attenuation of the designed notch at both ends of "
        "the 95 % interval of the resonance frequency; the notch is made wide enough",
    )
    keep_modulus_margin: float = _spec(
        0.5,
        ge=0,
        le=1,
        doc="[map]: the notches for the workspace must keep this "
        "fraction of the holding loop's modulus margin min|1 + L| (measured at the "
        "mapped positions); a design that costs more gives way to a narrower one. "
        "0: no check",
    )


@dataclass(frozen=True)
class MapConfig:
    """``[map]``: the resonance over the workspace: move to each position, hold it, excite, identify."""

    positions_m: list[float] = _spec(
        [],
        max_items=64,
        doc="cart positions to identify at, m (the encoder's axis, "
        "within [limits] position_min_m .. position_max_m less margin_m)",
    )
    count: int = _spec(
        0,
        ge=0,
        le=64,
        doc="or: this many positions spread evenly over the position window less margin_m (0: positions_m)",
    )
    margin_m: float = _spec(0.05, ge=0, doc="distance every mapped position keeps from the position limits, m")
    settle_s: float = _spec(0.5, ge=0, le=60, doc="hold at each position before the excitation starts, s")
    max_velocity_mps: float = _spec(
        0.1, gt=0, doc="moves between positions: velocity limit, m/s (below [limits] velocity_mps)"
    )
    max_accel_mps2: float = _spec(0.5, gt=0, le=1000, doc="moves between positions: acceleration limit, m/s^2")
    amplitude_nm: float = _spec(
        0.0,
        ge=0,
        doc="torque injected at each position, N*m; 0: half the run's amplitude "
        "(the drive's loops add their own torque while they hold the position)",
    )
    duration_s: float = _spec(
        0.0,
        ge=0,
        doc="excitation at each position, s (whole periods, one lead-in more, as "
        "the run's); 0: the run's [excitation] duration_s",
    )
    verify: bool = _spec(
        False,
        doc="after the verification, excite every mapped position again with the notches "
        "enabled and measure the reduction there (the approach moves run with the notches in the "
        "loop)",
    )
    verify_max_duration_s: float = _spec(
        0.0,
        ge=0,
        doc="longest the verification may excite one position, s, its "
        "lead-ins included: a record whose noise floor hides the target "
        "(notch.min_reduction_db) is followed by a longer one, their periods "
        "averaged together; 0: four times the map's own record at each position",
    )
    k_degree: int = _spec(2, ge=0, le=4, doc="joint fit: degree of the stiffness k(p) polynomial in position")
    d_degree: int = _spec(0, ge=0, le=4, doc="joint fit: degree of the damping d(p) polynomial in position")

    @property
    def enabled(self) -> bool:
        return bool(self.positions_m) or self.count > 0


@dataclass(frozen=True)
class BatchConfig:
    """``[batch]``: ``hilident batch``'s drift verdict per axis over many recordings."""

    drift_percent_per_day: float = _spec(
        0.1,
        gt=0,
        doc="rate of change of the resonance frequency, % per day, above which a significant trend is flagged",
    )
    min_recordings: int = _spec(5, ge=3, doc="recordings an axis needs for a verdict (fewer: no verdict)")
    confidence: float = _spec(0.95, gt=0, lt=1, doc="confidence level of the trend's interval and significance")


@dataclass(frozen=True)
class MoveConfig:
    """``[verification] move``: a point-to-point move done without and with the notch, its ringing compared."""

    distance_m: float = _spec(doc="signed length of the move, m (out and back again from where the axis is)")
    max_velocity_mps: float = _spec(gt=0, doc="velocity limit of the move, m/s (below [limits] velocity_mps)")
    max_accel_mps2: float = _spec(gt=0, le=1000, doc="acceleration limit of the move, m/s^2")
    profile: str = _spec(
        "trapezoid", choices=("trapezoid", "s-curve"), doc="trapezoid, or s-curve (jerk-limited by max_jerk_mps3)"
    )
    max_jerk_mps3: float = _spec(0.0, ge=0, doc="s-curve: jerk limit, m/s^3 (0: 50 times max_accel_mps2 per second)")
    dwell_s: float = _spec(1.0, gt=0, le=60, doc="held at the end of the move while its ringing is measured, s")
    notch: str = _spec(
        "auto",
        choices=("auto", "drive", "host"),
        doc="where the notch acts in the move with it: "
        "host: the move's set-point shaped on the host (the drive's slots bypassed in both moves); "
        "drive: the drive's filter slots (bypassed for the move without); auto: host, since every "
        "transport streams the move as set-points",
    )
    settle_band_m: float = _spec(
        0.0,
        ge=0,
        doc="settling band of the residual vibration, m (0: 5 % of the first peak of the move without the notch)",
    )
    repeats: int = _spec(
        1,
        ge=1,
        le=10,
        doc="times each move is made; the records are averaged, which keeps the move's ringing and lowers the "
        "vibration the axis has at rest by sqrt(repeats): for a bench whose rest vibration hides the ringing",
    )
    shapers: list[str] = _spec(
        ["fixed", "scheduled"],
        choices=("fixed", "scheduled", "both"),
        max_items=3,
        doc="input shapers the move is also made with (the drive's notch out of the way): fixed, one for the whole "
        "travel (the mapped range with [map], else the run's resonances); scheduled, following the map's mode "
        "along the travel ([map] only); both, the scheduled (else the fixed) shaper and the notch together; [] "
        "for none",
    )

    @property
    def jerk_mps3(self) -> float:
        return self.max_jerk_mps3 or 50.0 * self.max_accel_mps2


@dataclass(frozen=True)
class VerificationConfig:
    """``[verification]``: proofs that the notch works besides the repeated excitation (``[notch] verify``)."""

    move: MoveConfig | None = _spec(None)


@dataclass(frozen=True)
class DataConfig:
    format: str = _spec(
        "auto",
        choices=("auto", "hilident", "csv", "mat"),
        doc="file format; auto: by extension (.h5/.hdf5 hilident, .csv/.txt/.dat/.tsv csv, .mat)",
    )
    sample_rate_hz: float = _spec(0.0, ge=0, doc="0: from the time column (or the hilident file)")
    time: str = _spec("", doc="column of time stamps in s; must be uniform")
    column_names: list[str] = _spec(
        [], doc='names of the columns of a headerless numeric file, in order (default: their positions "0", "1", ...)'
    )
    excitation: str = _spec("", doc="column of the external excitation (closed-loop data); empty: none")
    torque: str = _spec("torque_nm", doc="column of the input torque (or force for a linear axis)")
    velocity: str = _spec("", doc="column of the velocity; empty: derived from position")
    position: str = _spec("", doc="column of the position")
    output: str = _spec("", doc="column of the response output; empty: [identification].output, else the velocity")
    torque_scale: float = _spec(1.0, gt=0, doc="multiplies the torque column to give N*m (rotary) or N (linear axis)")
    velocity_scale: float = _spec(1.0, gt=0, doc="multiplies the velocity column to give m/s (or rad/s)")
    position_scale: float = _spec(1.0, gt=0, doc="multiplies the position column to give m (or rad)")
    output_scale: float = _spec(1.0, gt=0, doc="multiplies the output column to give SI units")
    excitation_scale: float = _spec(
        1.0, gt=0, doc="multiplies the excitation column to give the unit of the excitation's mode"
    )
    closed_loop: bool = _spec(False, doc="the data were recorded with a controller closed around the axis")
    period_s: float = _spec(
        0.0,
        ge=0,
        doc="period of a periodic excitation, s: whole periods are averaged "
        "(leakage-free at the excited lines); 0: not periodic",
    )
    period_samples: int = _spec(0, ge=0, doc="the same period in samples (exact); 0: not periodic")
    inputs: list[str] = _spec(
        [], doc="columns of several inputs measured at once (forces, torques): a multi-input identification"
    )
    outputs: list[str] = _spec([], doc="columns of the outputs identified against data.inputs (all at once)")
    input_scales: list[float] = _spec([], doc="multiplies each input column to give SI units; empty: 1 each")
    output_scales: list[float] = _spec([], doc="multiplies each output column to give SI units; empty: 1 each")
    output_units: list[str] = _spec(
        [], doc='unit of each output after its scale, e.g. "m/s^2" for an accelerometer; empty: not stated'
    )


@dataclass(frozen=True)
class ModelConfig:
    kind: str = _spec(
        "none", choices=("none", "mass_spring_damper", "rigid_axis"), doc="grey-box model fitted to the data"
    )
    c: float = _spec(1.0, gt=0, doc="torque-to-force constant: force = c * torque")
    cutoff_hz: float = _spec(0.0, ge=0, doc="state-variable filter cut-off; 0: a tenth of the sample rate")
    input_hold: str = _spec(
        "sample",
        choices=("zoh", "sample"),
        doc="sample: the torque column holds point samples (a measured torque or current, the "
        "usual case); zoh: it holds a command the drive kept constant over each sample period",
    )
    filter_rate_hz: float = _spec(4000.0, gt=0, doc="rate the notch biquads are designed for (no device to ask)")
    holdout: float = _spec(
        0.3,
        ge=0,
        lt=1,
        doc="fraction at the end of the data kept out of the fit to validate it "
        "when there is no separate validation record",
    )
    asymmetric: bool = _spec(False, doc="rigid_axis: Coulomb and viscous friction per direction (Fc+, Fc-, Fv+, Fv-)")
    min_speed: float = _spec(
        0.0,
        ge=0,
        doc="rigid_axis: rows slower than this (m/s or rad/s, filtered) are left out "
        "of the fit; 0: 2 % of the RMS filtered speed",
    )
    decimate: int = _spec(1, ge=1, le=1_000_000, doc="use every decimate-th filtered sample in the regression")


# --- emulator -----------------------------------------------------------------------------


@dataclass(frozen=True)
class PositionFunction:
    """A plant coefficient as a function of the cart position ``p1`` (m, the encoder's ``position_m`` axis).

    ``{ poly = [c0, c1, c2, ...] }`` is ``c0 + c1 p + c2 p**2 + ...``; ``{ positions_m = [...], values = [...] }``
    a table, interpolated linearly and held at its end values beyond its ends. A polynomial is checked over
    the ``[limits]`` position window and held at its values at the window's ends beyond it (``span_m``, set
    when the configuration is loaded; None: evaluated everywhere).
    """

    poly: list[float] = _spec(
        [], max_items=8, doc="polynomial coefficients, constant term first (unit of the key per m**i)"
    )
    positions_m: list[float] = _spec([], max_items=256, doc="table: cart positions, m, strictly increasing")
    values: list[float] = _spec([], max_items=256, doc="table: the coefficient at each of positions_m")
    span_m: tuple[float, float] | None = field(default=None, metadata={"internal": True})

    @property
    def is_table(self) -> bool:
        """Whether this is the table form (else the polynomial)."""
        return not self.poly


def _position_function_check(positive: bool):
    """``check`` of a plant coefficient given as a number or a :class:`PositionFunction`: its form, and its sign
    over a table's span (a polynomial's sign over the position window is checked with ``[limits]``)."""
    bound = "> 0" if positive else ">= 0"

    def check(value, key: str, source: str) -> None:
        if not isinstance(value, PositionFunction):
            return  # a number: its bounds are the field's
        table = bool(value.positions_m or value.values)
        if value.poly and table:
            raise ConfigError(key, "give either poly or positions_m and values, not both", source)
        if not value.poly and not table:
            raise ConfigError(
                key,
                "a table needs poly = [c0, c1, ...] or positions_m = [...] and values = [...]; "
                "all of its lists are empty",
                source,
            )
        if not table:
            return
        p, v = value.positions_m, value.values
        if not p or not v:
            raise ConfigError(
                key,
                f"positions_m and values must both be non-empty, got {len(p)} positions and {len(v)} values",
                source,
            )
        if len(p) != len(v):
            raise ConfigError(
                key, f"positions_m and values differ in length: {len(p)} positions, {len(v)} values", source
            )
        for a, b in zip(p, p[1:], strict=False):
            if not b > a:
                raise ConfigError(key, f"positions_m must increase strictly, got {show(a)} then {show(b)}", source)
        for x, y in zip(p, v, strict=True):
            if not (y > 0 if positive else y >= 0):
                raise ConfigError(key, f"must be {bound} everywhere, got {show(y)} at {show(x)} m", source)

    return check


@dataclass(frozen=True)
class PlantConfig:
    model: str = _spec(
        "two_mass",
        choices=("two_mass", "three_mass", "mass_spring_damper"),
        doc="two_mass (the thesis's gantry), three_mass (a third mass hung from the load) or mass_spring_damper "
        "(the lecture's)",
    )
    m1: float = _spec(40.0, gt=0, doc="two_mass: cart mass, kg")
    m2: float = _spec(10.0, gt=0, doc="two_mass: load mass, kg")
    m3: float = _spec(2.0, gt=0, doc="three_mass: a third mass hung from the load, kg")
    k2: float = _spec(2.0e5, gt=0, doc="three_mass: stiffness between the load and the third mass, N/m")
    d2: float = _spec(10.0, ge=0, doc="three_mass: damping between the load and the third mass, N*s/m")
    backlash_m: float = _spec(
        0.0,
        ge=0,
        le=0.1,
        doc="two_mass, three_mass: total play in the cart-to-load "
        "coupling, m (inside it the coupling carries no force)",
    )
    k: float | PositionFunction = _spec(
        1.5e5,
        gt=0,
        check=_position_function_check(positive=True),
        doc="spring stiffness, N/m; two_mass, three_mass: or a function of the cart "
        "position, { poly = [...] } or { positions_m = [...], values = [...] }",
    )
    d: float | PositionFunction = _spec(
        40.0,
        ge=0,
        check=_position_function_check(positive=False),
        doc="two_mass, three_mass: coupling damping, N*s/m; or a function of the cart position like k",
    )
    c: float = _spec(1.0, gt=0, doc="torque-to-force constant, N/(N*m)")
    m: float = _spec(5.0, gt=0, doc="mass_spring_damper: mass, kg")
    b: float = _spec(1.0, ge=0, doc="mass_spring_damper: damping, N*s/m")


@dataclass(frozen=True)
class FrictionConfig:
    model: str = _spec(
        "stribeck",
        choices=("stribeck", "none"),
        doc="stribeck (thesis eq. 2.13, torque at the motor versus cart velocity) or none",
    )
    Fc: float = _spec(1.0, ge=0, doc="Coulomb friction, N*m")
    Fs: float = _spec(1.5, ge=0, doc="static friction, N*m")
    Fv: float = _spec(5.0, ge=0, doc="viscous coefficient, N*m/(m/s)^delta_v")
    vs: float = _spec(0.01, gt=0, doc="Stribeck velocity, m/s")
    delta_v: float = _spec(1.0, gt=0, doc="exponent of the cart velocity in the viscous term")
    delta_s: float = _spec(2.0, gt=0, doc="exponent of the Stribeck term")


@dataclass(frozen=True)
class DriveConfig:
    kp_pos_per_s: float = _spec(20.0, ge=0, doc="position loop gain, 1/s")
    ki_pos_per_s2: float = _spec(
        0.0, ge=0, doc="position loop integral gain, (m/s) per (m*s) of integrated position error (0: a P loop)"
    )
    kd_pos: float = _spec(0.0, ge=0, doc="position loop derivative gain, (m/s) per (m/s) of the error's rate (0: none)")
    kv_nm_per_mps: float = _spec(200.0, ge=0, doc="velocity loop proportional gain")
    ti_s: float = _spec(0.05, gt=0, doc="velocity loop integral time")
    velocity_filter_hz: float = _spec(500.0, gt=0, doc="low-pass of the drive's velocity estimate")
    torque_max_nm: float = _spec(50.0, gt=0, doc="drive torque saturation")
    current_loop_hz: float | None = _spec(
        None,
        gt=0,
        doc="bandwidth of the current loop (first order), Hz; unset: the preset's (bench 1000 Hz, clean ideal)",
    )
    delay_s: float | None = _spec(
        None,
        ge=0,
        le=0.1,
        doc="computation and transport delay before the current "
        "loop, rounded to whole loop ticks; unset: the preset's (bench one tick, clean 0)",
    )
    velocity_feedforward: float = _spec(
        0.0,
        ge=0,
        le=1.5,
        doc="position mode: fraction of the set-point's velocity fed forward to the velocity loop (0: none)",
    )
    accel_feedforward_nm_per_mps2: float = _spec(
        0.0,
        ge=0,
        doc="velocity and position mode: torque fed forward per m/s^2 of "
        "the set-point's acceleration, N*m/(m/s^2) (0: none; (m1+m2)/c "
        "cancels the axis's inertia)",
    )
    viscous_feedforward_nm_per_mps: float = _spec(
        0.0,
        ge=0,
        doc="velocity and position mode: torque fed forward per m/s of the set-point's velocity, N*m/(m/s) "
        "(0: none; the viscous friction cancels it)",
    )
    friction_feedforward_nm: float = _spec(
        0.0,
        ge=0,
        doc="velocity and position mode: torque fed forward with the sign of the set-point's velocity, N*m "
        "(0: none; the Coulomb friction cancels it)",
    )


@dataclass(frozen=True)
class DisturbanceConfig:
    torque_noise_nm: float | None = _spec(
        None,
        ge=0,
        doc="rms of the coloured process torque noise on the axis "
        "(not measured), N*m; unset: the preset's (bench 0.3 % of torque_max_nm)",
    )
    torque_noise_corner_hz: float = _spec(10.0, gt=0, doc="corner of the first-order low-pass colouring it, Hz")
    cogging_nm: float | None = _spec(
        None,
        ge=0,
        doc="amplitude of the torque ripple periodic in position, N*m; "
        "unset: the preset's (bench 0.5 % of torque_max_nm)",
    )
    cogging_period_m: float = _spec(0.01, gt=0, doc="period of the ripple in cart position, m")
    load_step_nm: float | None = _spec(
        None,
        ge=0,
        doc="largest level of random load-torque steps, N*m; unset: the preset's (bench 0.2 % of torque_max_nm)",
    )
    load_step_rate_hz: float = _spec(0.2, ge=0, doc="mean number of load steps per second")
    load_noise_n: float | None = _spec(
        None,
        ge=0,
        doc="rms of the coloured force noise on the load (floor, "
        "process), N; unset: the preset's (bench 0.3 % of c * torque_max_nm)",
    )


@dataclass(frozen=True)
class SensorsConfig:
    encoder_resolution_m: float = _spec(1e-6, ge=0, doc="one encoder count; the position is floored to counts")
    encoder_noise_m: float | None = _spec(
        None,
        ge=0,
        doc="rms of the encoder's interpolation noise before "
        "quantisation, m; unset: the preset's (bench half a count, clean 0)",
    )
    torque_noise_nm: float = _spec(0.02, ge=0, doc="rms noise of the measured torque")
    laser_range_m: list[float] = _spec([-0.005, 0.005], max_items=2, doc="load deflection window the load sensor sees")
    laser_noise_m: float = _spec(0.0, ge=0, doc="rms noise of the load sensor (channel load_position_m)")
    laser_resolution_m: float = _spec(1.2e-4, ge=0, doc="resolution of the load sensor")


@dataclass(frozen=True)
class SerialFaultsConfig:
    """``[emulator.faults.serial]``: faults of the serial board's line."""

    corrupt_frame_rate: float = _spec(0.0, ge=0, le=1, doc="probability that a board->host frame gets a byte flipped")
    drop_frame_rate: float = _spec(0.0, ge=0, le=1, doc="probability that bytes of a frame are lost on the line")
    close_after_s: float = _spec(0.0, ge=0, doc="close the line this long after a run starts; 0: never")


@dataclass(frozen=True)
class CanopenFaultsConfig:
    """``[emulator.faults.canopen]``: faults of an emulated CANopen drive."""

    heartbeat_stops_after_s: float = _spec(0.0, ge=0, doc="the heartbeat stops this long after a run starts")
    abort_object: str = _spec(
        "", check=_check_object_address, doc='every SDO access to this object aborts, "0x3100" or "0x3100:2"'
    )
    drop_pdo_rate: float = _spec(0.0, ge=0, le=1, doc="probability that a TPDO is not sent")


@dataclass(frozen=True)
class ModbusFaultsConfig:
    """``[emulator.faults.modbus]``: faults of an emulated Modbus drive."""

    exception_register: int = _spec(
        -1, ge=-1, le=65535, doc="requests touching this register get an exception; -1: none"
    )
    exception_code: int = _spec(4, ge=1, le=11, doc="the exception code answered (4: server device failure)")
    response_delay_s: float = _spec(0.0, ge=0, doc="every response is delayed this long")
    missing_response_rate: float = _spec(0.0, ge=0, le=1, doc="probability that a request gets no response")
    unknown_unit_id: str = _spec(
        "ignore",
        choices=("ignore", "gateway_exception"),
        doc="Modbus TCP: a request to a unit id other than [device.modbus].device_id and 255 "
        "is ignored, or answered with exception 11 (gateway target device failed to "
        "respond)",
    )


@moved_keys_readable
@dataclass(frozen=True)
class FaultsConfig:
    #: Flat keys of earlier releases and the sub-table each moved to (read with a DeprecationWarning).
    moved_keys: typing.ClassVar[dict[str, str]] = {
        "corrupt_frame_rate": "serial",
        "drop_frame_rate": "serial",
        "close_after_s": "serial",
        "heartbeat_stops_after_s": "canopen",
        "abort_object": "canopen",
        "drop_pdo_rate": "canopen",
        "exception_register": "modbus",
        "exception_code": "modbus",
        "response_delay_s": "modbus",
        "missing_response_rate": "modbus",
        "unknown_unit_id": "modbus",
    }

    drive_fault_after_s: float = _spec(
        0.0,
        ge=0,
        doc="CANopen/Modbus: the drive faults this long (simulated time) "
        "after a run starts (CANopen: EMCY and Fault state); 0: never",
    )
    capture_stops_after_s: float = _spec(
        0.0,
        ge=0,
        doc="CANopen/Modbus buffered and recorder runs: the capture stops "
        "this long (simulated time) after the start; 0: never",
    )
    serial: SerialFaultsConfig = _spec(SerialFaultsConfig(), doc="the serial board's line")
    canopen: CanopenFaultsConfig = _spec(CanopenFaultsConfig(), doc="CANopen drives")
    modbus: ModbusFaultsConfig = _spec(ModbusFaultsConfig(), doc="Modbus drives")


def _entry_check(fields: tuple[str, ...], positive: tuple[str, ...]):
    """``check`` of a list of entries ``[field, ...]`` (numbers the schema checked): mass indices (``i``, ``j``,
    ``mass``) whole numbers, the others >= 0 (> 0 where named in ``positive``)."""
    form = "[" + ", ".join(fields) + "]"

    def check(value: list[list[float]], key: str, source: str) -> None:
        for n, entry in enumerate(value):
            if len(entry) != len(fields):
                raise ConfigError(f"{key}[{n}]", f"must be {form}, got {show(entry)}", source)
            for name, item in zip(fields, entry, strict=True):
                where = f"{key}[{n}].{name}"
                if name in ("i", "j", "mass"):
                    if not item.is_integer():
                        raise ConfigError(where, f"must be a mass index (a whole number), got {show(item)}", source)
                elif not (item > 0 if name in positive else item >= 0):
                    raise ConfigError(where, f"must be {'>' if name in positive else '>='} 0, got {show(item)}", source)

    return check


@dataclass(frozen=True)
class MechanismConfig:
    """``[emulator.mechanism]``: one linear mechanism driven by the twins of several nodes on one bus.

    Lumped masses joined by springs and dampers (to each other or to ground), each node's motor pushing one mass
    and its load sensor watching one (``hilident.emulator.coupled_plant.CoupledModel``). Empty: no mechanism,
    each twin has its own ``[emulator.plant]``.
    """

    masses_kg: list[float] = _spec(
        [], gt=0, max_items=16, doc="mass of each lumped body, kg, indexed 0, 1, ... by the other keys; empty: none"
    )
    links: list[list[float]] = _spec(
        [],
        max_items=64,
        check=_entry_check(("i", "j", "k_n_per_m", "d_ns_per_m"), ()),
        doc="springs and dampers, each [i, j, k_n_per_m, d_ns_per_m]: stiffness N/m and damping N*s/m between "
        "masses i and j (j = -1: ground), not both 0",
    )
    motors: list[list[float]] = _spec(
        [],
        max_items=8,
        check=_entry_check(("mass", "c"), ("c",)),
        doc="one [mass_index, c] per node, in the order of device.canopen.node_ids: the mass its motor pushes "
        "with the force c * torque (c in N/(N*m))",
    )
    sensors: list[int] = _spec(
        [], ge=0, max_items=8, doc="per node, in node order: the mass its load sensor (load_position_m) watches"
    )

    @property
    def defined(self) -> bool:
        """Whether a mechanism is configured (``masses_kg`` given)."""
        return bool(self.masses_kg)


@dataclass(frozen=True)
class EmulatorConfig:
    link: str = _spec(
        "pty",
        choices=("pty", "tcp", "pipe"),
        doc="pseudo-terminal (real serial path), raw TCP on 127.0.0.1 (socket://), or in-memory pipe",
    )
    time_scale: float = _spec(1.0, gt=0, le=100, doc="simulated seconds per wall-clock second")
    seed: int = _spec(1, ge=0, le=2**32 - 1, doc="seed of the sensor noise and the disturbances")
    preset: str = _spec(
        "bench",
        choices=("bench", "clean"),
        doc="defaults of the keys left unset in [emulator.disturbance], [emulator.drive] "
        "(current_loop_hz, delay_s) and [emulator.sensors] (encoder_noise_m): 'bench' as messy as "
        "a real axis, 'clean' none of it (exact physics for tests)",
    )
    plant: PlantConfig = _spec(PlantConfig())
    friction: FrictionConfig = _spec(FrictionConfig())
    drive: DriveConfig = _spec(DriveConfig())
    sensors: SensorsConfig = _spec(SensorsConfig())
    disturbance: DisturbanceConfig = _spec(DisturbanceConfig())
    faults: FaultsConfig = _spec(FaultsConfig())
    mechanism: MechanismConfig = _spec(
        MechanismConfig(),
        doc="CANopen: one mechanism the twins of several nodes drive together (device.canopen.node_ids); empty: none",
    )


@dataclass(frozen=True)
class Config:
    device: DeviceConfig = _spec(DeviceConfig())
    run: RunConfig = _spec(RunConfig())
    limits: LimitsConfig | None = _spec(None)
    data: DataConfig = _spec(DataConfig())
    model: ModelConfig = _spec(ModelConfig())
    friction_test: FrictionTestConfig = _spec(FrictionTestConfig())
    excitation: ExcitationConfig = _spec(ExcitationConfig())
    identification: IdentificationConfig = _spec(IdentificationConfig())
    notch: NotchConfig = _spec(NotchConfig())
    tuning: TuningConfig = _spec(TuningConfig())
    map: MapConfig = _spec(MapConfig())
    batch: BatchConfig = _spec(BatchConfig())
    verification: VerificationConfig = _spec(VerificationConfig())
    emulator: EmulatorConfig = _spec(EmulatorConfig())
    source: str = field(default="", metadata={"internal": True})
    text: str = field(default="", repr=False, metadata={"internal": True})

    @property
    def uses_emulator(self) -> bool:
        return self.device.port == "emulator"

    @property
    def bench_limits(self) -> LimitsConfig:
        """``[limits]``, which every run on a device needs (``hilident identify`` does not).

        Raises
        ------
        ConfigError
            The config has no ``[limits]`` table.
        """
        if self.limits is None:
            raise ConfigError(
                "limits",
                "is required for a bench run: torque_nm, velocity_mps, position_min_m, position_max_m",
                self.source,
            )
        return self.limits


def device_table(device: DeviceConfig, keys=None) -> dict:
    """The ``[device]`` table of ``device`` as a dict for a TOML writer, transport keys in their sub-tables.

    Parameters
    ----------
    device : DeviceConfig
    keys : iterable of str, optional
        The keys to write, flat names (``node_id``) included; default: all of them.
    """
    if keys is None:
        subs = set(DeviceConfig.moved_keys.values())
        keys = [f.name for f in dataclasses.fields(DeviceConfig) if f.name not in subs] + list(DeviceConfig.moved_keys)
    table: dict = {}
    for key in keys:
        sub = DeviceConfig.moved_keys.get(key)
        (table.setdefault(sub, {}) if sub else table)[key] = getattr(device, key)
    return table


def amplitude_ceiling_nm(cfg: Config) -> float:
    """Largest torque amplitude ``amplitude_nm = "auto"`` may choose, N·m: ``auto_max_nm``, else the torque limit.

    What the plan shows and the limit checks use before the trials choose.
    Without ``[limits]`` (``hilident identify``) it is ``auto_max_nm`` or 0.
    """
    e = cfg.excitation
    if e.auto_max_nm:
        return e.auto_max_nm
    return cfg.limits.torque_nm if cfg.limits is not None else 0.0


def auto_coherence_target(cfg: Config) -> float:
    """Coherence ``amplitude_nm = "auto"`` aims for at ``AUTO_BAND_SHARE`` of the band's excited lines.

    ``excitation.auto_coherence``, else ``identification.coherence_threshold``
    + 0.15, at most 0.95 (and never below the threshold itself).
    """
    if cfg.excitation.auto_coherence:
        return cfg.excitation.auto_coherence
    threshold = cfg.identification.coherence_threshold
    return max(threshold, min(threshold + 0.15, 0.95))


# --- loading --------------------------------------------------------------------------------


def read_toml_text(path: str | Path, what: str) -> str:
    """The text of a TOML file, read with bounded memory.

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What the file is, for messages ("configuration", "driver description").

    Raises
    ------
    ConfigError
        The file cannot be read, is larger than :data:`MAX_FILE_BYTES`, or is not
        UTF-8 (the message gives the offset of the first bad byte).
    """
    path = Path(path)
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_FILE_BYTES + 1)
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the path
        raise ConfigError("(file)", f"cannot read {what}: {getattr(exc, 'strerror', None) or exc}", str(path)) from None
    if len(raw) > MAX_FILE_BYTES:
        raise ConfigError(
            "(file)", f"a {what} must be under {MAX_FILE_BYTES // 1024} KiB; this file is larger", str(path)
        )
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(
            "(file)", f"is not UTF-8 text (TOML must be): byte 0x{raw[exc.start]:02x} at offset {exc.start}", str(path)
        ) from None


def parse_toml(text: str, source: str) -> dict:
    """Parse TOML ``text``; any syntax error is a ConfigError naming ``source``."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError("(syntax)", f"not valid TOML: {exc}", source) from None
    except RecursionError:
        raise ConfigError("(syntax)", "arrays or tables are nested too deeply", source) from None


def load_config(path: str | Path) -> Config:
    """Read and validate a TOML configuration file.

    Raises
    ------
    ConfigError
        The file is missing, too large, not UTF-8, not TOML, or a key is unknown,
        of the wrong type or out of range; the message names the key and the file.
    """
    return parse_config(read_toml_text(path, "configuration"), source=str(path))


def parse_config(text: str, source: str = "<string>") -> Config:
    """Validate configuration ``text`` (TOML); ``source`` names it in errors."""
    cfg = build_table(Config, parse_toml(text, source), "", source)
    cfg = dataclasses.replace(cfg, source=source, text=text)
    _cross_check(cfg)
    return _bind_position_spans(cfg)


# --- checks across keys, before anything moves ------------------------------------------------


def _cross_check(cfg: Config) -> None:
    src = cfg.source
    lim = cfg.limits
    exc = cfg.excitation
    _check_port(cfg.device.port, src)
    if lim is not None:
        _check_limits(cfg, lim)
    rng = cfg.emulator.sensors.laser_range_m
    if len(rng) != 2 or rng[0] >= rng[1]:
        raise ConfigError("emulator.sensors.laser_range_m", "must be [min, max] with min < max", src)
    if exc.f_min_hz >= exc.f_max_hz:
        raise ConfigError("excitation.f_min_hz", "must be below excitation.f_max_hz", src)
    check_auto_amplitude(cfg)
    if not exc.amplitude_auto and not exc.amplitude_value > 0:
        unit = {"amplitude_mps": "m/s", "amplitude_m": "m"}.get(exc.amplitude_key, "N*m")
        raise ConfigError(
            f"excitation.{exc.amplitude_key}",
            f"must be set (> 0, in {unit}) for mode = {exc.mode!r}: the set-point perturbation's size",
            src,
        )
    _check_data_and_model(cfg)
    ic = cfg.identification
    if ic.f_min_hz and ic.f_max_hz and ic.f_min_hz >= ic.f_max_hz:
        raise ConfigError("identification.f_min_hz", "must be below identification.f_max_hz", src)
    if exc.f_max_hz >= cfg.run.sample_rate_hz / 2:
        raise ConfigError(
            "excitation.f_max_hz", f"must be below the Nyquist frequency {cfg.run.sample_rate_hz / 2:g} Hz", src
        )
    _check_outputs(ic, src)
    if cfg.run.channels:
        needed = {"excitation", "torque_nm", "velocity_mps", ic.output, *ic.outputs}
        missing = sorted(needed - set(cfg.run.channels))
        if missing:
            raise ConfigError("run.channels", f"the session needs {', '.join(missing)} too", src)
    excitation_samples(cfg)
    if cfg.friction_test.enabled:
        _friction_extent(cfg)
    _check_position_functions(cfg)
    _check_nodes(cfg)
    _check_mechanism(cfg)


def _check_outputs(ic: IdentificationConfig, src: str) -> None:
    """``identification.outputs``: other channels than ``output``, each named once."""
    if ic.output in ic.outputs:
        raise ConfigError("identification.outputs", f"names identification.output ({ic.output!r}) again", src)
    if len(set(ic.outputs)) != len(ic.outputs):
        raise ConfigError("identification.outputs", "names a channel twice", src)


def _check_position_functions(cfg: Config) -> None:
    """``[emulator.plant]`` k and d given as functions of the cart position: the models they apply to, and a
    polynomial's sign over the ``[limits]`` position window (a table's was checked with the table)."""
    plant, src = cfg.emulator.plant, cfg.source
    for name, positive in (("k", True), ("d", False)):
        value = getattr(plant, name)
        if not isinstance(value, PositionFunction):
            continue
        key = f"emulator.plant.{name}"
        if plant.model == "mass_spring_damper":
            raise ConfigError(
                key,
                "a function of the cart position applies to the cart-to-load coupling of "
                "two_mass and three_mass; mass_spring_damper takes a number",
                src,
            )
        if value.is_table:
            continue
        if cfg.limits is None:
            raise ConfigError(
                key,
                "a polynomial needs [limits] position_min_m and position_max_m: it is checked "
                "over that window and held at its ends beyond it",
                src,
            )
        lo, hi = cfg.limits.position_min_m, cfg.limits.position_max_m
        at, least = polynomial_minimum(value.poly, lo, hi)
        if not (least > 0 if positive else least >= 0):
            raise ConfigError(
                key,
                f"must be {'> 0' if positive else '>= 0'} over the position window "
                f"[{lo:g}, {hi:g}] m of [limits]; the polynomial is {least:.6g} at {at:.6g} m",
                src,
            )


def node_ids(device: DeviceConfig) -> list[int]:
    """The CANopen nodes of a session: ``[device.canopen] node_ids``, else ``node_id`` alone."""
    return list(device.canopen.node_ids) or [device.canopen.node_id]


def _check_nodes(cfg: Config) -> None:
    """``node_ids`` starts with ``node_id`` (the node a session of one drive, and every message, names first)."""
    c = cfg.device.canopen
    if c.node_ids and c.node_ids[0] != c.node_id:
        raise ConfigError(
            "device.canopen.node_ids",
            f"must start with device.canopen.node_id ({c.node_id}), got {show(c.node_ids)}: "
            f"set node_id = {c.node_ids[0]} or list node {c.node_id} first",
            cfg.source,
        )


def _check_mechanism(cfg: Config) -> None:
    """``[emulator.mechanism]``: required by a twin of several nodes; one motor and one sensor per node, every
    index naming a mass."""
    mech, src = cfg.emulator.mechanism, cfg.source
    nodes = len(node_ids(cfg.device))
    if not mech.defined:
        given = [name for name in ("links", "motors", "sensors") if getattr(mech, name)]
        if given:
            raise ConfigError(
                "emulator.mechanism.masses_kg", f"is empty while {given[0]} is given: name the masses", src
            )
        if nodes > 1 and cfg.uses_emulator:
            raise ConfigError(
                "emulator.mechanism",
                f'is required for the twin of {nodes} nodes (device.canopen.node_ids on port = "emulator"): '
                "masses_kg, links, motors (one per node) and sensors of the mechanism they drive",
                src,
            )
        return
    for name in ("motors", "sensors"):
        count = len(getattr(mech, name))
        if count != nodes:
            raise ConfigError(
                f"emulator.mechanism.{name}",
                f"has {count} {'entry' if count == 1 else 'entries'} for {nodes} node(s) (device.canopen.node_ids "
                "or node_id): one per node, in node order",
                src,
            )
    _check_mass_indices(mech, src)


def _check_mass_indices(mech: MechanismConfig, src: str) -> None:
    """Every index of ``links``, ``motors`` and ``sensors`` names a mass (a link's ``j`` may be -1, ground)."""
    n = len(mech.masses_kg)
    named = [(f"links[{k}].i", link[0], False) for k, link in enumerate(mech.links)]
    named += [(f"links[{k}].j", link[1], True) for k, link in enumerate(mech.links)]
    named += [(f"motors[{k}].mass", motor[0], False) for k, motor in enumerate(mech.motors)]
    named += [(f"sensors[{k}]", i, False) for k, i in enumerate(mech.sensors)]
    for key, i, ground in named:
        if not (0 <= i < n or (ground and i == -1)):
            where = f"0..{n - 1}" + (" or -1 (ground)" if ground else "")
            raise ConfigError(f"emulator.mechanism.{key}", f"must be a mass index {where}, got {i:g}", src)
    for k, (i, j, stiffness, damping) in enumerate(mech.links):
        if i == j:
            raise ConfigError(f"emulator.mechanism.links[{k}].j", f"must differ from i ({i:g}): a link joins two", src)
        if stiffness == 0 and damping == 0:
            raise ConfigError(f"emulator.mechanism.links[{k}]", "has k = 0 and d = 0: it joins nothing", src)


def polynomial_minimum(coefficients, lo: float, hi: float) -> tuple[float, float]:
    """Where on ``[lo, hi]`` the polynomial ``c0 + c1 p + ...`` is smallest, and its value there.

    Parameters
    ----------
    coefficients : sequence of float
        Constant term first.
    lo, hi : float
        The interval, ``lo <= hi``.

    Returns
    -------
    (position, value) : tuple of float

    Examples
    --------
    >>> polynomial_minimum([1.0, 0.0, -1.0], -2.0, 1.0)
    (-2.0, -3.0)
    """
    import numpy as np
    from numpy.polynomial import polynomial as P

    c = np.asarray(coefficients, dtype=float)
    candidates = [np.linspace(lo, hi, 513)]
    if c.size > 2:
        roots = P.polyroots(P.polyder(c))
        real = roots.real[np.abs(roots.imag) <= 1e-9 * (1.0 + np.abs(roots.real))]
        candidates.append(real[(real >= lo) & (real <= hi)])
    p = np.concatenate(candidates)
    v = P.polyval(p, c)
    i = int(np.argmin(v))
    return float(p[i]), float(v[i])


def _bind_position_spans(cfg: Config) -> Config:
    """``cfg`` with each polynomial k or d of ``[emulator.plant]`` held beyond the ``[limits]`` window it was
    checked over (:attr:`PositionFunction.span_m`)."""
    plant, lim = cfg.emulator.plant, cfg.limits
    if lim is None:
        return cfg
    bound: dict[str, typing.Any] = {
        name: dataclasses.replace(value, span_m=(lim.position_min_m, lim.position_max_m))
        for name, value in (("k", plant.k), ("d", plant.d))
        if isinstance(value, PositionFunction) and not value.is_table
    }
    if not bound:
        return cfg
    return dataclasses.replace(
        cfg, emulator=dataclasses.replace(cfg.emulator, plant=dataclasses.replace(plant, **bound))
    )


def check_auto_amplitude(cfg: Config) -> None:
    """``amplitude_nm = "auto"``: a multisine (trials are whole periods of it), within the limits."""
    e, src = cfg.excitation, cfg.source
    if not e.amplitude_auto:
        return
    if e.kind != "multisine":
        raise ConfigError(
            "excitation.amplitude_nm",
            f'"auto" needs kind = "multisine" (the trials are whole '
            f"periods of it), got kind = {e.kind!r}; give a number",
            src,
        )
    ceiling = amplitude_ceiling_nm(cfg)
    if cfg.limits is not None and e.auto_max_nm > cfg.limits.torque_nm:
        raise ConfigError(
            "excitation.auto_max_nm", f"{e.auto_max_nm:g} N*m exceeds limits.torque_nm = {cfg.limits.torque_nm:g}", src
        )
    if ceiling and e.auto_start_nm > ceiling:
        raise ConfigError(
            "excitation.auto_start_nm",
            f"{e.auto_start_nm:g} N*m is above the largest amplitude auto "
            f"may choose ({ceiling:g} N*m: excitation.auto_max_nm, else "
            "limits.torque_nm)",
            src,
        )


def _check_data_and_model(cfg: Config) -> None:
    """``[data]`` and ``[model]`` keys that only make sense together."""
    d, m, src = cfg.data, cfg.model, cfg.source
    if d.period_s and d.period_samples:
        raise ConfigError("data.period_samples", "give the period once: data.period_s or data.period_samples", src)
    if d.period_s and d.sample_rate_hz:
        exact = d.period_s * d.sample_rate_hz
        if abs(exact - round(exact)) > 1e-6 * max(exact, 1.0) or round(exact) < 4:
            raise ConfigError(
                "data.period_s",
                f"{d.period_s:g} s is {exact:.6g} samples at data.sample_rate_hz = "
                f"{d.sample_rate_hz:g} Hz: a period must be a whole number (>= 4) of "
                "samples (or give data.period_samples)",
                src,
            )
    if 0 < d.period_samples < 4:
        raise ConfigError("data.period_samples", f"must be >= 4 samples, got {d.period_samples}", src)
    if len(set(d.column_names)) != len(d.column_names):
        raise ConfigError("data.column_names", "names a column twice", src)
    _check_channel_lists(d, src)
    if m.kind != "rigid_axis":
        for key, default in (("asymmetric", False), ("min_speed", 0.0)):
            if getattr(m, key) != default:
                raise ConfigError(f"model.{key}", f'applies to kind = "rigid_axis" only (kind is {m.kind!r})', src)


def _check_channel_lists(d: DataConfig, src: str) -> None:
    """``data.inputs`` and ``data.outputs`` come together, each scale and unit list as long as its columns."""
    if bool(d.inputs) != bool(d.outputs):
        given, missing = ("inputs", "outputs") if d.inputs else ("outputs", "inputs")
        raise ConfigError(f"data.{missing}", f"is empty while data.{given} is given: name both", src)
    lists: tuple[tuple[str, list[str], list], ...] = (
        ("input_scales", d.inputs, d.input_scales),
        ("output_scales", d.outputs, d.output_scales),
        ("output_units", d.outputs, d.output_units),
    )
    for key, names, values in lists:
        if values and len(values) != len(names):
            columns = "inputs" if key.startswith("input") else "outputs"
            raise ConfigError(f"data.{key}", f"has {len(values)} entries for {len(names)} data.{columns}", src)
    for key, scales in (("input_scales", d.input_scales), ("output_scales", d.output_scales)):
        if any(not (math.isfinite(v) and v > 0) for v in scales):
            raise ConfigError(f"data.{key}", f"must be finite numbers > 0, got {scales}", src)
    if set(d.inputs) & set(d.outputs):
        raise ConfigError("data.outputs", f"names an input column too: {sorted(set(d.inputs) & set(d.outputs))}", src)


def _check_limits(cfg: Config, lim: LimitsConfig) -> None:
    """Every experiment of the run within ``[limits]``: the excitation, the friction test, the map and the move."""
    if lim.position_min_m >= lim.position_max_m:
        raise ConfigError("limits.position_min_m", "must be below limits.position_max_m", cfg.source)
    _check_excitation_limits(cfg, lim)
    _check_friction_test_limits(cfg, lim)
    if cfg.map.enabled:
        map_positions(cfg)
    if cfg.verification.move is not None:
        _check_move_limits(cfg.verification.move, lim, cfg.source)


def _check_excitation_limits(cfg: Config, lim: LimitsConfig) -> None:
    """The excitation's amplitude within the torque, speed or position window of ``[limits]``."""
    src, exc = cfg.source, cfg.excitation
    if exc.mode in ("torque", "torque_injection") and exc.amplitude_value > lim.torque_nm:
        raise ConfigError(
            "excitation.amplitude_nm", f"{exc.amplitude_value:g} N*m exceeds limits.torque_nm = {lim.torque_nm:g}", src
        )
    if exc.mode == "velocity" and exc.amplitude_mps >= lim.velocity_mps:
        raise ConfigError(
            "excitation.amplitude_mps",
            f"{exc.amplitude_mps:g} m/s reaches limits.velocity_mps = {lim.velocity_mps:g}",
            src,
        )
    if exc.mode == "position" and 2 * exc.amplitude_m >= lim.position_max_m - lim.position_min_m:
        raise ConfigError(
            "excitation.amplitude_m",
            f"{exc.amplitude_m:g} m each way does not fit the position "
            f"window [{lim.position_min_m:g}, {lim.position_max_m:g}] m",
            src,
        )


def _check_friction_test_limits(cfg: Config, lim: LimitsConfig) -> None:
    """The friction test's speeds below ``limits.velocity_mps`` and its travel within half the position window."""
    src, ft = cfg.source, cfg.friction_test
    if any(v <= 0 for v in ft.speeds_mps):
        raise ConfigError("friction_test.speeds_mps", "speeds must be positive (each is run both ways)", src)
    if ft.enabled and max(ft.speeds_mps, default=0) >= lim.velocity_mps:
        raise ConfigError(
            "friction_test.speeds_mps", f"a speed reaches limits.velocity_mps = {lim.velocity_mps:g}", src
        )
    if ft.settle_s >= ft.hold_s:
        raise ConfigError("friction_test.settle_s", "must be shorter than friction_test.hold_s", src)
    if not ft.enabled:
        return
    n_samples, travel = _friction_extent(cfg)
    if travel >= (lim.position_max_m - lim.position_min_m) / 2:
        raise ConfigError(
            "friction_test.speeds_mps",
            f"the friction test travels up to {travel:.3f} m, more than half the position window "
            f"[{lim.position_min_m:g}, {lim.position_max_m:g}] m (shorter hold_s or lower speeds)",
            src,
        )
    fixed_s = n_samples / cfg.run.sample_rate_hz
    if ft.target_ci_percent > 0 and ft.max_duration_s < fixed_s:
        raise ConfigError(
            "friction_test.max_duration_s",
            f"{ft.max_duration_s:g} s is shorter than the configured legs ({fixed_s:.3g} s), which the test "
            "always plays (a longer max_duration_s, or target_ci_percent = 0 for the configured legs only)",
            src,
        )


def _check_move_limits(move: MoveConfig, lim: LimitsConfig, src: str) -> None:
    """``[verification] move``: non-zero, shorter than half the position window, slower than the speed limit."""
    if move.distance_m == 0 or 2 * abs(move.distance_m) >= lim.position_max_m - lim.position_min_m:
        raise ConfigError(
            "verification.move.distance_m",
            f"{move.distance_m:g} m: a move must be non-zero and "
            "shorter than half the position window "
            f"[{lim.position_min_m:g}, {lim.position_max_m:g}] m",
            src,
        )
    if move.max_velocity_mps >= lim.velocity_mps:
        raise ConfigError(
            "verification.move.max_velocity_mps",
            f"{move.max_velocity_mps:g} m/s reaches limits.velocity_mps = {lim.velocity_mps:g}",
            src,
        )


def map_positions(cfg: Config) -> list[float]:
    """The cart positions ``[map]`` asks for, m: ``positions_m`` as given, or ``count`` spread evenly over the
    position window less ``margin_m``.

    Raises
    ------
    ConfigError
        Both or fewer than two positions are given, a position lies outside the window less the margin, or the
        moves between them would reach ``[limits] velocity_mps``.
    """
    m, src, lim = cfg.map, cfg.source, cfg.bench_limits
    if m.positions_m and m.count:
        raise ConfigError("map.count", "give either map.positions_m or map.count, not both", src)
    lo, hi = lim.position_min_m + m.margin_m, lim.position_max_m - m.margin_m
    if lo >= hi:
        raise ConfigError(
            "map.margin_m",
            f"{m.margin_m:g} m leaves nothing of the position window "
            f"[{lim.position_min_m:g}, {lim.position_max_m:g}] m",
            src,
        )
    positions = [float(p) for p in m.positions_m] or [lo + (hi - lo) * i / max(m.count - 1, 1) for i in range(m.count)]
    if len(positions) < 2:
        raise ConfigError(
            "map.positions_m" if m.positions_m else "map.count", "a map needs at least two positions", src
        )
    outside = [p for p in positions if not lo <= p <= hi]
    if outside:
        raise ConfigError(
            "map.positions_m",
            f"{outside[0]:g} m is outside the position window less map.margin_m, [{lo:g}, {hi:g}] m",
            src,
        )
    e = cfg.excitation
    if m.amplitude_nm >= lim.torque_nm:
        raise ConfigError(
            "map.amplitude_nm", f"{m.amplitude_nm:g} N*m reaches limits.torque_nm = {lim.torque_nm:g}", src
        )
    if m.duration_s and e.kind == "multisine" and m.duration_s < e.period_s:
        raise ConfigError(
            "map.duration_s",
            f"{m.duration_s:g} s is shorter than one excitation period (excitation.period_s = {e.period_s:g} s)",
            src,
        )
    if m.max_velocity_mps >= lim.velocity_mps:
        raise ConfigError(
            "map.max_velocity_mps",
            f"{m.max_velocity_mps:g} m/s reaches limits.velocity_mps = {lim.velocity_mps:g}",
            src,
        )
    return positions


_PYSERIAL_FILE_OPTIONS = {"spy": ("file",)}


def _check_port(port: str, source: str) -> None:
    """Refuse pyserial URLs that write files (``spy://...?file=PATH`` truncates PATH on open)."""
    scheme, sep, rest = port.partition("://")
    if not sep:
        return
    options = _PYSERIAL_FILE_OPTIONS.get(scheme.strip().lower())
    if not options:
        return
    query = urllib.parse.urlsplit("x://" + rest).query
    given = {name.strip().lower() for name in urllib.parse.parse_qs(query, keep_blank_values=True)}
    if given.intersection(options):
        raise ConfigError(
            "device.port",
            f"{show(port)}: a {scheme}:// port with a file= option would create or overwrite that "
            f"file outside --out; leave file= out ({scheme}:// then logs the traffic to stderr)",
            source,
        )


def excitation_samples(cfg: Config) -> int:
    """Samples the identification excitation of ``cfg`` will hold, checked without building it.

    Mirrors ``session.build_excitation``: a multisine plays one lead-in period and
    the whole periods that fit ``duration_s``; a PRBS one extra period.

    Raises
    ------
    ConfigError
        The excitation would exceed :data:`~hilident.signals._checks.MAX_SAMPLES`,
        a multisine period is longer than the run or holds no line of the band, a
        sine or square frequency is not below Nyquist, or the fades do not fit.
    """
    e, fs, src = cfg.excitation, cfg.run.sample_rate_hz, cfg.source

    def refuse(key, exact, what):
        raise ConfigError(
            key,
            f"{what} would take {exact:.4g} samples at {fs:g} Hz, more than the {MAX_SAMPLES} "
            f"(2**25) one experiment may hold",
            src,
        )

    exact = e.duration_s * fs
    if not exact <= MAX_SAMPLES:
        refuse("excitation.duration_s", exact, f"{e.duration_s:g} s")
    if exact < 1:
        raise ConfigError("excitation.duration_s", f"{e.duration_s:g} s is shorter than one sample at {fs:g} Hz", src)
    fade_applies = True
    if e.kind == "multisine":
        total = _multisine_samples(cfg)
        fade_applies = False
    elif e.kind == "prbs":
        length = (2**e.register_length - 1) * e.clock_divider
        periods = max(1, int(round(exact / length)))
        total = (periods + 1) * length
        if total > MAX_SAMPLES:
            key = "excitation.clock_divider" if e.clock_divider > 1 else "excitation.register_length"
            refuse(
                key, total, f"{periods + 1} PRBS periods of (2**{e.register_length} - 1) * {e.clock_divider} samples"
            )
        fade_applies = periods < 3
    else:
        total = int(round(exact))
        if e.kind == "noise" and math.floor(e.f_max_hz * total / fs) < math.ceil(e.f_min_hz * total / fs):
            raise ConfigError(
                "excitation.duration_s",
                f"{e.duration_s:g} s is too short: no frequency line (spacing {fs / total:g} Hz) lies in the band",
                src,
            )
        if e.kind in ("sine", "square") and e.frequency_hz >= fs / 2:
            raise ConfigError(
                "excitation.frequency_hz",
                f"must be below the Nyquist frequency {fs / 2:g} Hz, got {e.frequency_hz:g}",
                src,
            )
    if fade_applies and 2 * round(e.fade_s * fs) > total:  # as signals.fade counts its ramps
        raise ConfigError(
            "excitation.fade_s", f"two fades of {e.fade_s:g} s do not fit into the {total / fs:g} s excitation", src
        )
    return total


def _multisine_samples(cfg: Config) -> int:
    e, fs, src = cfg.excitation, cfg.run.sample_rate_hz, cfg.source
    if e.period_s > e.duration_s:
        raise ConfigError(
            "excitation.period_s",
            f"{e.period_s:g} s is longer than excitation.duration_s = {e.duration_s:g} s; whole periods are played",
            src,
        )
    period = int(round(e.period_s * fs))
    if period < 2:
        raise ConfigError("excitation.period_s", f"{e.period_s:g} s is shorter than two samples at {fs:g} Hz", src)
    df = fs / period
    k_min = max(1, math.ceil(e.f_min_hz / df - 1e-9))
    k_max = min((period - 1) // 2, math.floor(e.f_max_hz / df + 1e-9))
    if k_max < k_min:
        raise ConfigError(
            "excitation.period_s",
            f"no frequency line (spacing {df:g} Hz) lies in [{e.f_min_hz:g}, {e.f_max_hz:g}] Hz; lengthen the period",
            src,
        )
    total = (max(1, int(round(e.duration_s / e.period_s))) + 1) * period  # one lead-in period
    if total > MAX_SAMPLES:
        raise ConfigError(
            "excitation.duration_s",
            f"the multisine would take {total} samples, more than the {MAX_SAMPLES} (2**25) one experiment may hold",
            src,
        )
    return total


def _friction_extent(cfg: Config) -> tuple[int, float]:
    """Samples and travel (m) of the friction test's velocity ramps, checked without building them."""
    ft = cfg.friction_test
    try:
        return ramp_extent(ft.speeds_mps, ft.hold_s, ft.accel_mps2, cfg.run.sample_rate_hz, ft.settle_s)
    except ConfigError as exc:
        key = "run.sample_rate_hz" if exc.key == "sample_rate_hz" else f"friction_test.{exc.key}"
        raise ConfigError(key, exc.message, cfg.source) from None
