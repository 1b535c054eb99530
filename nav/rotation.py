"""Rotation helpers following docs/conventions.md.

``R_ab`` maps a vector from frame b into frame a (``v_a = R_ab @ v_b``); quaternions are stored
scalar-last ``[x, y, z, w]`` with unit norm, the same convention as
``scipy.spatial.transform.Rotation`` (which the tests use as the reference). These are the small,
allocation-light forms used by the filter; everything is vectorised over leading axes.
"""
from __future__ import annotations

import numpy as np

from nav.checks import as_finite, as_matrices, as_vectors, unit


def skew(v) -> np.ndarray:
    """Skew-symmetric matrix ``[v x]`` so that ``skew(a) @ b == cross(a, b)`` (003 eq. (48))."""
    v = as_vectors(v, "v")
    z = np.zeros_like(v[..., 0])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], axis=-2)


def quat_normalize(q) -> np.ndarray:
    """Unit quaternion with non-negative scalar part (the same rotation, one representative)."""
    q = unit(as_vectors(q, "q", 4), "q")
    return np.where(q[..., 3:4] < 0, -q, q)


def quat_to_matrix(q) -> np.ndarray:
    """Scalar-last unit quaternion -> rotation matrix ``R`` (the quaternion is normalised first)."""
    q = unit(as_vectors(q, "q", 4), "q")
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def matrix_to_quat(R) -> np.ndarray:
    """Rotation matrix -> scalar-last unit quaternion, w >= 0 (Shepperd's method, branch on the
    largest of trace and diagonal so that the square root never loses precision)."""
    R = as_matrices(R, "R")
    tr = np.trace(R, axis1=-2, axis2=-1)
    d = np.stack([R[..., 0, 0], R[..., 1, 1], R[..., 2, 2], tr], axis=-1)
    k = np.argmax(d, axis=-1)
    q = np.empty(R.shape[:-2] + (4,))
    # Case w largest.
    s = np.sqrt(np.maximum(1.0 + tr, 0.0)) * 2.0
    cw = np.stack([(R[..., 2, 1] - R[..., 1, 2]) / np.where(s == 0, 1, s),
                   (R[..., 0, 2] - R[..., 2, 0]) / np.where(s == 0, 1, s),
                   (R[..., 1, 0] - R[..., 0, 1]) / np.where(s == 0, 1, s), 0.25 * s], -1)
    cases = [cw]
    for i in range(3):
        j, m = (i + 1) % 3, (i + 2) % 3
        s = np.sqrt(np.maximum(1.0 + R[..., i, i] - R[..., j, j] - R[..., m, m], 0.0)) * 2.0
        s_safe = np.where(s == 0, 1, s)
        c = np.empty(R.shape[:-2] + (4,))
        c[..., i] = 0.25 * s
        c[..., j] = (R[..., j, i] + R[..., i, j]) / s_safe
        c[..., m] = (R[..., m, i] + R[..., i, m]) / s_safe
        c[..., 3] = (R[..., m, j] - R[..., j, m]) / s_safe
        cases.append(c)
    # argmax index 3 is the trace (w case), 0..2 the diagonal (x, y, z cases).
    q = np.where((k == 3)[..., None], cases[0],
                 np.where((k == 0)[..., None], cases[1],
                          np.where((k == 1)[..., None], cases[2], cases[3])))
    return quat_normalize(q)


def quat_multiply(p, q) -> np.ndarray:
    """Hamilton product ``p * q`` (scalar-last), so that ``R(p * q) = R(p) @ R(q)``."""
    p = as_vectors(p, "p", 4)
    q = as_vectors(q, "q", 4)
    pv, pw = p[..., :3], p[..., 3:4]
    qv, qw = q[..., :3], q[..., 3:4]
    v = pw * qv + qw * pv + np.cross(pv, qv)
    w = pw * qw - np.sum(pv * qv, axis=-1, keepdims=True)
    return np.concatenate([v, w], axis=-1)


def rotvec_to_quat(phi) -> np.ndarray:
    """Rotation vector (axis * angle) -> unit quaternion; exact, with a series near zero."""
    phi = as_vectors(phi, "phi")
    a = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * a
    # sin(a/2)/a, with its Taylor series below 1e-4 rad where the quotient loses digits.
    k = np.where(a < 1e-4, 0.5 - a * a / 48.0, np.sin(half) / np.where(a == 0, 1, a))
    return np.concatenate([k * phi, np.cos(half)], axis=-1)


def quat_to_rotvec(q) -> np.ndarray:
    """Unit quaternion -> rotation vector with angle in [0, pi]."""
    q = quat_normalize(q)
    v = q[..., :3]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(s, q[..., 3:4])
    k = np.where(s < 1e-12, 2.0, angle / np.where(s == 0, 1, s))
    return k * v


