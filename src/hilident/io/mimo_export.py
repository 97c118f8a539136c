"""The modal model of a multi-input identify (``summary.json["mimo"]``) as a real state space, for ``hilident export``.

``hilident identify`` with ``[data] inputs`` and ``outputs`` fits, from all outputs and inputs at once, the modes
``lambda_r`` and their LSFD residue matrices ``R_r`` (n_out x n_in) of

``H(s) = sum_r [R_r / (s - lambda_r) + conj(R_r) / (s - conj(lambda_r))] + L / s^2 + U``

(:func:`hilident.ident.mimo.modal.lsfd`). :func:`modal_state_space` realises the mode sum plus a feedthrough
``D`` as a real continuous-time state space ``C (sI - A)^-1 B + D``, exactly (to rounding): per mode and per
singular direction ``k`` of ``R_r = sum_k s_k u_k v_k^H`` (those above :data:`RANK_RTOL` of the largest), a
2 x 2 block ``[[sigma, omega], [-omega, sigma]]`` (``lambda = sigma + j omega``) with
``B_k = sqrt(s_k) [Re v_k^H; -Im v_k^H]`` and ``C_k = 2 sqrt(s_k) [Re u_k, Im u_k]``. A residue of rank one (one
mode shape times one participation vector, as physics has it) takes one block; a residue estimated from noisy
data is of full rank and takes ``min(n_out, n_in)`` blocks, its smaller singular values
(``residue_singular_values``) telling how far from rank one it is.

``D`` is the upper residual ``U`` (the modes above the band as a constant). The lower residual ``L / s^2`` is not
in the state space: it would add a double integrator per input, unbounded at DC, where the fit usually gives a
small ``L`` that only bends the response at the band's lower edge. It is exported beside the model; where it does
stand for rigid-body motion, append the states ``x1' = x2, x2' = u`` with output ``L x1``.

Examples
--------
>>> a, b, c, d, _ = modal_state_space([complex(-1.0, 10.0)], [[[0.5 - 2.0j]]])
>>> a
array([[ -1.,  10.],
       [-10.,  -1.]])
>>> s = 3.0j
>>> h = (c @ np.linalg.solve(s * np.eye(2) - a, b) + d)[0, 0]
>>> want = (0.5 - 2.0j) / (s - (-1 + 10j)) + (0.5 + 2.0j) / (s - (-1 - 10j))
>>> bool(abs(h - want) < 1e-12 * abs(want))
True
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from hilident.errors import DataError

__all__ = ["RANK_RTOL", "mimo_control_lines", "mimo_model_part", "modal_response", "modal_state_space"]

#: A residue's singular direction whose singular value is below this fraction of the largest is left out of the
#: state space: numerically zero, it changes the response by less than that fraction of the mode's.
RANK_RTOL = 1e-12


def _checked(poles: ArrayLike, residues: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``poles`` (n_modes,) complex with positive imaginary part and ``residues`` (n_modes, n_out, n_in) complex."""
    lam = np.atleast_1d(np.asarray(poles, dtype=np.complex128))
    res = np.asarray(residues, dtype=np.complex128)
    if lam.ndim != 1 or res.ndim != 3 or res.shape[0] != lam.size or not lam.size:
        raise DataError(f"poles (n,) and residues (n, n_out, n_in) with n >= 1 needed, got {lam.shape}, {res.shape}")
    if not (np.all(np.isfinite(lam)) and np.all(np.isfinite(res))):
        raise DataError("poles and residues must be finite")
    if np.any(lam.imag <= 0.0):
        raise DataError("every pole must have a positive imaginary part (its conjugate is implied)")
    return lam, res


