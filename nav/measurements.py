"""Observation equations of the navigation filter: GPS and camera direction vectors (003 §6.2-6.3).

Conventions (docs/conventions.md): ``psi`` in e with ``R_eb_true = (I + [psi x]) R_eb_est``; camera
misalignment ``psi_c`` in b with ``R_bc_true = (I + [psi_c x]) R_bc_nominal`` (003 eq. (50)).
Error states are "true minus estimated", innovations "measured minus predicted" (003 eq. (40)), so
``s = H z + noise`` with the Jacobians below.

Vectors (003 eqs. (39), (47), (48)). With ``u_e`` the unit direction in e (nadir
``-x/|x|`` or the Sun ``(X - x)/|X - x|``) and ``e_c = R_bc^T R_eb^T u_e``::

    H_psi   = R_bc^T R_eb^T [u_e x]                (003 eq. (48), first two lines)
    H_psi_c = R_bc^T [(R_eb^T u_e) x] = [e_c x] R_bc^T
    H_zeta  = I                                    (003 eq. (47))

003 eq. (48) writes the misalignment block as ``[e_c x]``: that is the same Jacobian with psi_c
expressed in the camera frame; here psi_c is in b to match eq. (50), hence the extra ``R_bc^T``.
003 neglects the position dependence; :func:`vector_jacobians` returns it too
(``H_dx = -R_bc^T R_eb^T (I - u u^T) / |x|`` for the nadir, about 1.5e-7 rad/m: small, kept).

A unit vector has two degrees of freedom, so the filter updates in the plane tangent to the
predicted vector (:func:`tangent_basis`): ``s2 = T^T s``, ``H2 = T^T H``, ``R2 = T^T R T``; this
is eq. (49) projected and makes the NIS chi-square with 2 degrees of freedom even when P_c from
003 eq. (33) is singular along the vector.

GPS (antenna at lever arm ``l_b`` in b)::

    x_ant = x_e + R_eb l_b            H = [I, 0, -[(R_eb l_b) x]]
    v_ant = v_e + R_eb (omega_eb_b x l_b)
                                      H = [0, I, -[(R_eb (omega_eb_b x l_b)) x]]
"""
from __future__ import annotations

import numpy as np

from nav import _kernels
from nav._kernels import skew
from nav.rotation import rotvec_to_matrix, tangent_bases, tangent_basis


def target_direction_e(target: str, x_e, target_pos_e=None) -> np.ndarray:
    """Unit direction in e from the vehicle at ``x_e`` to the target (003 eq. (39))."""
    x = np.asarray(x_e, float)
    if target == "hor":
        return -x / np.linalg.norm(x)
    if target_pos_e is None:
        raise ValueError(f"target_pos_e: the {target} direction needs the body's position in e")
    d = np.asarray(target_pos_e, float) - x
    return d / np.linalg.norm(d)


def predict_vector(u_e, R_eb, R_bc) -> np.ndarray:
    """Predicted camera-frame unit vector ``e_c = R_bc^T R_eb^T u_e`` (003 eq. (39))."""
    return R_bc.T @ (R_eb.T @ u_e)


def vector_jacobians(target: str, x_e, u_e, R_eb, R_bc, target_pos_e=None):
    """Jacobians of the vector error (003 eqs. (47)-(48)) w.r.t. dx, psi and psi_c (b-frame).

    Returns
    -------
    H_dx, H_psi, H_psic : (3, 3) each
    """
    R_ce = R_bc.T @ R_eb.T
    e_c = R_ce @ u_e
    H_psi = R_ce @ skew(np.asarray(u_e, float))
    H_psic = skew(e_c) @ R_bc.T
    x = np.asarray(x_e, float)
    if target == "hor":
        dist = np.linalg.norm(x)
        H_dx = -R_ce @ (np.eye(3) - np.outer(u_e, u_e)) / dist
    else:
        dist = np.linalg.norm(np.asarray(target_pos_e, float) - x)
        H_dx = -R_ce @ (np.eye(3) - np.outer(u_e, u_e)) / dist
    return H_dx, H_psi, H_psic


