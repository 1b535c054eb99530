"""IMU error model and in-flight calibration (003 §6.1, table 3, generalised).

Measurement model for each triad (accelerometer ``f``, gyro ``w``), to first order::

    f_meas = f_true + b_f + diag(f_true) s_f + [f_true x] m_f + noise
    w_meas = w_true + b_w + diag(w_true) s_w + [w_true x] m_w + S(n_w) w_true + noise

``s`` are scale-factor errors, ``m`` a small-angle misalignment of the sensor triad (the sensor
axes rotated by ``-m`` from b, so ``(I - [m x]) f = f + [f x] m``). ``n_w = (n_yz, n_xz, n_xy)`` is
the gyro triad's non-orthogonality: the symmetric off-diagonal matrix

    S(n) = [[0, n_xy, n_xz], [n_xy, 0, n_yz], [n_xz, n_yz, 0]].

A triad whose six off-diagonal terms N_ij are independent (``M = I + diag(s) + N``, as
:mod:`scenarios.sim.imu` draws them) holds both: ``N = -[m x] + S(n)`` with
``m = ((N_yz - N_zy) / 2, (N_zx - N_xz) / 2, (N_xy - N_yx) / 2)`` and ``n_ij = (N_ij + N_ji) / 2``
(:func:`split_misalignment`); six independent terms of 1-sigma ``sigma`` give each of ``m`` and
``n`` a 1-sigma of ``sigma / sqrt(2)``, and the rotation ``m`` alone leaves the other half of their
variance out. The filter's error states are the residuals after calibration with the current
estimates, so the corrected measurement's error is ``delta_f = b_f + diag(f) s_f + [f x] m_f``
(the gyro's adds ``S(n_w) w = N(w) n_w``): its Jacobian with respect to the bias, scale,
misalignment and non-orthogonality groups is ``I``, ``diag(f)``, ``[f x]``, ``N(w)``
(:func:`nonorthogonality_jacobian`, :func:`nav.error_state.error_dynamics`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numba as nb
import numpy as np

from nav._kernels import inverse3_into, skew
from nav.checks import as_vectors


@dataclass
class ImuCalibration:
    """Current in-flight calibration (estimates of the error terms, SI units)."""
    b_f: np.ndarray = field(default_factory=lambda: np.zeros(3))
    b_w: np.ndarray = field(default_factory=lambda: np.zeros(3))
    s_f: np.ndarray = field(default_factory=lambda: np.zeros(3))
    m_f: np.ndarray = field(default_factory=lambda: np.zeros(3))
    s_w: np.ndarray = field(default_factory=lambda: np.zeros(3))
    m_w: np.ndarray = field(default_factory=lambda: np.zeros(3))
    n_w: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def copy(self) -> "ImuCalibration":
        return ImuCalibration(*(getattr(self, k).copy() for k in ("b_f", "b_w", "s_f", "m_f", "s_w", "m_w", "n_w")))

    def matrices(self):
        """Affine calibration ``x_true = A (x_meas - b)`` for accel and gyro: (A_f, b_f, A_w, b_w).

        ``A = (I + diag(s) - [m x] + S(n))^-1`` (``n = 0`` for the accelerometer): the exact inverse
        of the first-order model above.
        """
        A = np.empty((2, 3, 3))
        affine_into(*(np.asarray(getattr(self, k), float) for k in ("s_f", "m_f", "s_w", "m_w", "n_w")), A)
        return A[0], self.b_f.copy(), A[1], self.b_w.copy()


@nb.njit(cache=True)
def affine_into(s_f, m_f, s_w, m_w, n_w, out):
    """``out[0] = (I + diag(s_f) - [m_f x])^-1`` and ``out[1] = (I + diag(s_w) - [m_w x] + S(n_w))^-1``
    (:meth:`ImuCalibration.matrices`; ``out`` (>= 2, >= 3, 3), its first three columns written).
    A singular matrix (a scale factor of -1) raises ValueError, as numpy's inverse did."""
    M = np.empty((3, 3))
    A = np.empty((3, 3))
    for t in range(2):
        s, m = (s_f, m_f) if t == 0 else (s_w, m_w)
        K = skew(m)
        for i in range(3):
            for j in range(3):
                M[i, j] = (1.0 + s[i] if i == j else 0.0) - K[i, j]
        if t == 1:
            M[0, 1] += n_w[2]; M[1, 0] += n_w[2]
            M[0, 2] += n_w[1]; M[2, 0] += n_w[1]
            M[1, 2] += n_w[0]; M[2, 1] += n_w[0]
        det = inverse3_into(M, A)
        if not (det != 0.0 and np.isfinite(det)):
            raise ValueError("IMU calibration: the scale-factor/misalignment matrix is singular")
        for i in range(3):
            for j in range(3):
                out[t, i, j] = A[i, j]


GROUP_TO_FIELD = {"accel_bias": "b_f", "gyro_bias": "b_w", "accel_scale": "s_f",
                  "accel_misalignment": "m_f", "gyro_scale": "s_w", "gyro_misalignment": "m_w",
                  "gyro_nonorthogonality": "n_w"}


def symmetric_offdiagonal(n) -> np.ndarray:
    """``S(n)`` of the module docstring, ``n = (n_yz, n_xz, n_xy)``."""
    n_yz, n_xz, n_xy = np.asarray(n, float)
    return np.array([[0.0, n_xy, n_xz], [n_xy, 0.0, n_yz], [n_xz, n_yz, 0.0]])


def nonorthogonality_jacobian(w) -> np.ndarray:
    """``N(w)`` with ``N(w) n = S(n) w``: the rate error's sensitivity to the non-orthogonality."""
    wx, wy, wz = np.asarray(w, float)
    return np.array([[0.0, wz, wy], [wz, 0.0, wx], [wy, wx, 0.0]])


def split_misalignment(N) -> tuple[np.ndarray, np.ndarray]:
    """The rotation ``m`` and the non-orthogonality ``n`` of an off-diagonal matrix ``N``
    (``N = -[m x] + S(n)``, module docstring); the diagonal of ``N`` is ignored."""
    N = np.asarray(N, float)
    m = 0.5 * np.array([N[1, 2] - N[2, 1], N[2, 0] - N[0, 2], N[0, 1] - N[1, 0]])
    n = 0.5 * np.array([N[1, 2] + N[2, 1], N[0, 2] + N[2, 0], N[0, 1] + N[1, 0]])
    return m, n


def apply_calibration(f_meas, w_meas, cal: ImuCalibration):
    """Calibrated specific force and angular rate, ``A (x_meas - b)``, vectorised over samples."""
    f = as_vectors(f_meas, "f_meas")
    w = as_vectors(w_meas, "w_meas")
    A_f, b_f, A_w, b_w = cal.matrices()
    return (f - b_f) @ A_f.T, (w - b_w) @ A_w.T


def corrupt(f_true, w_true, *, b_f=0, b_w=0, s_f=0, m_f=0, s_w=0, m_w=0, n_w=0):
    """Apply the measurement model above (without noise) to true samples; for simulations/tests."""
    f = as_vectors(f_true, "f_true")
    w = as_vectors(w_true, "w_true")
    b_f, b_w, s_f, m_f, s_w, m_w, n_w = (np.broadcast_to(np.asarray(a, float), (3,))
                                         for a in (b_f, b_w, s_f, m_f, s_w, m_w, n_w))
    return (f + b_f + f * s_f + np.cross(f, m_f),
            w + b_w + w * s_w + np.cross(w, m_w) + w @ symmetric_offdiagonal(n_w))