def _mode_blocks(pole: complex, residue: np.ndarray, rank_rtol: float) -> tuple[np.ndarray, ...]:
    """``A, B, C`` of one mode: one 2 x 2 block per kept singular direction of its residue; and the singular values.

    A complex state ``z' = lambda z + b u`` with output ``c z + conj(c z)`` gives ``c b / (s - lambda)`` and its
    conjugate; with ``z = x1 - j x2`` it is real: ``x' = [[sigma, omega], [-omega, sigma]] x + [Re b; -Im b] u``,
    ``y = [2 Re c, 2 Im c] x``.
    """
    u, sv, vh = np.linalg.svd(residue)
    keep = int(np.count_nonzero(sv > rank_rtol * sv[0])) if sv[0] > 0.0 else 0
    n_out, n_in = residue.shape
    block = np.array([[pole.real, pole.imag], [-pole.imag, pole.real]])
    a = np.kron(np.eye(keep), block)
    b, c = np.zeros((2 * keep, n_in)), np.zeros((n_out, 2 * keep))
    for k in range(keep):
        root = np.sqrt(sv[k])
        row, col = root * vh[k], root * u[:, k]
        b[2 * k], b[2 * k + 1] = row.real, -row.imag
        c[:, 2 * k], c[:, 2 * k + 1] = 2.0 * col.real, 2.0 * col.imag
    return a, b, c, sv


