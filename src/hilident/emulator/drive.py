"""The emulated servo drive: a cascade controller, filter slots and limits around a plant.

One loop tick (period ``1 / loop_rate_hz``) does what a real drive does:

1. sample the sensors (encoder, laser) at the tick's start;
2. estimate the velocity by a backward difference of successive encoder positions
   through a first-order low-pass at ``velocity_filter_hz``;
3. check the velocity and position limits (trip: torque 0 from this tick on);
4. compute the torque command for the mode (position P -> velocity PI -> torque);
5. pass it through the enabled biquad slots, check the torque limit, saturate at
   ``torque_max_nm``;
6. after ``delay_ticks`` ticks of computation and transport delay, the current loop
   (first order, bandwidth ``current_loop_hz``) makes the motor torque follow that
   command; the drive reports this torque (its measured current) through the torque
   sensor;
7. hold the motor torque, plus any process disturbance the drive does not measure
   (:class:`~hilident.emulator.disturbance.ProcessDisturbance`), on the plant for
   the tick.

The drive knows only its measurements; it never sees the true state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from hilident.emulator.coupled_plant import PlantPort
from hilident.emulator.disturbance import ProcessDisturbance
from hilident.emulator.plant import Plant
from hilident.emulator.sensors import SensorModel
from hilident.errors import ConfigError, DataError, DeviceError
from hilident.filters.biquad import BiquadChain
from hilident.protocol.loop_parameters import FEEDFORWARD, POSITION_TERMS

__all__ = ["DriveTuning", "DriveLoop", "MODES", "FAULTS"]

MODES = ("torque", "torque_injection", "velocity", "position")
FAULTS = ("torque_limit", "velocity_limit", "position_limit")


@dataclass(frozen=True)
class DriveTuning:
    """Cascade controller settings of a servo drive.

    The defaults suit an axis of about 10 kg with ``c`` about 10 N/(N·m); tune them
    for the plant at hand.

    Parameters
    ----------
    loop_rate_hz : float
        Control loop rate, Hz; one output row per tick.
    kp_pos_per_s : float
        Position loop gain, (m/s) of velocity set-point per m of position error.
    kv_nm_per_mps : float
        Velocity loop proportional gain, N·m per (m/s).
    ti_s : float
        Velocity loop integral time, s (``math.inf`` for a P controller).
    velocity_filter_hz : float
        Cut-off of the first-order low-pass on the velocity estimate, Hz.
    torque_max_nm : float
        Torque saturation of the power stage, N·m.
    current_loop_hz : float
        Bandwidth of the current (torque) loop, Hz: the motor torque follows the
        command through a first-order lag; ``math.inf`` for an ideal loop.
    delay_ticks : int
        Computation and transport delay between the controller's command and the
        current loop, in loop ticks (0: none).
    velocity_feedforward : float
        Position mode: fraction of the set-point's velocity added to the velocity
        set-point (0: none, 1: full), as servo drives do in cyclic position mode.
    accel_feedforward_nm_per_mps2 : float
        Torque added per m/s^2 of the set-point's acceleration, N·m/(m/s^2) (the
        axis's inertia over ``c`` cancels the lag of the loops; 0: none).
    viscous_feedforward_nm_per_mps : float
        Torque added per m/s of the set-point's velocity, N·m/(m/s) (the viscous
        friction; 0: none).
    friction_feedforward_nm : float
        Torque added with the sign of the set-point's velocity, N·m (the Coulomb
        friction; 0: none).
    ki_pos_per_s2 : float
        Position loop integral gain, (m/s) per (m·s) of integrated position error (0: none).
    kd_pos : float
        Position loop derivative gain, (m/s) per (m/s) of the position error's backward difference (0: none).

    The torque terms act in velocity and in position mode. The set-point's
    velocity is the velocity set-point itself in velocity mode, the backward
    difference of the position set-point in position mode; its acceleration is
    the backward difference of that velocity; both differences are over the
    set-point period (:attr:`DriveLoop.setpoint_ticks`).
    """

    loop_rate_hz: float = 4000.0
    kp_pos_per_s: float = 20.0
    kv_nm_per_mps: float = 100.0
    ti_s: float = 0.05
    velocity_filter_hz: float = 500.0
    torque_max_nm: float = 50.0
    current_loop_hz: float = math.inf
    delay_ticks: int = 0
    velocity_feedforward: float = 0.0
    accel_feedforward_nm_per_mps2: float = 0.0
    viscous_feedforward_nm_per_mps: float = 0.0
    friction_feedforward_nm: float = 0.0
    ki_pos_per_s2: float = 0.0
    kd_pos: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "delay_ticks":
                if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 1000:
                    raise ConfigError(f.name, f"must be an int in [0, 1000], got {value!r}")
                continue
            try:
                x = float(value)
            except (TypeError, ValueError):
                raise ConfigError(f.name, f"must be a number, got {value!r}") from None
            finite_ok = f.name in ("ti_s", "current_loop_hz")
            zero_ok = f.name in FEEDFORWARD or f.name in POSITION_TERMS  # 0: the term is off
            low_ok = x >= 0.0 if zero_ok else x > 0.0
            if isinstance(value, bool) or not low_ok or (not finite_ok and not math.isfinite(x)):
                bound = (">= 0" if zero_ok else "> 0") + ("" if finite_ok else " and finite")
                raise ConfigError(f.name, f"must be {bound}, got {value!r}")
            object.__setattr__(self, f.name, x)

    def cascade_values(self) -> dict[str, float]:
        """The cascade's parameters and feed-forward terms (the names of ``[loop]``, cascade form), SI units."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name not in ("loop_rate_hz", "torque_max_nm")}


