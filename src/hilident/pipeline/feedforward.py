"""Feed-forward terms proposed from the identified plant and friction, for the terms the drive has.

A drive's feed-forward (``[loop]``'s :data:`~hilident.protocol.loop_parameters.FEEDFORWARD`
terms) adds to the command what the set-point will need, so the loops only
correct what the model misses:

* ``accel_feedforward_nm_per_mps2``: the inertia the motor torque drives,
  ``J`` (N·m per m/s²), from the plant the loop sees: below its modes the
  whole axis moves together and ``H = x / tau`` tends to ``1 / (J s^2)``;
* ``viscous_feedforward_nm_per_mps`` and ``friction_feedforward_nm``: the
  identified friction's viscous coefficient ``Fv`` and Coulomb level ``Fc``
  (the friction test's fit, the level it holds at speed: the Stribeck rise near
  rest is left to the loop);
* ``velocity_feedforward``: 1, the whole set-point velocity (position mode).

A term is proposed only with its basis: no friction test, no friction terms; a
plant the loop sees only on its measured lines, or whose mechanics are not a
free rigid body (two integrators), no inertia. Each term left out says why.
"""

from __future__ import annotations

import math

from hilident.pipeline.loop_plant import SeenPlant

__all__ = ["inertia_nm_per_mps2", "propose_feedforward"]


def inertia_nm_per_mps2(seen: SeenPlant) -> float | None:
    """``J``: motor torque per m/s² of the axis moving as one, from the low-frequency asymptote of the plant the
    loop sees, ``gain / s^2`` (every factor of the mechanics is 1 at ``s = 0``); None when its mechanics are
    unknown or are not a free rigid body (two integrators)."""
    m = seen.mechanics
    if m is None or getattr(m, "integrators", None) != 2:
        return None
    low = abs(seen.gain * float(m.gain))  # type: ignore[attr-defined]
    return 1.0 / low if low > 0 and math.isfinite(1.0 / low) else None


def propose_feedforward(parameters: dict, seen: SeenPlant | None, friction_fit, host_skips: int = 0) -> dict:
    """The feed-forward terms for the drive whose loop parameters are ``parameters`` (those it has).

    Parameters
    ----------
    parameters : dict
        The drive's loop parameters as read (:meth:`read_loop`): a feed-forward term among them is one the
        drive has.
    seen : SeenPlant or None
        The plant the loop sees.
    friction_fit : FrictionFit or None
        The friction test's fit (``params.Fc``, ``params.Fv``), None without a friction test.
    host_skips : int
        Cycles the host's own clock skipped in the session's runs (0: the drive or the interface kept the
        clock). A skipped cycle is a set-point jump, which the acceleration term turns into a torque impulse of
        the jump over one set-point period: with skips it is left out.

    Returns
    -------
    dict
        ``{"terms": {name: value}, "left_out": {name: why}}``, SI units.
    """
    inertia = inertia_nm_per_mps2(seen) if seen is not None and not host_skips else None
    basis: dict[str, tuple[float | None, str]] = {
        "velocity_feedforward": (1.0, ""),
        "accel_feedforward_nm_per_mps2": (
            inertia,
            f"the set-points came on the host's clock, which skipped {host_skips} cycles: each skip is a set-point "
            "jump the acceleration term would turn into a torque impulse (give the drive or the interface the "
            "clock: [canopen.sync] producer, or an interface with cyclic transmit)"
            if host_skips
            else "the plant's mechanics are not known as a free rigid body below its modes",
        ),
    }
    p = None if friction_fit is None else friction_fit.params
    no_test = "no friction test ([friction_test]) identified the friction"
    basis["viscous_feedforward_nm_per_mps"] = (
        None if p is None or p.delta_v != 1.0 else max(0.0, float(p.Fv)),
        no_test if p is None else "the viscous friction is not linear (delta_v != 1)",
    )
    basis["friction_feedforward_nm"] = (None if p is None else max(0.0, float(p.Fc)), no_test)
    terms, left_out = {}, {}
    for name, (value, why) in basis.items():
        if name not in parameters:
            continue
        if value is None:
            left_out[name] = why
        else:
            terms[name] = value
    return {"terms": terms, "left_out": left_out}