def modal_state_space(
    poles: ArrayLike,
    residues: ArrayLike,
    feedthrough: ArrayLike | None = None,
    rank_rtol: float = RANK_RTOL,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
    """A real continuous-time state space of ``sum_r R_r / (s - lambda_r) + conj(R_r) / (s - conj(lambda_r)) + D``.

    Parameters
    ----------
    poles : array of complex, shape (n_modes,)
        ``lambda_r``, rad/s, positive imaginary part (the conjugate pole is implied).
    residues : array of complex, shape (n_modes, n_out, n_in)
        ``R_r``, in the response's unit times rad/s.
    feedthrough : array, shape (n_out, n_in), optional
        ``D`` (the upper residual), the response's unit; default zeros.
    rank_rtol : float
        Singular directions of a residue below this fraction of its largest singular value are left out.

    Returns
    -------
    A, B, C, D : ndarray
        ``x' = A x + B u``, ``y = C x + D u``: ``A`` (n, n) block diagonal of ``[[sigma, omega], [-omega, sigma]]``
        in 1/s, ``B`` (n, n_in), ``C`` (n_out, n), ``D`` (n_out, n_in).
    modes : list of dict
        Per mode: ``first_state`` (0-based row of its first block in ``A``), ``n_states`` and
        ``residue_singular_values`` (descending, the residue's unit).
    """
    lam, res = _checked(poles, residues)
    n_out, n_in = res.shape[1:]
    d = np.zeros((n_out, n_in)) if feedthrough is None else np.asarray(feedthrough, dtype=float)
    if d.shape != (n_out, n_in) or not np.all(np.isfinite(d)):
        raise DataError(f"feedthrough must be finite, shape {(n_out, n_in)}, got {d.shape}")
    blocks = [_mode_blocks(complex(p), r, rank_rtol) for p, r in zip(lam, res, strict=True)]
    n = sum(blk[0].shape[0] for blk in blocks)
    a, b, c = np.zeros((n, n)), np.zeros((n, n_in)), np.zeros((n_out, n))
    modes, at = [], 0
    for ak, bk, ck, sv in blocks:
        k = ak.shape[0]
        a[at : at + k, at : at + k], b[at : at + k], c[:, at : at + k] = ak, bk, ck
        modes.append({"first_state": at, "n_states": k, "residue_singular_values": sv.tolist()})
        at += k
    return a + 0.0, b + 0.0, c + 0.0, d + 0.0, modes  # + 0.0: no -0.0 in the files


def modal_response(
    poles: ArrayLike,
    residues: ArrayLike,
    s: ArrayLike,
    lower: ArrayLike | None = None,
    upper: ArrayLike | None = None,
) -> np.ndarray:
    """``sum_r R_r / (s - lambda_r) + conj(R_r) / (s - conj(lambda_r)) [+ L / s^2] [+ U]`` at each ``s``.

    Parameters
    ----------
    poles, residues
        As :func:`modal_state_space`.
    s : array of complex, shape (F,)
        Laplace variable, rad/s (``2j pi f`` for ``f`` in Hz).
    lower, upper : array, shape (n_out, n_in), optional
        Lower and upper residuals.

    Returns
    -------
    ndarray of complex, shape (F, n_out, n_in)
    """
    lam, res = _checked(poles, residues)
    x = np.atleast_1d(np.asarray(s, dtype=np.complex128))[:, None, None, None]
    h = np.sum(res / (x - lam[:, None, None]) + res.conj() / (x - lam.conj()[:, None, None]), axis=1)
    if lower is not None:
        h = h + np.asarray(lower, dtype=float) / x[:, 0] ** 2
    if upper is not None:
        h = h + np.asarray(upper, dtype=float)
    return h


def _matrix(rows: Any, shape: tuple[int, int], what: str) -> np.ndarray:
    try:
        m = np.asarray(rows, dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"summary.json mimo: {what} is not a matrix of numbers") from None
    if m.shape != shape:
        raise DataError(f"summary.json mimo: {what} has shape {m.shape}, not {shape} (outputs x inputs)")
    return m


def _summary_modes(mimo: dict) -> tuple[np.ndarray, np.ndarray]:
    """The poles (rad/s) and residues of ``summary.json["mimo"]["modes"]``, checked."""
    shape = (len(mimo["outputs"]), len(mimo["inputs"]))
    poles, residues = [], []
    for n, mode in enumerate(mimo["modes"]):
        if not {"pole_rad_per_s", "residue_real", "residue_imag"} <= set(mode):
            raise DataError(
                f"summary.json mimo.modes[{n}] has no pole_rad_per_s / residue_real / residue_imag "
                "(written by an older hilident: run identify again)"
            )
        re, im = (float(v) for v in mode["pole_rad_per_s"])
        poles.append(complex(re, im))
        residues.append(
            _matrix(mode["residue_real"], shape, f"modes[{n}].residue_real")
            + 1j * _matrix(mode["residue_imag"], shape, f"modes[{n}].residue_imag")
        )
    return np.array(poles), np.array(residues)


def _matrices(a, b, c, d) -> dict[str, list]:
    return {
        name: np.atleast_2d(np.asarray(m, dtype=float)).tolist() for name, m in zip("ABCD", (a, b, c, d), strict=True)
    }


def _state_names(modes: list[dict], n: int) -> list[str]:
    """``mode1_re``, ``mode1_im`` (``mode1_2_re``, ... for a residue's further directions), in state order."""
    names = [""] * n
    for r, mode in enumerate(modes, start=1):
        for k in range(mode["n_states"] // 2):
            stem = f"mode{r}" if k == 0 else f"mode{r}_{k + 1}"
            at = mode["first_state"] + 2 * k
            names[at], names[at + 1] = f"{stem}_re", f"{stem}_im"
    return names


def _units() -> dict[str, str]:
    return {
        "response": "output j per input i: (output_units[j])/(input_units[i])",
        "s": "rad/s",
        "ss": "x' = A x + B u, y = C x + D u; u the inputs (input_units), y the outputs (output_units), t in s; "
        "A in 1/s; each mode a 2x2 block [[sigma, omega], [-omega, sigma]] per singular direction of its residue",
        "poles_rad_s": "rows [re, im] of each mode's pole, rad/s (its conjugate is a pole too)",
        "residue": "residue_real, residue_imag: n_out x n_in, the response's unit times rad/s",
        "lower_residual": "n_out x n_in, the response's unit times (rad/s)^2: the term L / s^2, not in A, B, C, D",
        "D": "the upper residual, n_out x n_in, the response's unit",
        "discrete": "x[k+1] = A x[k] + B u[k], y[k] = C x[k] + D u[k]; zero-order hold, dt_s s",
        "frequency_hz": "Hz",
        "band_hz": "Hz",
        "damping_ratio": "dimensionless",
    }


def _discrete(a, b, c, d, rate: float | None, rate_source: str) -> dict | None:
    from scipy import signal

    if rate is None:
        return None
    dt = 1.0 / rate
    ad, bd, cd, dd, _ = signal.cont2discrete((a, b, c, d), dt, method="zoh")
    return {
        "sample_rate_hz": rate,
        "dt_s": dt,
        "method": "zoh",
        "rate_source": rate_source,
        "ss": _matrices(ad, bd, cd, dd),
    }


def _mode_entries(mimo: dict, blocks: list[dict]) -> list[dict]:
    return [
        {
            "frequency_hz": m.get("frequency_hz"),
            "damping_ratio": m.get("damping_ratio"),
            "pole_rad_s": m["pole_rad_per_s"],
            "residue_real": m["residue_real"],
            "residue_imag": m["residue_imag"],
            **blk,
        }
        for m, blk in zip(mimo["modes"], blocks, strict=True)
    ]


def mimo_model_part(
    mimo: dict,
    unit_of: Callable[[str, str | None], str],
    rate: float | None,
    rate_source: str,
) -> dict | None:
    """The ``mimo_model`` part of the export: the modal state space of ``summary.json["mimo"]`` with every channel.

    Parameters
    ----------
    mimo : dict
        ``summary.json["mimo"]``.
    unit_of : callable
        ``unit_of(column, stated_unit)``: a channel's unit (the stated one, else from its name), ``"unknown"``
        when neither says.
    rate : float or None
        Rate to discretise at, Hz; None: no discrete form (``discrete_reason`` says why).
    rate_source : str
        Where the rate came from.

    Returns
    -------
    dict or None
        None when the summary has no modes.
    """
    if not mimo.get("modes"):
        return None
    poles, residues = _summary_modes(mimo)
    upper = mimo.get("upper_residual")
    shape = residues.shape[1:]
    d = None if upper is None else _matrix(upper, shape, "upper_residual")
    a, b, c, d, blocks = modal_state_space(poles, residues, d)
    inputs = [str(i.get("column")) for i in mimo["inputs"]]
    outputs = [str(o.get("column")) for o in mimo["outputs"]]
    input_units = [unit_of(col, i.get("unit")) for col, i in zip(inputs, mimo["inputs"], strict=True)]
    output_units = [unit_of(col, o.get("unit")) for col, o in zip(outputs, mimo["outputs"], strict=True)]
    part: dict[str, Any] = {
        "inputs": inputs,
        "input_units": input_units,
        "outputs": outputs,
        "output_units": output_units,
        "band_hz": mimo.get("band_hz"),
        "n_states": int(a.shape[0]),
        "state_names": _state_names(blocks, a.shape[0]),
        "modes": _mode_entries(mimo, blocks),
        "lower_residual": mimo.get("lower_residual"),
        "lower_residual_in_model": False,
        "continuous": {"ss": _matrices(a, b, c, d), "poles_rad_s": [[p.real, p.imag] for p in poles.tolist()]},
        "units": _units(),
    }
    part["discrete"] = _discrete(a, b, c, d, rate, rate_source)
    if part["discrete"] is None:
        part["discrete_reason"] = rate_source
    return part


def _names(values: Sequence[str]) -> str:
    return "[" + ", ".join(repr(str(v)) for v in values) + "]"


def mimo_control_lines(part: dict) -> list[str]:
    """Lines of the python-control script that build ``mimo_ss`` (and ``mimo_ss_discrete`` with a rate) from
    ``part`` (:func:`mimo_model_part`), with named inputs, outputs and states (floats by ``repr``: exact)."""
    names = f"inputs={_names(part['inputs'])}, outputs={_names(part['outputs'])}, states={_names(part['state_names'])}"
    units = ", ".join(f"{n} [{u}]" for n, u in zip(part["inputs"], part["input_units"], strict=True))
    out_units = ", ".join(f"{n} [{u}]" for n, u in zip(part["outputs"], part["output_units"], strict=True))
    cont, disc = part["continuous"]["ss"], part["discrete"]
    lines = [
        "",
        f"# the modal model of every channel: inputs {units}; outputs {out_units}; t in s",
        "mimo_ss = control.ss({A!r}, {B!r}, {C!r}, {D!r}, ".format(**cont) + names + ', name="mimo_model")',
    ]
    if disc is not None:
        lines += [
            f"mimo_dt = {disc['dt_s']!r}  # s: {disc['sample_rate_hz']!r} Hz, {disc['rate_source']}",
            "mimo_ss_discrete = control.ss({A!r}, {B!r}, {C!r}, {D!r}, mimo_dt, ".format(**disc["ss"])
            + names
            + ', name="mimo_model_discrete")',
        ]
    return lines