class DriveLoop:
    """A servo drive closing its loops around a :class:`~hilident.emulator.plant.Plant`.

    Parameters
    ----------
    plant : Plant or PlantPort
        The plant (or a port of a :class:`~hilident.emulator.coupled_plant.CoupledPlant`); the drive steps it one
        tick at a time. Set its initial state before building the drive (the velocity estimator starts from it).
    tuning : DriveTuning
    sensors : SensorModel
    n_filter_slots : int
        Number of biquad slots in :attr:`filters`.
    disturbance : ProcessDisturbance, optional
        Unmeasured torque added on the plant every tick; None for none.

    Attributes
    ----------
    filters : BiquadChain
        Slots applied in series to the torque command (after excitation injection,
        before the torque limit and saturation). Write coefficients with
        ``filters.write(slot, Biquad(b, a), enabled=True)``.
    mode : str
        One of :data:`MODES`:

        * ``"torque"``: excitation is the torque command (N·m), loops open;
        * ``"torque_injection"``: the cascade holds the position measured at
          :meth:`enable`, and the excitation (N·m) is added to the velocity
          controller's output -- how drives measure Bode plots;
        * ``"velocity"``: excitation is the velocity set-point (m/s);
        * ``"position"``: excitation is the position set-point (m) relative to the
          position measured at :meth:`enable`.
    enabled : bool
    fault : str or None
        One of :data:`FAULTS` after a trip, else None.
    fault_tick : int or None
        Tick index (row of the global tick count) at which the trip happened.
    fault_value : float or None
        The offending value: filtered torque command (N·m), velocity estimate (m/s)
        or encoder position (m).
    tick : int
        Number of ticks run so far; the next row's ``time_s`` is ``tick / loop_rate_hz``.

    Examples
    --------
    >>> from hilident.emulator.plant import Plant, TwoMass
    >>> drive = DriveLoop(Plant(TwoMass(8.0, 2.0, 8e4, 20.0, c=10.0)), DriveTuning(),
    ...                   SensorModel(seed=0))
    >>> drive.set_mode("velocity"); drive.enable()
    >>> rows = drive.run(np.full(4000, 0.1))      # 1 s at 0.1 m/s
    >>> rows.shape
    (4000, 7)
    >>> bool(abs(rows[-400:, DriveLoop.CHANNELS.index("velocity_mps")].mean() - 0.1) < 1e-3)
    True
    """

    CHANNELS = ("time_s", "excitation", "torque_cmd_nm", "torque_nm", "position_m", "velocity_mps", "load_position_m")
    #: Units aligned with :attr:`CHANNELS`; the excitation's unit depends on the mode
    #: (:attr:`EXCITATION_UNITS`, or :attr:`units` for the current mode).
    UNITS = ("s", "", "N·m", "N·m", "m", "m/s", "m")
    EXCITATION_UNITS = {"torque": "N·m", "torque_injection": "N·m", "velocity": "m/s", "position": "m"}

    @classmethod
    def columns_of(cls, names, what: str) -> list[int]:
        """Row columns of the channels ``names`` (``what`` names them in the error).

        Raises
        ------
        ValueError
            A name that is not one of :attr:`CHANNELS`.
        """
        try:
            return [list(cls.CHANNELS).index(name) for name in names]
        except ValueError as exc:
            raise ValueError(f"{what} not produced by the drive loop: {exc}") from None

    def __init__(
        self,
        plant: Plant | PlantPort,
        tuning: DriveTuning,
        sensors: SensorModel,
        n_filter_slots: int = 4,
        disturbance: ProcessDisturbance | None = None,
    ):
        if not isinstance(plant, Plant | PlantPort):
            raise TypeError(f"plant must be a Plant or a PlantPort, got {type(plant).__name__}")
        if not isinstance(tuning, DriveTuning):
            raise TypeError(f"tuning must be a DriveTuning, got {type(tuning).__name__}")
        if not isinstance(sensors, SensorModel):
            raise TypeError(f"sensors must be a SensorModel, got {type(sensors).__name__}")
        if isinstance(n_filter_slots, bool) or not isinstance(n_filter_slots, int) or n_filter_slots < 0:
            raise ConfigError("n_filter_slots", f"must be an int >= 0, got {n_filter_slots!r}")
        if disturbance is not None and not isinstance(disturbance, ProcessDisturbance):
            raise TypeError(f"disturbance must be a ProcessDisturbance or None, got {type(disturbance).__name__}")
        self.plant = plant
        self.disturbance = disturbance if disturbance is not None and disturbance.active else None
        self.tuning = tuning
        self.sensors = sensors
        self.filters = BiquadChain(n_filter_slots)
        self.period_s = 1.0 / tuning.loop_rate_hz
        self.mode = "torque"
        self.enabled = False
        self.fault: str | None = None
        self.fault_tick: int | None = None
        self.fault_value: float | None = None
        self.tick = 0
        self.torque_limit_nm = math.inf
        self.velocity_limit_mps = math.inf
        self.position_min_m = -math.inf
        self.position_max_m = math.inf
        self.hold_position_m = sensors.encoder(plant.p1)
        self.torque_offset_nm = 0.0  # added to the torque command in every mode (a CiA 402 drive's 0x60B2)
        #: Loop ticks per set-point (the host's sample period over the loop's): the feed-forward's differences
        #: are taken over it. Set by what plays the set-points (:class:`hilident.emulator.clock.TablePlayer`,
        #: the CANopen twin's SYNC handler).
        self.setpoint_ticks = 1
        # position mode: last set-point, its velocity and acceleration, tick in its period (None: none yet)
        self._setpoint: tuple[float, float, float, int] | None = None
        self._last_position = self.hold_position_m
        self._velocity = 0.0
        self._integral = 0.0
        # the position controller's integral and last error (None: none yet), when it has those terms
        self._position_state: list = [0.0, None]
        # Commands on their way to the current loop (oldest first) and the motor torque.
        self._pending = [0.0] * tuning.delay_ticks
        self._motor_torque = 0.0

    # -- configuration -------------------------------------------------------

    @property
    def units(self) -> tuple[str, ...]:
        """Units of :attr:`CHANNELS` in the current mode."""
        return (self.UNITS[0], self.EXCITATION_UNITS[self.mode], *self.UNITS[2:])

    def set_mode(self, mode: str) -> None:
        """Select the operating mode (one of :data:`MODES`); resets the integrator and the feed-forward's set-point."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        self.mode = mode
        self._integral = 0.0
        self._position_state[:] = [0.0, None]
        self._setpoint = None  # a set-point of another mode starts no difference

    def set_limits(
        self,
        torque_nm: float | None = None,
        velocity_mps: float | None = None,
        position_min_m: float | None = None,
        position_max_m: float | None = None,
    ) -> None:
        """Set the trip limits; None removes a limit.

        Parameters
        ----------
        torque_nm : float, optional
            Trip when the filtered torque command's magnitude exceeds this, N·m.
        velocity_mps : float, optional
            Trip when the velocity estimate's magnitude exceeds this, m/s.
        position_min_m, position_max_m : float, optional
            Absolute window of the encoder position, m (the same axis as
            ``position_m``, not relative to the enable position).
        """

        def positive(key, v):
            if v is None:
                return math.inf
            x = float(v)
            if not x > 0.0:
                raise ConfigError(key, f"must be > 0, got {v!r}")
            return x

        def finite(key, v, default):
            if v is None:
                return default
            x = float(v)
            if not math.isfinite(x):
                raise ConfigError(key, f"must be finite, got {v!r}")
            return x

        t = positive("torque_nm", torque_nm)
        v = positive("velocity_mps", velocity_mps)
        lo = finite("position_min_m", position_min_m, -math.inf)
        hi = finite("position_max_m", position_max_m, math.inf)
        if not lo < hi:
            raise ConfigError("position_max_m", f"must exceed position_min_m={lo!r}, got {hi!r}")
        self.torque_limit_nm = t
        self.velocity_limit_mps = v
        self.position_min_m = lo
        self.position_max_m = hi

    # -- state machine ------------------------------------------------------

    def enable(self) -> None:
        """Close the loops: capture the hold position, reset integrator and filter states.

        Raises
        ------
        DeviceError
            While a fault is set; call :meth:`clear_fault` first.
        """
        if self.fault is not None:
            raise DeviceError(f"drive fault {self.fault!r} at tick {self.fault_tick}; clear_fault() before enable()")
        self.hold_position_m = self.sensors.encoder(self.plant.p1)
        self._setpoint = None  # the first set-point after enabling starts the feed-forward's differences
        self._integral = 0.0
        self._position_state[:] = [0.0, None]
        self.filters.reset()
        self.enabled = True

    def disable(self) -> None:
        """Open the loops: torque 0, integrator reset."""
        self.enabled = False
        self._integral = 0.0

    def clear_fault(self) -> None:
        """Reset the fault; the drive stays disabled until :meth:`enable`."""
        self.fault = None
        self.fault_tick = None
        self.fault_value = None

    def true_state(self) -> tuple[float, float, float, float]:
        """The plant's exact state ``(p1, v1, p2, v2)`` (for tests; no drive sees it)."""
        return self.plant.state

    # -- the loop -------------------------------------------------------------

    def retune(self, **gains) -> None:
        """Run on with other cascade settings (fields of :class:`DriveTuning`), as a drive takes a new
        parameter: the next tick uses them, the loop's state (integrator, velocity estimate) carries on.

        Raises
        ------
        ConfigError
            A value the loop cannot run (the old tuning stays).
        """
        if "delay_ticks" in gains and gains["delay_ticks"] != self.tuning.delay_ticks:
            raise ConfigError("delay_ticks", "is the firmware's: it does not change while the drive runs")
        self.tuning = replace(self.tuning, **gains)

    def run(self, excitation) -> np.ndarray:
        """Run one tick per excitation sample.

        Parameters
        ----------
        excitation : array_like, shape (n,)
            Per-tick excitation in the unit of the current mode.

        Returns
        -------
        ndarray, shape (n, len(CHANNELS))
            One row per tick: simulated time at the tick's start, the excitation,
            the torque command before the filter slots (controller output plus
            injection), the measured torque actually applied over the tick, the
            encoder position, the velocity estimate and the laser's load position
            (NaN out of range). Simulated time continues across calls.
        """
        x = _excitation_samples(excitation)
        if x.size == 0:
            return np.empty((0, len(self.CHANNELS)))

        # Everything the tick loop reads is bound to a local once per call: the loop runs per simulated tick.
        T = self.period_s
        inv_T = 1.0 / T
        alpha = -math.expm1(-2.0 * math.pi * self.tuning.velocity_filter_hz * T)
        law_tick = _control_law(self)
        beta = self._current_loop_gain()
        pending = self._pending  # commands on their way to the current loop, oldest first
        disturb, load_force = self._disturbance_hooks()
        push_load = self.plant.push_load

        plant = self.plant
        plant_step = plant.step
        encoder = self.sensors.encoder
        measure_torque = self.sensors.torque
        laser = self.sensors.laser

        enabled = self.enabled
        if not enabled:
            self._drop_pending_commands()
        tick = self.tick
        last = self._last_position
        vf = self._velocity
        integ = self._integral
        motor = self._motor_torque

        tn = self.tuning
        kvff, kaff = tn.velocity_feedforward, tn.accel_feedforward_nm_per_mps2
        kvisc, kfric = tn.viscous_feedforward_nm_per_mps, tn.friction_feedforward_nm
        feedforward = self._feedforward_active()
        of_position = self.mode == "position"  # the set-point's velocity by difference, else the set-point itself
        sp_ticks = max(1, int(self.setpoint_ticks))
        inv_Tsp = inv_T / sp_ticks
        sp, sp_v, sp_a, sp_n = self._setpoint_at_start(feedforward, float(x[0]))
        ff_v, ff_a = _feedforward(sp_v, sp_a, kvff, kaff, kvisc, kfric) if feedforward else (0.0, 0.0)

        rows: list[tuple[float, float, float, float, float, float, float]] = []
        append = rows.append
        for e in x.tolist():
            if feedforward:
                if sp_n == 0:  # a new set-point: its velocity and acceleration by backward differences
                    v_new = (e - sp) * inv_Tsp if of_position else e
                    sp_a = (v_new - sp_v) * inv_Tsp
                    sp, sp_v = e, v_new
                    ff_v, ff_a = _feedforward(sp_v, sp_a, kvff, kaff, kvisc, kfric)
                sp_n = (sp_n + 1) % sp_ticks
            p1 = plant.p1
            pm = encoder(p1)
            vf += alpha * ((pm - last) * inv_T - vf)
            last = pm
            lm = laser(p1, plant.p2)
            if enabled:
                cmd, applied, integ, trip = law_tick(e, pm, vf, integ, ff_v, ff_a)
                if trip is None:
                    if pending:
                        pending.append(applied)
                        applied = pending.pop(0)
                    motor = applied if beta == 1.0 else motor + beta * (applied - motor)
                else:
                    enabled, integ, motor = False, 0.0, 0.0
                    self._trip(trip, tick)
            else:
                # A disabled power stage carries no current: the torque is 0 at once.
                cmd = motor = 0.0
            append((tick * T, e, cmd, measure_torque(motor), pm, vf, lm))
            if load_force is not None:
                push_load(load_force(), T)
            plant_step(motor if disturb is None else motor + disturb(p1), T)
            tick += 1

        self.enabled = enabled
        self.tick = tick
        self._last_position = last
        self._velocity = vf
        self._integral = integ
        self._motor_torque = motor
        self._keep_setpoint(feedforward, (sp, sp_v, sp_a, sp_n))
        return np.array(rows, dtype=float)

    # -- what one run binds before its tick loop --------------------------------

    def _current_loop_gain(self) -> float:
        """Fraction of the way from the motor torque to the command that the current loop moves per tick.

        The first-order lag of bandwidth ``current_loop_hz`` sampled at the loop period; 1 for an ideal
        (infinitely fast) current loop.
        """
        cl_hz = self.tuning.current_loop_hz
        return -math.expm1(-2.0 * math.pi * cl_hz * self.period_s) if math.isfinite(cl_hz) else 1.0

    def _disturbance_hooks(self):
        """``(torque(p1) -> N·m, load_force() -> N)`` of the process disturbance; each None when it adds nothing."""
        disturbance = self.disturbance
        if disturbance is None:
            return None, None
        return disturbance.torque, (disturbance.load_force if disturbance.load_noise_n else None)

    def _feedforward_active(self) -> bool:
        """Whether the mode adds feed-forward terms of the set-point: position mode with any feed-forward gain set,
        velocity mode with a torque term set."""
        tn = self.tuning
        torque = bool(
            tn.accel_feedforward_nm_per_mps2 or tn.viscous_feedforward_nm_per_mps or tn.friction_feedforward_nm
        )
        return (self.mode == "position" and (torque or bool(tn.velocity_feedforward))) or (
            self.mode == "velocity" and torque
        )

    def _setpoint_at_start(self, feedforward: bool, first: float) -> tuple[float, float, float, int]:
        """The set-point state a run starts from: ``(set-point, its velocity in unit/s, its acceleration in
        unit/s^2, tick in its period)``.

        With none kept yet (none since :meth:`enable`), the feed-forward's first set-point is ``first`` at rest:
        no difference is taken to what came before enabling.
        """
        if self._setpoint is not None:
            return self._setpoint
        return (first if feedforward else 0.0, 0.0, 0.0, 0)

    def _keep_setpoint(self, feedforward: bool, state: tuple[float, float, float, int]) -> None:
        """Keep the set-point state a run ended with, once the feed-forward has taken a set-point."""
        if feedforward or self._setpoint is not None:
            self._setpoint = state

    def _drop_pending_commands(self) -> None:
        """Zero the commands on their way to the current loop (a power stage without current drops them)."""
        self._pending[:] = [0.0] * len(self._pending)

    def _trip(self, fault: tuple[str, float], tick: int) -> None:
        """Record the trip ``(fault name, offending value)`` at ``tick``; the power stage stops at once."""
        self.fault, self.fault_value = fault
        self.fault_tick = tick
        self._drop_pending_commands()


