"""Linearised multiphase power flow around the zero-load profile, eqs. (39)-(40).

Network equations (per unit, Section V of the asynchronous paper): with the slack voltage
``v0`` and the admittance blocks ``Y = [[Y00, Y0L], [YL0, YLL]]``, the nodal current
injections are ``i = YL0 v0 + YLL v``. A delta load/source injecting ``s_ab`` between
phases a and b draws the branch current ``i_ab = conj(s_ab / (v_a - v_b))``, so with the
block-diagonal ``H = I_B kron [[1, -1, 0], [0, 1, -1], [-1, 0, 1]]``

.. math::  v = w + Y_{LL}^{-1} H^\\top \\overline{(s_\\Delta \\oslash H v)}, \\qquad
           w = -Y_{LL}^{-1} Y_{L0} v_0

where ``w`` is the zero-load voltage profile. Replacing ``v`` by ``w`` on the right (the
fixed-point linearisation of Bernstein and Dall'Anese, ref. [26] of the paper) gives the
linear model of eq. (39):

.. math::  \\tilde v = v - w \\approx M [p; q], \\quad
           M = Y_{LL}^{-1} H^\\top \\mathrm{diag}(\\overline{H w})^{-1} [I, -jI], \\qquad
           |v| - |w| \\approx K [p; q], \\quad
           K = \\mathrm{diag}(|w|)^{-1} \\Re(\\mathrm{diag}(\\bar w) M).

Eq. (39) writes the magnitude rows as ``|v~|``; what is linear in the injections (and what a
meter's magnitude reading minus the known ``|w|`` gives) is ``|v| - |w|``, used here.
Eq. (40) stacks ``Phi = [Re M; Im M; K; I]`` (``15B x 6B``).

:func:`solve_power_flow` iterates the exact fixed point (the nonlinear solution) with one
LU factorisation of ``YLL``; it is used to check the linear model without OpenDSS.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lu_factor, lu_solve

from netsense.grid.feeder import Feeder

__all__ = ["LinearPowerFlow", "delta_incidence", "linearize", "solve_power_flow"]

_GAMMA = np.array([[1, -1, 0], [0, 1, -1], [-1, 0, 1]], dtype=float)


def delta_incidence(B: int) -> np.ndarray:
    """``H = I_B kron Gamma``: maps phase-to-ground to ab/bc/ca voltages, ``(3B, 3B)``."""
    return np.kron(np.eye(B), _GAMMA)


def _split(Y: np.ndarray):
    return Y[3:, :3], Y[3:, 3:]


def _check_x(x: np.ndarray, B: int) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.shape[-1] != 6 * B:
        raise ValueError(f"x = [p; q] must end with 6B = {6 * B} entries, got shape {x.shape}")
    return x


@dataclass(frozen=True, eq=False)
class LinearPowerFlow:
    """The linear model of eqs. (39)-(40) for one feeder.

    Attributes
    ----------
    w : (3B,) complex
        Zero-load voltage profile (per unit).
    M : (3B, 6B) complex
        ``v - w ~= M [p; q]``.
    K : (3B, 6B) real
        ``|v| - |w| ~= K [p; q]``.
    """

    w: np.ndarray
    M: np.ndarray
    K: np.ndarray

    @property
    def B(self) -> int:
        """Number of non-source buses."""
        return self.w.shape[0] // 3

    @property
    def Phi(self) -> np.ndarray:
        """``Phi = [Re M; Im M; K; I]``, eq. (40), ``(15B, 6B)``."""
        return np.vstack([self.M.real, self.M.imag, self.K, np.eye(6 * self.B)])

    @property
    def offset(self) -> np.ndarray:
        """Known part of the measured quantities at zero injection: ``[Re w; Im w; |w|; 0;
        0]``, the ``b`` of Remark 1 when meters report actual voltages."""
        z = np.zeros(6 * self.B)
        return np.concatenate([self.w.real, self.w.imag, np.abs(self.w), z])

    def voltages(self, x: np.ndarray) -> np.ndarray:
        """Linear-model complex voltages ``w + M x`` for ``x`` of shape ``(..., 6B)``."""
        return self.w + _check_x(x, self.B) @ self.M.T

    def quantities(self, x: np.ndarray) -> np.ndarray:
        """All 15B measurable quantities ``Phi x + offset`` (Re v, Im v, |v|, p, q)."""
        return _check_x(x, self.B) @ self.Phi.T + self.offset


def linearize(feeder: Feeder) -> LinearPowerFlow:
    """Zero-load profile ``w`` and the matrices ``M``, ``K`` of eq. (39)."""
    Y = feeder.admittance()
    YL0, YLL = _split(Y)
    lu = lu_factor(YLL)
    w = -lu_solve(lu, YL0 @ feeder.v0)
    B = feeder.B
    H = delta_incidence(B)
    G = H.T / np.conj(H @ w)[None, :]                   # H^T diag(conj(H w))^-1
    rhs = np.hstack([G, -1j * G])                       # times [I, -jI]
    M = lu_solve(lu, rhs)
    K = (np.conj(w)[:, None] * M).real / np.abs(w)[:, None]
    return LinearPowerFlow(w=w, M=M, K=K)


def solve_power_flow(feeder: Feeder, x: np.ndarray, tol: float = 1e-12,
                     max_iter: int = 200) -> np.ndarray:
    """Nonlinear power flow with delta constant-power injections ``x = [p; q]``.

    Iterates ``v <- w + YLL^-1 H^T conj(s / (H v))`` from ``v = w`` (Z-bus fixed point).

    Returns
    -------
    (3B,) complex ndarray
        Phase-to-ground voltages in per unit.

    Raises
    ------
    RuntimeError
        If the iteration does not converge within ``max_iter`` steps.
    """
    B = feeder.B
    x = _check_x(x, B)
    s = x[: 3 * B] + 1j * x[3 * B:]
    Y = feeder.admittance()
    YL0, YLL = _split(Y)
    lu = lu_factor(YLL)
    w = -lu_solve(lu, YL0 @ feeder.v0)
    H = delta_incidence(B)
    v = w.copy()
    for _ in range(max_iter):
        v_new = w + lu_solve(lu, H.T @ np.conj(s / (H @ v)))
        if np.max(np.abs(v_new - v)) < tol:
            return v_new
        v = v_new
    raise RuntimeError(f"power flow did not converge in {max_iter} iterations")