def second_order_noise(P, u_e, R_eb, R_bc, T) -> np.ndarray:
    """Covariance (2, 2) of the terms of a camera vector that are quadratic in the attitude error
    psi (e) and, when ``P`` is (6, 6), the camera misalignment psi_c (b): the noise a Gaussian
    second-order filter adds to the first-order model of 003 eqs. (47)-(49).

    With ``v = R_eb^T u_e``, ``psi_b = R_eb^T psi`` and ``phi = psi_b + psi_c`` (the camera's
    attitude error, in b), the true vector ``R_bc^T exp(-[psi_c x]) R_eb^T exp(-[psi x]) u_e`` is
    the predicted one plus ``H [psi; psi_c]`` plus, to second order,

        R_bc^T q,   q = 1/2 phi x (phi x v) + 1/2 (psi_c x psi_b) x v

    (the product of the two exponentials; the second term is their commutator). Each tangent
    component ``T[:, k]^T R_bc^T q`` is a quadratic form ``x^T A_k x`` of ``x = [psi; psi_c]``, and
    for ``x ~ N(0, P)`` its covariance is ``Cov_kl = 2 tr(A_k P A_l P)``
    (:func:`nav._kernels.quadratic_form_covariance` builds ``A_k`` in ``[psi_b; psi_c]``). It matters while psi
    and psi_c are both uncertain by a degree or more and the camera's attitude is not yet
    pinned (a 2 deg attitude with a 1 deg misalignment: about 0.05 deg, the size of the vision's
    error); once the vectors fix ``phi``, ``psi_c x psi_b = psi_c x phi`` is small and so is the term.

    Parameters
    ----------
    P : (3, 3) or (6, 6) prior covariance of psi, or of [psi; psi_c].
    u_e : (3,) unit direction to the target in e; R_eb, R_bc : current attitude and mounting.
    T : (3, 2) tangent basis of the predicted vector (:func:`tangent_basis`).
    """
    m = P.shape[0]
    v = R_eb.T @ np.asarray(u_e, float)
    B = np.eye(m)
    B[:3, :3] = R_eb.T
    Pt = B @ P @ B.T                               # covariance of [psi_b; psi_c]
    return _kernels.quadratic_form_covariance(Pt, v, R_bc @ np.asarray(T, float))


def vector_rate(target: str, x_e, v_e, u_e, R_eb, R_bc, w_eb_b, target_pos_e=None) -> np.ndarray:
    """Rate of change of the predicted camera-frame vector ``e_c = R_bc^T R_eb^T u_e`` [1/s]::

        de_c/dt = -[omega_c x] e_c + R_bc^T R_eb^T du_e/dt,    omega_c = R_bc^T omega_eb_b

    with ``dR_eb/dt = R_eb [omega_eb_b x]`` and ``du_e/dt = (I - u u^T) d'/|d|`` for the line of
    sight ``d`` to the target: ``d' = -v_e`` for the nadir (``d = -x_e``), ``d' = -[omega_ie x] X - v_e``
    for the Sun / Moon at X (fixed in inertial space, so moving in e with the Earth's rotation).
    The measurement Jacobian of a camera clock offset error is ``-de_c/dt`` (:mod:`nav.navigator`).
    """
    from nav.earth import OMEGA_IE_E
    R_ce = R_bc.T @ R_eb.T
    e_c = R_ce @ u_e
    w_c = R_bc.T @ np.asarray(w_eb_b, float)
    x = np.asarray(x_e, float)
    v = np.zeros(3) if v_e is None else np.asarray(v_e, float)
    if target == "hor":
        d, dd = -x, -v
    else:
        X = np.asarray(target_pos_e, float)
        d, dd = X - x, -np.cross(OMEGA_IE_E, X) - v
    du = (dd - u_e * (u_e @ dd)) / np.linalg.norm(d)
    return -np.cross(w_c, e_c) + R_ce @ du


