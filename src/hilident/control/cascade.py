"""A drive's cascade as discrete transfer functions: what the controller does between the encoder and the motor.

A servo drive closes its loops at its own rate. Between the position the
encoder reads at tick ``k`` and the torque the motor gives over that tick, the
drive runs a fixed chain, each part a transfer function in ``z`` at the loop
rate:

* the velocity estimate: the backward difference of the position, smoothed by a
  first-order low-pass, ``V(z) = a (1 - z^-1) / T / (1 - (1 - a) z^-1)`` with
  ``a = 1 - exp(-2 pi f_v T)``;
* the velocity controller, a PI: ``C(z) = K_v + K_v T / T_i / (1 - z^-1)``
  (the integrator adds its increment before the output, as a drive's code does);
* the position controller, from the position error to the velocity set-point:
  ``P(z) = K_p + K_ip T / (1 - z^-1) + K_dp (1 - z^-1) / T`` (a P controller
  unless the drive has the integral or derivative term);
* the filter slots in series, ``N(z)``;
* the computation and transport delay, ``z^-d``;
* the current loop, a first-order lag sampled at the loop rate,
  ``G(z) = b / (1 - (1 - b) z^-1)`` with ``b = 1 - exp(-2 pi f_c T)``.

The plant closes the loop: ``H``, the response from the motor torque of a tick to
the position the encoder reads in the same tick (a recording's torque and
position columns, row by row). The chain from the encoder to the motor torque is
``K_vel = C N z^-d G V`` with the position loop open (velocity mode) and
``K_pos = C N z^-d G (P + V)`` with both loops closed (position mode). A
cascade is tuned loop by loop: the velocity loop broken at the torque,
``L_v = K_vel H``; the position loop broken at the velocity set-point with the
velocity loop closed, ``L_p = P C N z^-d G H / (1 + L_v)``.

Feed-forward terms act on the set-point, outside the loops: they change how
the axis follows its set-point, not the margins. With the set-point held over
``D`` ticks and its velocity and acceleration taken by backward differences over
that period, ``s_D = (1 - z^-D) / (D T)``: in velocity mode the torque command
gains ``F_v r`` with ``F_v = K_visc + K_acc s_D`` (``r`` the velocity set-point);
in position mode the velocity set-point gains ``K_vff s_D r`` and the torque
``(K_visc s_D + K_acc s_D^2) r`` (``r`` the position set-point). The Coulomb
term ``F_c sign(v_r)`` is not linear: it is taken with the friction it cancels
(:mod:`hilident.pipeline.closed_loop`).

The same model describes the emulated drive (:mod:`hilident.emulator.drive`)
exactly; a real drive's documentation says which parts it has.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from hilident.errors import ConfigError
from hilident.filters.biquad import Biquad
from hilident.protocol.loop_parameters import FEEDFORWARD, POSITION_TERMS

__all__ = ["Cascade"]


@dataclass(frozen=True)
class Cascade:
    """A drive's cascade controller, as its parameters describe it.

    Parameters
    ----------
    loop_rate_hz : float
        Rate of the drive's control loop, Hz.
    kv_nm_per_mps : float
        Velocity controller's proportional gain, N·m per (m/s).
    ti_s : float
        Velocity controller's integral time, s (``inf``: a P controller).
    kp_pos_per_s : float
        Position controller's gain, (m/s) per m.
    velocity_filter_hz : float
        Cut-off of the first-order low-pass on the velocity estimate, Hz
        (``inf``: the raw backward difference).
    current_loop_hz : float
        Bandwidth of the current loop's first-order lag, Hz (``inf``: ideal).
    delay_ticks : int
        Computation and transport delay between the controller and the current
        loop, loop ticks.
    filters : tuple of Biquad
        The enabled filter slots, in series on the torque command, at the loop rate.
    velocity_feedforward : float
        Position mode: share of the set-point's velocity added to the velocity set-point, 1.
    accel_feedforward_nm_per_mps2 : float
        Torque added per m/s^2 of the set-point's acceleration, N·m/(m/s^2).
    viscous_feedforward_nm_per_mps : float
        Torque added per m/s of the set-point's velocity, N·m/(m/s).
    friction_feedforward_nm : float
        Torque added with the sign of the set-point's velocity, N·m (outside the linear model).
    ki_pos_per_s2 : float
        Position controller's integral gain, (m/s) per (m·s) (0: none).
    kd_pos : float
        Position controller's derivative gain, (m/s) per (m/s) (0: none).
    """

    loop_rate_hz: float
    kv_nm_per_mps: float
    ti_s: float = math.inf
    kp_pos_per_s: float = 0.0
    velocity_filter_hz: float = math.inf
    current_loop_hz: float = math.inf
    delay_ticks: int = 0
    filters: tuple[Biquad, ...] = field(default_factory=tuple)
    velocity_feedforward: float = 0.0
    accel_feedforward_nm_per_mps2: float = 0.0
    viscous_feedforward_nm_per_mps: float = 0.0
    friction_feedforward_nm: float = 0.0
    ki_pos_per_s2: float = 0.0
    kd_pos: float = 0.0

    def __post_init__(self):
        checks = {
            "loop_rate_hz": self.loop_rate_hz > 0 and math.isfinite(self.loop_rate_hz),
            "kv_nm_per_mps": self.kv_nm_per_mps >= 0 and math.isfinite(self.kv_nm_per_mps),
            "ti_s": self.ti_s > 0,
            "kp_pos_per_s": self.kp_pos_per_s >= 0 and math.isfinite(self.kp_pos_per_s),
            "velocity_filter_hz": self.velocity_filter_hz > 0,
            "current_loop_hz": self.current_loop_hz > 0,
            "delay_ticks": isinstance(self.delay_ticks, int) and self.delay_ticks >= 0,
            **{
                name: getattr(self, name) >= 0 and math.isfinite(getattr(self, name))
                for name in (*POSITION_TERMS, *FEEDFORWARD)
            },
        }
        for name, ok in checks.items():
            if not ok:
                raise ConfigError(name, f"is out of range: {getattr(self, name)!r}")
        object.__setattr__(self, "filters", tuple(self.filters))

    @classmethod
    def from_parameters(cls, values: Mapping[str, float], loop_rate_hz: float, filters=()) -> Cascade:
        """The cascade whose parameters (the names of :data:`hilident.protocol.loop_parameters.PARAMETERS`)
        read ``values``, in SI units; ``delay_ticks`` is rounded to whole ticks."""
        return cls(
            loop_rate_hz=float(loop_rate_hz),
            kv_nm_per_mps=float(values["kv_nm_per_mps"]),
            ti_s=float(values["ti_s"]),
            kp_pos_per_s=float(values["kp_pos_per_s"]),
            velocity_filter_hz=float(values["velocity_filter_hz"]),
            current_loop_hz=float(values["current_loop_hz"]),
            delay_ticks=int(round(float(values["delay_ticks"]))),
            filters=tuple(filters),
            **{name: float(values[name]) for name in (*POSITION_TERMS, *FEEDFORWARD) if name in values},
        )

    @property
    def period_s(self) -> float:
        """The loop period, s."""
        return 1.0 / self.loop_rate_hz

    def with_gains(self, **gains) -> Cascade:
        """The same cascade with other gains (``kv_nm_per_mps``, ``ti_s``, ``kp_pos_per_s``) or filters."""
        values = {f: getattr(self, f) for f in self.__dataclass_fields__}
        values.update(gains)
        return Cascade(**values)

    def _z_inverse(self, frequency_hz) -> np.ndarray:
        return np.exp(-2j * np.pi * np.asarray(frequency_hz, dtype=float) * self.period_s)

    def velocity_estimate(self, frequency_hz) -> np.ndarray:
        """``V``: encoder position to velocity estimate, (m/s) per m."""
        zi = self._z_inverse(frequency_hz)
        a = _lag_step(self.velocity_filter_hz, self.period_s)
        return a * (1.0 - zi) / self.period_s / (1.0 - (1.0 - a) * zi)

    def velocity_controller(self, frequency_hz) -> np.ndarray:
        """``C``: velocity error to torque command, N·m per (m/s)."""
        zi = self._z_inverse(frequency_hz)
        integral = 0.0 if math.isinf(self.ti_s) else self.kv_nm_per_mps * self.period_s / self.ti_s
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.kv_nm_per_mps + integral / (1.0 - zi)

    def position_controller(self, frequency_hz) -> np.ndarray:
        """``P``: position error to velocity set-point, (m/s) per m."""
        zi = self._z_inverse(frequency_hz)
        p = self.kp_pos_per_s + self.kd_pos * (1.0 - zi) / self.period_s
        if self.ki_pos_per_s2:
            with np.errstate(divide="ignore", invalid="ignore"):
                p = p + self.ki_pos_per_s2 * self.period_s / (1.0 - zi)
        return p

    def torque_path(self, frequency_hz) -> np.ndarray:
        """``N z^-d G``: torque command to motor torque (filters, delay, current loop), 1."""
        zi = self._z_inverse(frequency_hz)
        h = np.ones_like(zi)
        for section in self.filters:
            h = h * section.response(frequency_hz, self.loop_rate_hz)
        b = _lag_step(self.current_loop_hz, self.period_s)
        return h * zi**self.delay_ticks * b / (1.0 - (1.0 - b) * zi)

    def controller(self, frequency_hz, loop: str = "velocity") -> np.ndarray:
        """``K``: encoder position to motor torque through the whole chain, N·m per m.

        Parameters
        ----------
        frequency_hz : array_like
            Frequencies, Hz (below half the loop rate).
        loop : {"velocity", "position"}
            ``"velocity"``: the position loop open (velocity mode);
            ``"position"``: both loops closed (position mode).
        """
        inner = self.velocity_estimate(frequency_hz)
        if loop == "position":
            inner = inner + self.position_controller(frequency_hz)
        elif loop != "velocity":
            raise ValueError(f"loop must be 'velocity' or 'position', got {loop!r}")
        return self.velocity_controller(frequency_hz) * self.torque_path(frequency_hz) * inner

    def open_loop(self, frequency_hz, plant_position, loop: str = "velocity") -> np.ndarray:
        """The loop broken where a tuner breaks it, 1.

        Parameters
        ----------
        frequency_hz : array_like
            Frequencies, Hz.
        plant_position : array_like of complex
            ``H``: motor torque to encoder position at ``frequency_hz``, m per N·m,
            row-aligned (the position read in the tick the torque is given).
        loop : {"velocity", "position", "torque"}
            ``"velocity"``: the velocity loop broken at the motor torque, the
            position loop open, ``C N z^-d G V H``; ``"position"``: the
            position loop broken at the velocity set-point, the velocity loop
            closed, ``K_p C N z^-d G H / (1 + L_velocity)`` (how a cascade's
            outer loop is tuned); ``"torque"``: both loops closed, broken at
            the motor torque, ``K_pos H`` (what an injection at the
            controller's output measures).
        """
        f = np.asarray(frequency_hz, dtype=float)
        h = np.asarray(plant_position)
        if loop == "torque":
            return self.controller(f, "position") * h
        velocity_loop = self.controller(f, "velocity") * h
        if loop == "velocity":
            return velocity_loop
        if loop != "position":
            raise ValueError(f"loop must be 'velocity', 'position' or 'torque', got {loop!r}")
        outer = self.position_controller(f) * self.velocity_controller(f) * self.torque_path(f)
        return outer * h / (1.0 + velocity_loop)

    def setpoint_difference(self, frequency_hz, setpoint_ticks: int = 1) -> np.ndarray:
        """``s_D = (1 - z^-D) / (D T)``: a set-point held over ``D`` ticks to its backward difference, 1/s."""
        d = max(1, int(setpoint_ticks))
        return (1.0 - self._z_inverse(frequency_hz) ** d) / (d * self.period_s)

    def feedforward_torque(self, frequency_hz, loop: str = "velocity", setpoint_ticks: int = 1) -> np.ndarray:
        """The linear feed-forward torque per unit set-point: ``K_visc + K_acc s_D`` (N·m per (m/s)) for the
        velocity set-point, ``K_visc s_D + K_acc s_D^2`` (N·m per m) for the position set-point."""
        s_d = self.setpoint_difference(frequency_hz, setpoint_ticks)
        torque = self.viscous_feedforward_nm_per_mps + self.accel_feedforward_nm_per_mps2 * s_d
        return torque * s_d if loop == "position" else torque

    def setpoint_response(
        self, frequency_hz, plant_position, loop: str = "velocity", setpoint_ticks: int = 1, what: str = "output"
    ) -> np.ndarray:
        """The set-point's response with the feed-forward terms: to the velocity estimate ((m/s) per (m/s),
        ``"velocity"``) or the encoder position (m per m, ``"position"``); ``what = "torque"``: to the motor
        torque (N·m per unit set-point). Without feed-forward the velocity and position responses are
        :meth:`closed_loop`'s.

        Parameters
        ----------
        setpoint_ticks : int
            ``D``: loop ticks each set-point is held (the feed-forward's differences are over that period).
        """
        f = np.asarray(frequency_hz, dtype=float)
        h = np.asarray(plant_position)
        c, path = self.velocity_controller(f), self.torque_path(f)
        if loop == "position":
            s_d = self.setpoint_difference(f, setpoint_ticks)
            drive = c * (self.position_controller(f) + self.velocity_feedforward * s_d)
        elif loop == "velocity":
            drive = c
        else:
            raise ValueError(f"loop must be 'velocity' or 'position', got {loop!r}")
        torque = (
            path
            * (drive + self.feedforward_torque(f, loop, setpoint_ticks))
            / (1.0 + self.open_loop(f, h, "torque" if loop == "position" else "velocity"))
        )
        if what == "torque":
            return torque
        if what != "output":
            raise ValueError(f"what must be 'output' or 'torque', got {what!r}")
        return torque * h * (self.velocity_estimate(f) if loop == "velocity" else 1.0)

    def closed_loop(self, frequency_hz, plant_position, loop: str = "velocity") -> np.ndarray:
        """The set-point's response: velocity set-point to velocity estimate ((m/s) per (m/s)) for
        ``"velocity"``, position set-point to encoder position (m per m) for ``"position"``."""
        f = np.asarray(frequency_hz, dtype=float)
        h = np.asarray(plant_position)
        if loop == "position":
            outer = self.open_loop(f, h, "position")
            return outer / (1.0 + outer)
        velocity_loop = self.open_loop(f, h, "velocity")
        return velocity_loop / (1.0 + velocity_loop)


def _lag_step(bandwidth_hz: float, period_s: float) -> float:
    """Fraction of the way to its input a first-order lag of ``bandwidth_hz`` moves per tick (1: none)."""
    return -math.expm1(-2.0 * math.pi * bandwidth_hz * period_s) if math.isfinite(bandwidth_hz) else 1.0