def _feedforward(
    velocity: float, accel: float, kvff: float, kaff: float, kvisc: float, kfric: float
) -> tuple[float, float]:
    """``(velocity added to the velocity set-point, m/s; torque added to the command, N·m)`` for a set-point
    moving at ``velocity`` (unit/s) and ``accel`` (unit/s^2)."""
    sign = 1.0 if velocity > 0 else (-1.0 if velocity < 0 else 0.0)
    return kvff * velocity, kaff * accel + kvisc * velocity + kfric * sign


def _excitation_samples(excitation) -> np.ndarray:
    """``excitation`` as a one-dimensional float array of finite samples.

    Raises
    ------
    DataError
        It is not one-dimensional, or holds NaN or infinite values.
    """
    x = np.asarray(excitation, dtype=float)
    if x.ndim != 1:
        raise DataError(f"excitation must be one-dimensional, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise DataError("excitation contains NaN or infinite values")
    return x


def _position_law(loop: DriveLoop):
    """The position controller of ``loop`` with its integral or derivative term, ``law(error) -> velocity
    set-point`` (m -> m/s), its state in ``loop._position_state``; None for a P controller (``kp * error``).

    The integral adds its increment before the output (as the velocity PI's does), clamped to the velocity limit;
    the derivative is the error's backward difference over a tick (0 on the first tick after enabling).
    """
    tn = loop.tuning
    if not (tn.ki_pos_per_s2 or tn.kd_pos):
        return None
    kp, ki_T, kd_inv_T = tn.kp_pos_per_s, tn.ki_pos_per_s2 * loop.period_s, tn.kd_pos / loop.period_s
    clamp = loop.velocity_limit_mps
    state = loop._position_state

    def law(error: float) -> float:
        integral = min(clamp, max(-clamp, state[0] + ki_T * error))
        last = state[1]
        state[0], state[1] = integral, error
        return kp * error + integral + (0.0 if last is None else kd_inv_T * (error - last))

    return law


def _control_law(loop: DriveLoop):
    """The enabled tick of ``loop`` as it stands: ``tick(e, pm, vf, integ, ff_v, ff_a) -> (cmd, applied, integ,
    trip)`` (``ff_v``, ``ff_a``: the velocity and torque feed-forward, m/s and N·m).

    ``cmd`` is the torque command before the filter slots, ``applied`` the
    torque the power stage is asked for (N·m), ``integ`` the new integrator
    state and ``trip`` None or ``(fault name, the value that tripped)``. Gains,
    limits and mode are bound once per :meth:`DriveLoop.run` call: the tick
    loop reads them as closure constants.
    """
    tn = loop.tuning
    kp, kv, tmax = tn.kp_pos_per_s, tn.kv_nm_per_mps, tn.torque_max_nm
    position = _position_law(loop)
    ki_T = kv * loop.period_s / tn.ti_s  # integrator gain per tick, N·m per (m/s)
    tlim, vlim = loop.torque_limit_nm, loop.velocity_limit_mps
    pmin, pmax = loop.position_min_m, loop.position_max_m
    mode = MODES.index(loop.mode)
    hold, offset = loop.hold_position_m, loop.torque_offset_nm
    filt = loop.filters.step

    def tick(e: float, pm: float, vf: float, integ: float, ff_v: float = 0.0, ff_a: float = 0.0):
        if vf > vlim or vf < -vlim:
            return 0.0, 0.0, integ, ("velocity_limit", vf)
        if pm < pmin or pm > pmax:
            return 0.0, 0.0, integ, ("position_limit", pm)
        if mode == 0:
            cmd = e + offset
        else:
            if mode == 2:
                verr = e - vf
            elif position is None:
                verr = kp * (hold - pm if mode == 1 else hold + e - pm) + ff_v - vf
            else:
                verr = position(hold - pm if mode == 1 else hold + e - pm) + ff_v - vf
            integ += ki_T * verr
            # Clamp so the integrator cannot wind up beyond the power stage.
            if integ > tmax:
                integ = tmax
            elif integ < -tmax:
                integ = -tmax
            cmd = kv * verr + integ + offset + ff_a
            if mode == 1:
                cmd += e
        tf = filt(cmd)
        if tf > tlim or tf < -tlim:
            return cmd, 0.0, integ, ("torque_limit", tf)
        return cmd, (tmax if tf > tmax else (-tmax if tf < -tmax else tf)), integ, None

    return tick