def correct_mounting(R_bc, psi_c) -> np.ndarray:
    """003 eq. (50): ``(I + [psi_c x]) R_bc`` in its exact, orthonormal form ``exp([psi_c x]) R_bc``."""
    return rotvec_to_matrix(np.asarray(psi_c, float)) @ R_bc


def vector_covariance_problem(P_c, e_c) -> str | None:
    """Why a vision covariance is unusable, or None. Accepted: finite, symmetric (1e-9 relative),
    positive semi-definite, and positive definite in the plane tangent to the vector."""
    P = np.asarray(P_c, float)
    if P.shape != (3, 3):
        return f"covariance shape {P.shape}, expected (3, 3)"
    if not np.all(np.isfinite(P)):
        return "non-finite covariance"
    scale = max(np.max(np.abs(P)), 1e-300)
    if np.max(np.abs(P - P.T)) > 1e-9 * scale:
        return "non-symmetric covariance"
    ev = np.linalg.eigvalsh(0.5 * (P + P.T))
    if ev[0] < -1e-9 * scale:
        return "covariance not positive semi-definite"
    T = tangent_basis(e_c)
    if np.linalg.eigvalsh(T.T @ P @ T)[0] <= 1e-12 * scale:
        return "covariance not positive definite across the vector"
    return None


def gps_position(x_e, R_eb, lever_b):
    """Predicted antenna position and its Jacobians (H_dx, H_psi)."""
    r = R_eb @ np.asarray(lever_b, float)
    return np.asarray(x_e, float) + r, np.eye(3), -skew(r)


def gps_velocity(v_e, R_eb, w_eb_b, lever_b):
    """Predicted antenna velocity and its Jacobians (H_dv, H_psi); the gyro-error dependence of
    the lever-arm term (|l| * gyro error, micrometres per second) is neglected."""
    r = R_eb @ (skew(np.asarray(w_eb_b, float)) @ np.asarray(lever_b, float))
    return np.asarray(v_e, float) + r, np.eye(3), -skew(r)


def vector_covariance_problems(P_c, e_c) -> np.ndarray:
    """:func:`vector_covariance_problem` of every row at once: ``P_c`` (N, 3, 3), ``e_c`` (N, 3)
    unit vectors (rows that are not finite unit vectors get an answer that is not meaningful);
    returns an object array of reasons (None where the covariance is usable)."""
    P = np.asarray(P_c, float)
    e = np.asarray(e_c, float)
    N = P.shape[0]
    if P.shape != (N, 3, 3) or e.shape != (N, 3):
        raise ValueError(f"P_c, e_c: expected (N, 3, 3) and (N, 3), got {P.shape} and {e.shape}")
    out = np.full(N, None, dtype=object)
    fin = np.all(np.isfinite(P), axis=(1, 2))
    out[~fin] = "non-finite covariance"
    Pf = np.where(fin[:, None, None], P, np.eye(3))
    scale = np.maximum(np.max(np.abs(Pf), axis=(1, 2)), 1e-300)
    asym = fin & (np.max(np.abs(Pf - np.swapaxes(Pf, 1, 2)), axis=(1, 2)) > 1e-9 * scale)
    out[asym] = "non-symmetric covariance"
    ev = np.linalg.eigvalsh(0.5 * (Pf + np.swapaxes(Pf, 1, 2)))[:, 0]
    not_psd = fin & ~asym & (ev < -1e-9 * scale)
    out[not_psd] = "covariance not positive semi-definite"
    ok_e = np.all(np.isfinite(e), axis=1) & (np.linalg.norm(np.where(np.isfinite(e), e, 0.0), axis=1) > 0)
    T = tangent_bases(np.where(ok_e[:, None], e, [0.0, 0.0, 1.0]))
    ev2 = np.linalg.eigvalsh(np.swapaxes(T, 1, 2) @ Pf @ T)[:, 0]
    out[fin & ~asym & ~not_psd & (ev2 <= 1e-12 * scale)] = "covariance not positive definite across the vector"
    return out
