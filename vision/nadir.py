"""Direction of a spherical body from the rays of its limb: Earth nadir (known cone angle) and
Sun/Moon (unknown cone angle), 003 §2.4-2.6, §3.3-3.4, §5, on the unit sphere of 000 §2.2-2.4.

Cone equation on the unit sphere
--------------------------------
Every limb ray p lies on the cone of half-angle alpha about the body direction e
(003 eq. (3)): ``p^T e = cos(alpha) |p|``. With *unit* rays p_j (000 eq. (3): the edge pixels
mapped onto the unit sphere, which stays well conditioned for rays at or beyond 90 deg from the
optical axis, where 003's z = f plane points blow up) the m equations are linear in e::

    H e = cos(alpha) 1,    H = [p_1^T; ...; p_m^T]       (003 eqs. (22)-(23) with |p_j| = 1)

and the least-squares solution (003 eq. (24)) is computed with ``numpy.linalg.lstsq`` (SVD), not
the normal equations.

Unknown alpha (Sun, Moon; 003 §5): the equations are linear in ``n = e / cos(alpha)``::

    H n = 1,    e = n / |n|,    cos(alpha) = 1 / |n|

so the direction and the apparent radius come out of one linear solve (a blooming Sun gives a
larger alpha but the same direction, 003 §5). Rays must not lie on a great circle
(alpha = 90 deg, n infinite).

Note: for the unconstrained linear fit the *direction* of the known-alpha estimate does not depend
on alpha at all (``lstsq(H, c 1) = c lstsq(H, 1)``): the known angle only scales the solution,
which is why 003 §4 finds the estimate insensitive to the sphere's scale. ``method="constrained"``
uses alpha: it minimises |H e - cos(alpha) 1|^2 subject to |e| = 1 (a trust-region boundary
problem, solved exactly with the 3x3 eigen-decomposition and the secular equation), which is more
accurate on short arcs.

Residuals (for choosing among candidate edges; smallest wins, 003 §3.4)
-----------------------------------------------------------------------
- `angle_residual`: mean squared angular distance of the rays from the cone, [rad^2]:
  mean_j (acos(p_j^T e) - alpha)^2. Exact geometric distance on the sphere, valid at any theta.
- `pframe_residual`: 003 eqs. (25)-(28): the z = f plane points are rotated/shifted into the
  principal-axes frame of the estimated conic and compared along x_p. Only rays with z > 0 take
  part. f = 1 (normalised plane) unless given.

Mirrored nadir (002 §3): a short limb arc is also close to a cone of the same alpha around the
mirror image of e across the arc; `earth_side_check` scores a candidate against rays known to see
the body (or space) so the caller can reject the wrong side.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

__all__ = [
    "ConeFit",
    "nadir_from_horizon",
    "direction_and_radius",
    "constrained_cone_fit",
    "conic_type",
    "angle_residuals",
    "angle_residual",
    "per_ray",
    "within_cone",
    "pframe_residual",
    "earth_side_check",
    "mirrored_direction",
    "horizon_alpha",
]


@dataclass(frozen=True)
class ConeFit:
    """Result of a cone fit.

    Attributes
    ----------
    e_c : (3,) unit direction of the body centre in the camera frame (003 eq. (24), normalised).
    alpha : cone half-angle [rad] (given, or estimated for the Sun/Moon).
    n : (3,) the raw least-squares solution (e/cos(alpha) for ``H n = 1``, e for ``H e = c 1``);
        the covariance of `vision.covariance` is that of this vector.
    rhs : right-hand side value used in ``H n = rhs`` (cos(alpha) or 1).
    discriminant : 003 eq. (9), sin^2(alpha) - e_z^2 (> 0 hyperbola, < 0 ellipse).
    conic : "ellipse", "parabola" or "hyperbola" (003 eqs. (8)-(11), Table 1).
    residual : mean squared angular distance of the rays from the cone [rad^2] (`angle_residual`).
    m : number of rays used.
    method : "linear", "constrained" or "free-alpha".
    """

    e_c: np.ndarray
    alpha: float
    n: np.ndarray
    rhs: float
    discriminant: float
    conic: str
    residual: float
    m: int
    method: str


def horizon_alpha(height: float, radius: float, atmosphere: float = 0.0) -> float:
    """Earth cone half-angle alpha = arcsin((r + d)/(r + H)), 003 eq. (5) [rad]."""
    s = (radius + atmosphere) / (radius + height)
    if not 0.0 < s <= 1.0:
        raise ValueError(f"horizon_alpha: (r + d)/(r + H) = {s}; expected in (0, 1] "
                         f"(height {height} m, radius {radius} m, atmosphere {atmosphere} m)")
    return math.asin(s)


def conic_type(e_c: np.ndarray, alpha: float, tol: float = 1e-12) -> tuple[float, str]:
    """Discriminant Delta = sin^2(alpha) - e_z^2 (003 eq. (9)) and the conic it means (Table 1)."""
    delta = math.sin(alpha) ** 2 - float(e_c[2]) ** 2
    kind = "parabola" if abs(delta) <= tol else ("hyperbola" if delta > 0 else "ellipse")
    return delta, kind


def per_ray(values, m: int) -> np.ndarray:
    """A scalar or (m,) values as a C-contiguous float64 (m,) array, not copied when it already
    is one (np.broadcast_to's per-call overhead matters: this is called for every ray set)."""
    a = np.asarray(values, dtype=float)
    if a.shape == (m,):
        return np.ascontiguousarray(a)
    if a.ndim == 0:
        return np.full(m, float(a))
    return np.ascontiguousarray(np.broadcast_to(a, (m,)))


def check_rays(rays_c: np.ndarray, minimum: int = 3) -> np.ndarray:
    """Rays (m, 3), m >= ``minimum``, normalised to unit length; ValueError for a wrong shape, too
    few rays, NaN/inf or zero-length rays."""
    H = np.asarray(rays_c, dtype=float)
    if H.ndim != 2 or H.shape[1] != 3:
        raise ValueError(f"rays_c must have shape (m, 3), got {H.shape}")
    if H.shape[0] < minimum:
        raise ValueError(f"need at least {minimum} rays, got {H.shape[0]}")
    out, status = _normalise_rows(np.ascontiguousarray(H))
    if status == 1:
        raise ValueError("rays_c contains NaN/inf (pixels outside the camera's valid range?)")
    if status == 2:
        raise ValueError("rays_c contains zero-length rays")
    return out


@numba.njit(cache=True)
def _normalise_rows(H):
    """Rows of H (m, 3) divided by their norms; status 1: a NaN/inf, 2: a zero row, else 0."""
    m = H.shape[0]
    out = np.empty((m, 3))
    for j in range(m):
        if not (math.isfinite(H[j, 0]) and math.isfinite(H[j, 1]) and math.isfinite(H[j, 2])):
            return out, 1
    for j in range(m):
        n = math.sqrt(H[j, 0] * H[j, 0] + H[j, 1] * H[j, 1] + H[j, 2] * H[j, 2])
        if n == 0.0:
            return out, 2
        out[j, 0], out[j, 1], out[j, 2] = H[j, 0] / n, H[j, 1] / n, H[j, 2] / n
    return out, 0


def angle_residuals(rays_c: np.ndarray, e_c: np.ndarray, alpha: float) -> np.ndarray:
    """Signed angular distance of each unit ray from the cone, acos(p^T e) - alpha [rad]."""
    c = np.asarray(rays_c, dtype=float) @ np.asarray(e_c, dtype=float)
    if isinstance(c, np.ndarray):
        c = np.minimum(np.maximum(c, -1.0, out=c), 1.0, out=c)   # np.clip without its per-call overhead
    else:
        c = min(max(float(c), -1.0), 1.0)
    return np.arccos(c) - alpha


def within_cone(rays_c: np.ndarray, e_c: np.ndarray, alpha: float, threshold) -> np.ndarray:
    """Inlier mask ``|angle_residuals(rays_c, e_c, alpha)| <= threshold`` (scalar or per ray
    [rad]) of unit rays in one pass (the fits' inlier test; ~5 numpy calls otherwise)."""
    H = np.ascontiguousarray(rays_c, dtype=float).reshape(-1, 3)
    return _within_cone(H, np.ascontiguousarray(e_c, dtype=float), float(alpha), per_ray(threshold, H.shape[0]))


@numba.njit(cache=True)
def _within_cone(H, e, alpha, thr):  # pragma: no cover - numba
    m = H.shape[0]
    out = np.empty(m, np.bool_)
    for j in range(m):
        c = min(max(H[j, 0] * e[0] + H[j, 1] * e[1] + H[j, 2] * e[2], -1.0), 1.0)
        out[j] = abs(math.acos(c) - alpha) <= thr[j]
    return out


def angle_residual(rays_c: np.ndarray, e_c: np.ndarray, alpha: float) -> float:
    """Mean squared angular distance of the rays from the cone (e_c, alpha) [rad^2]."""
    H = np.ascontiguousarray(rays_c, dtype=float).reshape(-1, 3)
    return float(_mean_sq_residual(H, np.ascontiguousarray(e_c, dtype=float), float(alpha)))


def pframe_residual(rays_c: np.ndarray, e_c: np.ndarray, alpha: float, f: float = 1.0,
                    mean: bool = False) -> float:
    """Residual of 003 eqs. (25)-(28) in the principal-axes frame of the estimated conic.

    The rays with z > 0 are put on the plane z = f (p_i = f [x/z, y/z]), rotated so x_p is along
    [e_x, e_y] and shifted by f e_z rho / A' (the conic centre, rho = |[e_x, e_y]|), then
    ``delta = sum_j (|x_p,j| - sqrt(-C'/A' y_p,j^2 - F'/A'))^2`` (eq. (28)) with
    A' = rho^2 - cos^2(alpha), C' = -cos^2(alpha), F' = -f^2 (1 - cos^2 alpha) cos^2 alpha / A'
    (eq. (26)). For ellipses the square-root argument can go negative beyond the minor axis: it is
    clipped at 0 (003 designs this residual for flat hyperbolae). Undefined when e is along the
    optical axis (rho = 0) or for a parabola (A' = 0): returns inf. ``mean=True`` divides by the
    number of rays used.
    """
    P = np.asarray(rays_c, dtype=float)
    P = P[P[:, 2] > 0.0]
    ex, ey, ez = (float(v) for v in e_c)
    rho = math.hypot(ex, ey)
    c2 = math.cos(alpha) ** 2
    A1 = rho * rho - c2
    if P.shape[0] == 0 or rho < 1e-12 or abs(A1) < 1e-15:
        return math.inf
    C1 = -c2
    F1 = -f * f * (1.0 - c2) * c2 / A1
    xi = f * P[:, 0] / P[:, 2]
    yi = f * P[:, 1] / P[:, 2]
    xp = (ex * xi + ey * yi) / rho + f * ez * rho / A1
    yp = (-ey * xi + ex * yi) / rho
    arg = np.maximum(-C1 / A1 * yp * yp - F1 / A1, 0.0)
    d = np.abs(xp) - np.sqrt(arg)
    total = float(np.sum(d * d))
    return total / P.shape[0] if mean else total


def norm3(v: np.ndarray) -> float:
    """|v| of a 3-vector in float arithmetic (without np.linalg.norm's call overhead; fits are
    made several times per frame); NaN/inf propagate."""
    a, b, c = v.tolist()
    return math.sqrt(a * a + b * b + c * c)


def _make_fit(H: np.ndarray, n: np.ndarray, rhs: float, alpha: float, method: str,
              norm_n: float | None = None) -> ConeFit:
    e = n / (norm3(n) if norm_n is None else norm_n)
    delta, kind = conic_type(e, alpha)
    return ConeFit(e_c=e, alpha=float(alpha), n=n, rhs=float(rhs), discriminant=delta, conic=kind,
                   residual=_mean_sq_residual(H, e, float(alpha)), m=H.shape[0], method=method)


@numba.njit(cache=True)
def _mean_sq_residual(H, e, alpha):
    """`angle_residual` of the rows H in one pass (a fit's residual: the numpy version was ~6
    small calls, and every fit computes it)."""
    m = H.shape[0]
    acc = 0.0
    for j in range(m):
        c = H[j, 0] * e[0] + H[j, 1] * e[1] + H[j, 2] * e[2]
        r = math.acos(min(max(c, -1.0), 1.0)) - alpha
        acc += r * r
    return acc / m


@numba.njit(cache=True)
def _normal_eigen(H, c):
    """Eigen-decomposition (w ascending, Q) of N = H^T H and b = Q^T (c H^T 1) of
    `constrained_cone_fit` (the sums in one pass over the rays, LAPACK syevd for the 3x3)."""
    N = np.zeros((3, 3))
    g = np.zeros(3)
    for j in range(H.shape[0]):
        for a in range(3):
            g[a] += H[j, a]
            for b in range(3):
                N[a, b] += H[j, a] * H[j, b]
    w, Q = np.linalg.eigh(N)
    b = np.zeros(3)
    for a in range(3):
        b[a] = c * (Q[0, a] * g[0] + Q[1, a] * g[1] + Q[2, a] * g[2])
    return w, Q, b


@numba.njit(cache=True)
def _secular_root(w, b, lo, hi, scale):
    """Root lam in (lo, hi) of 1/|e(lam)| - 1, |e(lam)|^2 = sum b_i^2 / (w_i - lam)^2, by
    safeguarded Newton from lo (`constrained_cone_fit`; 3 eigenvalues)."""
    lam = lo
    for _ in range(200):
        d0, d1, d2 = w[0] - lam, w[1] - lam, w[2] - lam
        q0, q1, q2 = b[0] / d0, b[1] / d1, b[2] / d2
        s = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
        ds = (q0 * (q0 / d0) + q1 * (q1 / d1) + q2 * (q2 / d2)) / s  # d|e|/dlam
        phi = 1.0 / s - 1.0  # increasing -> 0 at the root; phi >= 0 left of it
        if phi > 0:
            lo = lam
        else:
            hi = lam
        if abs(phi) < 1e-15:
            break
        dphi = -ds / (s * s)
        new = lam - phi / dphi if dphi != 0 else 0.5 * (lo + hi)
        if not lo < new < hi:
            new = 0.5 * (lo + hi)
        if abs(new - lam) <= 1e-16 * scale:
            lam = new
            break
        lam = new
    return lam


def constrained_cone_fit(H: np.ndarray, c: float) -> np.ndarray:
    """argmin_{|e| = 1} |H e - c 1|^2 (global minimum), H with unit rows.

    Lagrange: (N - lam I) e = b with N = H^T H, b = c H^T 1, lam <= lam_min(N) for the global
    minimum (trust-region theory). In N's eigenbasis |e(lam)|^2 = sum b_i^2 / (lam_i - lam)^2 is
    increasing on (-inf, lam_min), so the root of 1/|e(lam)| - 1 is found by safeguarded Newton
    in the bracket [lam_min - |b|, lam_min). The "hard case" (b orthogonal to the smallest
    eigenvector) adds the eigenvector to reach unit length.
    """
    return _constrained_kernel(np.ascontiguousarray(H, dtype=float), float(c))


@numba.njit(cache=True)
def _constrained_kernel(H, c):
    """`constrained_cone_fit` in one numba call (its docstring; the numpy version made ~15 small
    calls per fit, and RANSAC and the scoring fit 2-4 times per candidate)."""
    w, Q, b = _normal_eigen(H, c)
    lam_min = w[0]
    bn = math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    lo, hi = lam_min - bn, lam_min
    scale = max(abs(w[2]), 1.0)
    e = np.empty(3)
    if abs(b[0]) <= 1e-14 * max(bn, 1e-300):
        # hard case: check whether lam = lam_min already gives |e| <= 1
        q = np.zeros(3)
        for i in range(1, 3):
            d = w[i] - lam_min
            q[i] = b[i] / (1.0 if d == 0 else d)
        sq = q[0] * q[0] + q[1] * q[1] + q[2] * q[2]
        if sq <= 1.0:
            q[0] = math.sqrt(1.0 - sq)
            for i in range(3):
                e[i] = Q[i, 0] * q[0] + Q[i, 1] * q[1] + Q[i, 2] * q[2]
            return e
    lam = _secular_root(w, b, lo, hi, scale)
    q0, q1, q2 = b[0] / (w[0] - lam), b[1] / (w[1] - lam), b[2] / (w[2] - lam)
    for i in range(3):
        e[i] = Q[i, 0] * q0 + Q[i, 1] * q1 + Q[i, 2] * q2
    en = math.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
    return e / en


def nadir_from_horizon(rays_c: np.ndarray, alpha: float, method: str = "constrained") -> ConeFit:
    """Earth nadir from horizon rays with known cone half-angle alpha.

    Parameters
    ----------
    rays_c : (m, 3) horizon rays in the camera frame (any length; normalised here), m >= 3.
    alpha : cone half-angle [rad], 003 eq. (5) (`horizon_alpha`), 0 < alpha < pi/2.
    method : "constrained" (default: |e| = 1 enforced, `constrained_cone_fit`, uses alpha) or
        "linear" (003 eq. (24) with unit rays, solved by lstsq; its direction does not depend on
        alpha and it is ill-conditioned on short arcs: with integer-rounded pixels of a 1920x1080
        94.4 deg fisheye it is off by degrees on 100-400 px arcs where "constrained" stayed
        below 0.02 deg, see tests/test_nadir.py).

    Returns
    -------
    ConeFit with e_c normalised, the conic type (003 eqs. (8)-(11)) and the angle residual.
    """
    if not 0.0 < alpha < math.pi / 2:
        raise ValueError(f"nadir_from_horizon: alpha = {alpha} rad; expected 0 < alpha < pi/2")
    H = check_rays(rays_c)
    c = math.cos(alpha)
    if method == "linear":
        n, _, rank, _ = np.linalg.lstsq(H, np.full(H.shape[0], c), rcond=None)
        if rank < 3:
            raise ValueError("nadir_from_horizon: degenerate ray set (rank < 3: rays on a great "
                             "circle or fewer than 3 distinct rays)")
    elif method == "constrained":
        n = constrained_cone_fit(H, c)
    else:
        raise ValueError(f"nadir_from_horizon: method {method!r}; expected 'linear' or 'constrained'")
    nn = norm3(n)
    if not (math.isfinite(nn) and nn > 0.0):
        raise ValueError("nadir_from_horizon: degenerate ray set (rays on a plane through the origin)")
    return _make_fit(H, n, c, alpha, method, nn)


def direction_and_radius(rays_c: np.ndarray) -> ConeFit:
    """Sun/Moon direction and apparent cone half-angle together (003 §5; alpha unknown).

    Solves ``H n = 1`` by least squares; e = n/|n|, alpha = arccos(1/|n|) (0 < alpha < 90 deg;
    a blooming disc gives a larger alpha, not a different direction). Three rays determine it
    exactly. Raises ValueError when the rays lie on a great circle (|n| < 1 cannot happen for a
    cone with alpha < 90 deg; it signals a non-conical ray set).
    """
    H = check_rays(rays_c)
    n, rank = _lstsq_ones(H)
    if rank < 3:
        raise ValueError("direction_and_radius: degenerate ray set (rank < 3: rays on a great "
                         "circle or fewer than 3 distinct rays)")
    nn = norm3(n)
    if not math.isfinite(nn) or nn < 1.0:
        raise ValueError(f"direction_and_radius: |n| = {nn:.6g} < 1: the rays do not lie on a cone "
                         f"with half-angle below 90 deg")
    return _make_fit(H, n, 1.0, math.acos(1.0 / nn), "free-alpha", nn)


@numba.njit(cache=True)
def _lstsq_ones(H):
    """``np.linalg.lstsq(H, 1, rcond=None)`` (LAPACK gelsd, numpy's default rcond eps * max(m, 3))
    in one numba call: solution and rank."""
    m = H.shape[0]
    x, _, rank, _ = np.linalg.lstsq(H, np.ones(m), np.finfo(np.float64).eps * max(m, 3))
    return x, rank


def mirrored_direction(e_c: np.ndarray, rays_c: np.ndarray) -> np.ndarray:
    """Mirror image of e across the great-circle plane that best fits the arc (002 §3).

    The plane through the origin closest to the rays has the normal of the smallest right
    singular vector of H; the mirror e' = e - 2 (e.u) u is the other local minimum of the
    unit-constrained fit for a short, nearly straight arc.
    """
    H = check_rays(rays_c, minimum=2)
    u = np.linalg.svd(H, full_matrices=False)[2][-1]
    e = np.asarray(e_c, dtype=float)
    return e - 2.0 * (e @ u) * u


def earth_side_check(e_c: np.ndarray, alpha: float, body_rays: np.ndarray | None = None,
                     space_rays: np.ndarray | None = None, margin: float = 0.0) -> float:
    """Fraction of reference rays on their expected side of the cone (e_c, alpha) (002 §3).

    ``body_rays``: rays of pixels known to see the body (bright side of the edge, e.g. a few
    pixels a short step inside the edge); they must satisfy angle(p, e) < alpha - margin.
    ``space_rays``: rays known to see space; angle(p, e) > alpha + margin. Returns the fraction
    of all given rays that agree (1.0 = consistent, ~0 = mirrored nadir / wrong side). The
    caller compares candidates (e.g. e and `mirrored_direction(e, rays)`) and keeps the best.
    """
    e = np.asarray(e_c, dtype=float)
    e = e / np.linalg.norm(e)
    good, total = 0, 0
    if body_rays is not None:
        B = check_rays(body_rays, minimum=1)
        ang = np.arccos(np.clip(B @ e, -1, 1))
        good += int(np.count_nonzero(ang < alpha - margin))
        total += B.shape[0]
    if space_rays is not None:
        S = check_rays(space_rays, minimum=1)
        ang = np.arccos(np.clip(S @ e, -1, 1))
        good += int(np.count_nonzero(ang > alpha + margin))
        total += S.shape[0]
    if total == 0:
        raise ValueError("earth_side_check: give body_rays and/or space_rays")
    return good / total