def rotvec_to_matrix(phi) -> np.ndarray:
    """Rotation vector -> rotation matrix ``exp([phi x])`` (Rodrigues)."""
    return quat_to_matrix(rotvec_to_quat(phi))


def matrix_to_rotvec(R) -> np.ndarray:
    return quat_to_rotvec(matrix_to_quat(R))


def small_angle_update(R, psi) -> np.ndarray:
    """Apply an attitude correction: ``exp([psi x]) @ R``, the exact form of
    ``(I + [psi x]) @ R`` (docs/conventions.md "Rotations"; 003 eq. (50)) that keeps R orthonormal."""
    return rotvec_to_matrix(psi) @ as_matrices(R, "R")


def tangent_basis(e) -> np.ndarray:
    """(3, 2) orthonormal basis ``[t1, t2]`` of the plane perpendicular to ``e`` (normalised first):
    ``t1 = e x a / |e x a|`` with ``a`` the x axis (the y axis when e is within 26 deg of x),
    ``t2 = e x t1`` (:func:`nav._kernels.tangent_basis`; it is called per measurement and per fit)."""
    from nav._kernels import tangent_basis as kernel   # numba: imported when first needed
    e = np.asarray(e, dtype=float).reshape(3)
    if not float(np.dot(e, e)) > 0.0:
        raise ValueError("e: zero-length or non-finite vector has no tangent plane")
    return kernel(e)


def tangent_bases(e, *, unit: bool = False) -> np.ndarray:
    """:func:`tangent_basis` of every row of ``e`` (N, 3): (N, 3, 2). ``unit``: the rows are unit
    vectors already and are used as they are (not normalised again)."""
    e = as_vectors(e, "e")
    if not unit:
        e = e / np.linalg.norm(e, axis=-1, keepdims=True)
    a = np.where((np.abs(e[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    t1 = np.cross(e, a)
    t1 /= np.linalg.norm(t1, axis=-1, keepdims=True)
    return np.stack([t1, np.cross(e, t1)], axis=-1)


def angle_between(a, b) -> np.ndarray:
    """Angle between vectors [rad], accurate at small and large angles (atan2 form)."""
    a = as_vectors(a, "a")
    b = as_vectors(b, "b")
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def triad(v1_b, v2_b, v1_r, v2_r, *, min_angle_deg: float = 1.0) -> np.ndarray:
    """TRIAD attitude from two vector pairs (Black 1964, 003 ref. [4]; 003 §7.4).

    Parameters
    ----------
    v1_b, v2_b : (..., 3)
        The two directions measured in the body frame (any length).
    v1_r, v2_r : (..., 3)
        The same directions in the reference frame (e.g. e). ``v1`` is the primary vector: it is
        matched exactly; ``v2`` fixes the rotation about it.
    min_angle_deg : float
        Smallest angle between the two vectors (in either frame) accepted. The TRIAD error grows
        as 1/sin(angle) of the secondary vector's error, so nearly parallel pairs raise.

    Returns
    -------
    R_rb : (..., 3, 3)
        Rotation from body into the reference frame, ``v_r = R_rb @ v_b``.
    """
    b1 = unit(as_vectors(v1_b, "v1_b"), "v1_b")
    b2 = unit(as_vectors(v2_b, "v2_b"), "v2_b")
    r1 = unit(as_vectors(v1_r, "v1_r"), "v1_r")
    r2 = unit(as_vectors(v2_r, "v2_r"), "v2_r")
    lim = np.deg2rad(as_finite(min_angle_deg, "min_angle_deg"))
    for name, a, b in (("v1_b, v2_b", b1, b2), ("v1_r, v2_r", r1, r2)):
        ang = angle_between(a, b)
        ang = np.minimum(ang, np.pi - ang)
        if np.any(ang < lim):
            raise ValueError(f"triad: vectors {name} are {np.rad2deg(np.min(ang)):.3g} deg from parallel; "
                             f"TRIAD needs at least min_angle_deg={float(np.rad2deg(lim)):.3g} deg")

    def frame(u, w):
        t2 = unit(np.cross(u, w), "cross")
        return np.stack([u, t2, np.cross(u, t2)], axis=-1)

    return frame(r1, r2) @ np.swapaxes(frame(b1, b2), -1, -2)


def euler_zyx_deg(R_nb) -> tuple:
    """Roll, pitch, heading [deg] of body -> north-east-down rotations ``R_nb`` (..., 3, 3) in the
    z-y-x convention (heading about down, then pitch, then roll); heading in [0, 360)."""
    roll = np.degrees(np.arctan2(R_nb[..., 2, 1], R_nb[..., 2, 2]))
    pitch = np.degrees(-np.arcsin(np.clip(R_nb[..., 2, 0], -1.0, 1.0)))
    heading = np.degrees(np.arctan2(R_nb[..., 1, 0], R_nb[..., 0, 0])) % 360.0
    return roll, pitch, heading
