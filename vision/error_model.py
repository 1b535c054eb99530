"""Vision error model: what the filter studies use instead of images (003 §3.5, §6.3).

The filter studies feed the navigation filter "vectors from truth plus the vision error model":
the true Earth nadir (or Sun) direction in the camera frame, perturbed by errors whose covariance is
the one the vision front end would report for that geometry. Three steps:

1. `predicted_limb_pixels`: the part of the limb that the camera would see. The cone of half-angle
   alpha about the body direction e (003 eq. (3); Earth: alpha from eq. (5), Sun/Moon: apparent
   radius inflated by a bloom factor, `bloomed_alpha`) is traced ray by ray, projected through the
   camera model (003 eqs. (13)-(14)), and kept where it falls inside the image and outside the
   payload mask. The kept curve is split into contiguous arcs and each arc is resampled at
   ``step_px`` (1 px) arc-length spacing *on the exact curve* (the cone angle is interpolated,
   the rays are recomputed), ordered along the curve as an edge follower would report it.
2. `predicted_covariance` / `predict_vision`: the covariance of the estimated direction for the
   longest visible arc, from `vision.covariance.direction_covariance` (003 eq. (33) with the
   correlated pixel noise of eqs. (34)-(35), in O(m)): R = (1 px)^2, L = 300 px for the horizon
   (eq. (36)) and R = (3 px)^2, L = 300 px for the Sun (eq. (38)). The default estimator is the
   one `vision.nadir` uses for that body ("constrained" for the Earth, "free-alpha" for the Sun).
   Too short an arc gives ``None`` (see `predict_vision` for the reason).
3. `draw_vector_errors`: simulated measured vectors = truth + a first-order Gauss-Markov
   time-correlated part (003 eqs. (41)-(45), T_c = 20 s) + white noise, whose sum has the
   predicted covariance at every epoch.

Why the longest arc only: the front end selects *one* edge per body (the candidate with the
smallest residual, 003 §3.4), so a limb cut in two by the payload mask or the image border gives
two candidates, not one longer edge. The other arcs are available from
``predicted_limb_pixels(..., arcs="all")``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from vision.camera import Camera, project, unproject_jacobian
from vision.covariance import DirectionCovariance, direction_covariance, tangent_basis
from vision.nadir import conic_type

__all__ = [
    "HORIZON_NOISE",
    "SUN_NOISE",
    "T_C",
    "VisionPrediction",
    "DrawnVectors",
    "cone_rays",
    "trace_limb",
    "predicted_limb_pixels",
    "predict_vision",
    "predicted_covariance",
    "bloomed_alpha",
    "linear_recurrence",
    "psd_sqrt",
    "draw_vector_errors",
]

#: (R [px^2], L [px]) of the horizon pixel noise, 003 eq. (36).
HORIZON_NOISE = (1.0, 300.0)
#: (R [px^2], L [px]) of the Sun pixel noise, 003 eq. (38).
SUN_NOISE = (9.0, 300.0)
#: Correlation time of the vector errors [s], 003 §6.3.
T_C = 20.0

_METHODS = ("constrained", "linear", "free-alpha")


# ----------------------------------------------------------------------------------------------
# limb tracing


def cone_rays(e_c: np.ndarray, alpha: float, phi: np.ndarray) -> np.ndarray:
    """Unit rays (n, 3) on the cone of half-angle alpha about unit e_c (003 eq. (3)).

    ``p(phi) = cos(alpha) e + sin(alpha) (cos(phi) t1 + sin(phi) t2)`` with (t1, t2) the tangent
    basis of `vision.covariance.tangent_basis`; phi in rad.
    """
    e = np.asarray(e_c, dtype=float)
    T = tangent_basis(e)
    phi = np.asarray(phi, dtype=float)
    return (math.cos(alpha) * e[None, :]
            + math.sin(alpha) * (np.cos(phi)[:, None] * T[:, 0] + np.sin(phi)[:, None] * T[:, 1]))


def _unit(e_c: np.ndarray, name: str = "e_c") -> np.ndarray:
    e = np.asarray(e_c, dtype=float)
    if e.shape != (3,) or not np.all(np.isfinite(e)) or np.linalg.norm(e) == 0:
        raise ValueError(f"{name}: expected a finite non-zero 3-vector, got {e!r}")
    return e / np.linalg.norm(e)


def _check_alpha(alpha: float) -> float:
    a = float(alpha)
    if not 0.0 < a < math.pi / 2:
        raise ValueError(f"alpha = {alpha!r} rad; expected a cone half-angle in (0, pi/2) "
                         f"(003 eq. (5) for the Earth, bloomed apparent radius for Sun/Moon)")
    return a


def trace_limb(e_c: np.ndarray, alpha: float, project_fn: Callable[[np.ndarray], np.ndarray],
               keep_fn: Callable[[np.ndarray], np.ndarray], step_px: float = 1.0,
               n_start: int = 4096, n_max: int = 1 << 22) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """Visible arcs of the cone (e_c, alpha) in pixel coordinates, resampled every ``step_px``.

    Parameters
    ----------
    e_c, alpha : body direction (camera frame) and cone half-angle [rad].
    project_fn : rays (n, 3) -> pixels (n, 2) (NaN where a ray cannot be imaged).
    keep_fn : pixels (n, 2) -> bool (n,), True where the pixel is seen (finite, in the image,
        not masked).
    step_px : arc-length spacing of the output samples [px].

    Returns
    -------
    List of ``(uv (m, 2), phi (m,), closed)`` per contiguous arc, longest first. ``phi`` are the
    cone angles of the samples (exact curve points); ``closed`` is True when the whole limb is
    visible (then the arc runs once around it).

    The cone is first sampled uniformly in phi; the sampling is refined until the largest chord
    between consecutive visible samples is below step_px/4, so runs are not split or merged by
    the sampling and the arc-length parameterisation is accurate to well below a pixel.
    """
    e = _unit(e_c)
    alpha = _check_alpha(alpha)
    if not step_px > 0:
        raise ValueError(f"step_px = {step_px!r}; expected > 0 [px]")
    n = int(n_start)
    while True:
        phi = np.arange(n) * (2.0 * math.pi / n)
        uv = project_fn(cone_rays(e, alpha, phi))
        keep = np.asarray(keep_fn(uv), dtype=bool) & np.all(np.isfinite(uv), axis=1)
        if not keep.any():
            return []
        both = keep & np.roll(keep, -1)
        chord = np.linalg.norm(np.roll(uv, -1, axis=0) - uv, axis=1)
        worst = float(np.max(np.where(both, chord, 0.0)))
        if worst <= step_px / 4 or n >= n_max:
            break
        n = min(n_max, int(n * min(64.0, math.ceil(4.0 * worst / step_px + 1.0))))
    dphi = 2.0 * math.pi / n
    closed = bool(keep.all())
    if closed:
        runs = [np.arange(n + 1)]  # once around, back to the start
    else:
        k = int(np.argmin(keep))  # start outside so no arc is cut at phi = 0
        order = (np.arange(n) + k) % n
        kept = order[keep[order]]
        pos = np.nonzero(keep[order])[0]
        runs = np.split(kept, np.nonzero(np.diff(pos) > 1)[0] + 1)
        runs = [np.asarray(r) for r in runs]
    out = []
    for run in runs:
        # phi unwrapped along the run (indices increase modulo n)
        steps = np.diff(run) % n
        ph = run[0] * dphi + np.concatenate([[0.0], np.cumsum(steps) * dphi])
        q = project_fn(cone_rays(e, alpha, ph))
        s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])
        total = s[-1]
        if total <= 0.0:
            t = np.zeros(1)
        elif closed:
            t = np.arange(0.0, total - 0.5 * step_px, step_px)
        else:
            t = np.arange(0.0, total, step_px)
        ph_t = np.interp(t, s, ph)
        uv_t = project_fn(cone_rays(e, alpha, ph_t))
        ok = np.asarray(keep_fn(uv_t), dtype=bool) & np.all(np.isfinite(uv_t), axis=1)
        # a resampled point can only leave the visible set within step/4 of a run end
        out.append((uv_t[ok], np.mod(ph_t[ok], 2.0 * math.pi), closed))
    out.sort(key=lambda a: -len(a[0]))
    return out


def camera_keep(camera: Camera, mask: np.ndarray | None) -> Callable[[np.ndarray], np.ndarray]:
    """Test of pixels (k, 2): inside the image and, with a payload ``mask`` (H, W; True =
    payload), off the mask."""
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != (camera.height, camera.width):
            raise ValueError(f"mask: shape {mask.shape}; expected (height, width) = "
                             f"({camera.height}, {camera.width}) of camera {camera.name!r}, "
                             f"True where the payload hides the view")
        mask = mask.astype(bool)

    def keep(uv: np.ndarray) -> np.ndarray:
        u, v = uv[:, 0], uv[:, 1]
        with np.errstate(invalid="ignore"):
            ok = ((u >= -0.5) & (u <= camera.width - 0.5) & (v >= -0.5) & (v <= camera.height - 0.5))
        if mask is not None and ok.any():
            iu = np.clip(np.rint(u[ok]), 0, camera.width - 1).astype(np.intp)
            iv = np.clip(np.rint(v[ok]), 0, camera.height - 1).astype(np.intp)
            sub = ok.copy()
            sub[ok] = ~mask[iv, iu]
            ok = sub
        return ok

    return keep


def predicted_limb_pixels(camera: Camera, e_c: np.ndarray, alpha: float,
                          mask: np.ndarray | None = None, step_px: float = 1.0,
                          arcs: str = "longest") -> np.ndarray | list[np.ndarray]:
    """Visible limb of the body (e_c, alpha) in distorted pixels (u, v), ordered along the curve.

    Parameters
    ----------
    camera : the camera model (any `vision.camera` model).
    e_c : (3,) body direction in the camera frame (Earth nadir or Sun), any length.
    alpha : cone half-angle [rad] (003 eq. (5); `bloomed_alpha` for the Sun/Moon).
    mask : optional bool (height, width), True where the payload hides the view (003 §3.1: "the
        area on the right where the payload is visible was set to be ignored").
    step_px : spacing of consecutive pixels along the curve [px] (1 px: an edge follower's spacing).
    arcs : "longest" -> (m, 2) array of the longest contiguous arc ((0, 2) if nothing is seen);
        "all" -> list of (m_i, 2) arrays, longest first.

    Pixels are exact projections of cone rays (sub-pixel floats, not rounded); every returned
    pixel lies inside the image (pixel edges, [-0.5, w - 0.5] x [-0.5, h - 0.5]) and off the mask.
    """
    if arcs not in ("longest", "all"):
        raise ValueError(f"arcs = {arcs!r}; expected 'longest' or 'all'")
    found = trace_limb(e_c, alpha, lambda r: project(camera, r), camera_keep(camera, mask), step_px)
    if arcs == "all":
        return [a[0] for a in found]
    return found[0][0] if found else np.zeros((0, 2))


# ----------------------------------------------------------------------------------------------
# predicted covariance


def bloomed_alpha(apparent_radius: float, bloom: float = 1.0) -> float:
    """Cone half-angle of a blooming Sun/Moon disc: ``bloom * apparent_radius`` [rad] (003 §5:
    the visible disc is larger than the body, same centre direction). ``bloom >= 1``."""
    if not (apparent_radius > 0 and bloom >= 1.0):
        raise ValueError(f"bloomed_alpha: apparent_radius = {apparent_radius!r} rad (expected > 0), "
                         f"bloom = {bloom!r} (expected >= 1)")
    return _check_alpha(bloom * apparent_radius)


@dataclass(frozen=True)
class VisionPrediction:
    """What the vision front end would deliver for one body at one epoch.

    Attributes
    ----------
    pixels : (m, 2) the arc used (longest visible arc), ordered, ``step_px`` apart.
    covariance : `vision.covariance.DirectionCovariance` (P_n, P_c, P_sphere eq. (37)) or None.
    reason : "" when ``covariance`` is given, otherwise why not (nothing in view, hidden by the
        mask, arc shorter than ``min_pixels``, degenerate geometry).
    n_arcs : number of visible arcs (the others are not used, see the module docstring).
    conic : "ellipse", "parabola" or "hyperbola" (003 eqs. (9)-(11), Table 1).
    method : estimator the covariance describes.
    """

    pixels: np.ndarray
    covariance: DirectionCovariance | None
    reason: str
    n_arcs: int
    conic: str
    method: str


def predict_vision(camera: Camera, e_c: np.ndarray, alpha: float,
                   R_px2: float = HORIZON_NOISE[0], L_px: float = HORIZON_NOISE[1],
                   mask: np.ndarray | None = None, step_px: float = 1.0,
                   method: str = "constrained", min_pixels: int = 30) -> VisionPrediction:
    """Visible arc and predicted direction covariance of one body (003 eq. (33), (34)-(37)).

    Parameters
    ----------
    camera, e_c, alpha, mask, step_px : as `predicted_limb_pixels`.
    R_px2, L_px : pixel noise variance [px^2] and correlation length [px] (003 eq. (34)-(35)):
        `HORIZON_NOISE` = (1, 300) (eq. (36)), `SUN_NOISE` = (9, 300) (eq. (38)).
    method : the estimator whose error is predicted: "constrained" (`vision.nadir.
        nadir_from_horizon` default, Earth), "linear" (003 eq. (24)/(33) as written) or
        "free-alpha" (`vision.nadir.direction_and_radius`, Sun/Moon: ``H n = 1``,
        n = e / cos(alpha); 003 §5).
    min_pixels : shortest arc [samples] for which a covariance is given. Below it the front end
        would not accept the edge and eq. (33), a first-order (linearised) result, no longer
        describes the error of a fit to a few pixels (short arcs have strongly non-Gaussian
        errors and the mirrored-nadir ambiguity of 002 §3).
    """
    if method not in _METHODS:
        raise ValueError(f"method = {method!r}; expected one of {_METHODS}")
    if not (R_px2 >= 0 and math.isfinite(R_px2)):
        raise ValueError(f"R_px2 = {R_px2!r}; expected a finite pixel variance >= 0 [px^2]")
    if not L_px >= 1.0:
        raise ValueError(f"L_px = {L_px!r}; expected a correlation length >= 1 px (003 eq. (35))")
    e = _unit(e_c)
    alpha = _check_alpha(alpha)
    _, kind = conic_type(e, alpha)
    found = trace_limb(e, alpha, lambda r: project(camera, r), camera_keep(camera, mask), step_px)
    if not found:
        if mask is not None:
            unmasked = trace_limb(e, alpha, lambda r: project(camera, r), camera_keep(camera, None),
                                  step_px)
            if unmasked:
                return VisionPrediction(np.zeros((0, 2)), None,
                                        "the limb is inside the image but hidden by the mask",
                                        0, kind, method)
        return VisionPrediction(np.zeros((0, 2)), None, "no part of the limb is inside the image",
                                0, kind, method)
    uv = found[0][0]
    if len(uv) < min_pixels:
        return VisionPrediction(uv, None, f"only {len(uv)} limb pixels visible in the longest arc "
                                f"(minimum {min_pixels})", len(found), kind, method)
    rays, J = unproject_jacobian(camera, uv)
    if method == "free-alpha":
        n = e / math.cos(alpha)
        cov_method = "linear"
    else:
        n = e
        cov_method = method
    try:
        cov = direction_covariance(rays, J, n, R_px2, L_px, method=cov_method)
    except np.linalg.LinAlgError:
        cov = None
    if cov is None or not np.all(np.isfinite(cov.P_c)):
        return VisionPrediction(uv, None, "degenerate arc (H^T H singular)", len(found), kind, method)
    return VisionPrediction(uv, cov, "", len(found), kind, method)


def predicted_covariance(camera: Camera, e_c: np.ndarray, alpha: float,
                         R_px2: float = HORIZON_NOISE[0], L_px: float = HORIZON_NOISE[1],
                         mask: np.ndarray | None = None, step_px: float = 1.0,
                         method: str = "constrained", min_pixels: int = 30) -> DirectionCovariance | None:
    """P_n / P_c / P_sphere of the visible limb arc, or None when too few pixels are visible.

    Shorthand for ``predict_vision(...).covariance``; call `predict_vision` to learn why it is None.
    """
    return predict_vision(camera, e_c, alpha, R_px2, L_px, mask, step_px, method,
                          min_pixels).covariance


# ----------------------------------------------------------------------------------------------
# drawing time-correlated vector errors


def linear_recurrence(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x_k = a_k x_{k-1} + b_k along axis 0 (x_{-1} = 0), vectorised (Hillis-Steele scan).

    ``a`` (K,), ``b`` (K, ...). log2(K) passes of whole-array operations, O(K log K) work, no
    division (stable for any a_k in [0, 1], including 0).
    """
    A = np.asarray(a, dtype=float).copy()
    X = np.asarray(b, dtype=float).copy()
    K = A.shape[0]
    if X.shape[0] != K:
        raise ValueError(f"linear_recurrence: a has {K} steps, b has {X.shape[0]}")
    ex = (slice(None),) + (None,) * (X.ndim - 1)
    d = 1
    while d < K:
        X[d:] = X[d:] + A[d:][ex] * X[:-d]
        A[d:] = A[d:] * A[:-d]
        d *= 2
    return X


def psd_sqrt(P: np.ndarray) -> np.ndarray:
    """Symmetric square roots S (S S^T = P) of PSD matrices (..., n, n); negative eigenvalues
    from rounding are clipped to 0."""
    w, V = np.linalg.eigh(0.5 * (P + np.swapaxes(P, -1, -2)))
    return (V * np.sqrt(np.clip(w, 0.0, None))[..., None, :]) @ np.swapaxes(V, -1, -2)


@dataclass(frozen=True)
class DrawnVectors:
    """Simulated vision vectors.

    Attributes
    ----------
    e_meas : ([runs,] K, 3) measured unit vectors, normalised ``e_true + zeta + white``.
    P_report : (K, 3, 3) covariance to report with each vector (the P given: total of both parts).
    zeta : ([runs,] K, 3) the time-correlated Gauss-Markov part (003 eqs. (41)-(45)).
    white : ([runs,] K, 3) the white part.
    """

    e_meas: np.ndarray
    P_report: np.ndarray
    zeta: np.ndarray
    white: np.ndarray


def draw_vector_errors(e_true: np.ndarray, P: np.ndarray, t_s: np.ndarray,
                       rng: np.random.Generator, *, T_c: float = T_C, gm_fraction: float = 1.0,
                       transition: str = "exact", runs: int | None = None) -> DrawnVectors:
    """Measured direction vectors: truth + Gauss-Markov part + white part (003 §6.3).

    Parameters
    ----------
    e_true : (K, 3) true unit directions (camera frame) at the epochs ``t_s``.
    P : (K, 3, 3) or (3, 3) predicted covariance (P_c or P_sphere of `predict_vision`).
    t_s : (K,) strictly increasing epochs [s] (gaps are allowed: the correlation decays over them).
    rng : numpy Generator (seeded by the caller).
    T_c : correlation time [s] (003 §6.3: 20 s).
    gm_fraction : share f in [0, 1] of P carried by the time-correlated part; the white part has
        (1 - f) P. Default 1: 003 §6.3 models the whole vision covariance (eq. (33)) as the
        stationary covariance of the Gauss-Markov process (eq. (44)-(45)); the white "0.005" of
        003 table 3 is filter tuning, not part of the vision error.
    transition : "exact": phi_k = exp(-dt_k / T_c), autocorrelation exp(-tau/T_c) for any dt;
        "eq42": phi_k = 1 - dt_k / T_c (003 eq. (42), needs dt < T_c), autocorrelation
        (1 - dt/T_c)^k.
    runs : None -> one realisation (arrays (K, 3)); an int -> that many independent realisations
        (arrays (runs, K, 3)), for Monte Carlo.

    Model
    -----
    With S_k = (f P_k)^(1/2) (symmetric root) and a unit-variance vector Gauss-Markov sequence
    ``x_k = phi_k x_{k-1} + sqrt(1 - phi_k^2) eta_k`` (x_0 ~ N(0, I): started stationary), the
    correlated part is ``zeta_k = S_k x_k``. For constant P this is exactly eq. (41) with the
    driving noise of eqs. (44)-(45), ``Gamma Q Gamma^T = P - Phi P Phi^T = (1 - phi^2) P``; for a
    slowly changing P (003: "quasi-stationary") it keeps Cov(zeta_k) = f P_k at every epoch, even
    when P shrinks (where ``P_k - phi^2 P_{k-1}`` would not be a covariance). The white part is
    ``(1 - f)^(1/2) P_k^(1/2) w_k``. P_c has no component along e, so the errors are tangent to
    the unit sphere and normalising changes them only at second order.
    """
    e = np.asarray(e_true, dtype=float)
    if e.ndim != 2 or e.shape[1] != 3 or not np.all(np.isfinite(e)):
        raise ValueError(f"e_true: expected a finite (K, 3) array, got shape {e.shape}")
    K = e.shape[0]
    t = np.asarray(t_s, dtype=float)
    if t.shape != (K,) or not np.all(np.isfinite(t)):
        raise ValueError(f"t_s: expected a finite ({K},) array of epochs [s], got shape {t.shape}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        raise ValueError(f"t_s: epochs must strictly increase (smallest step {dt.min()} s)")
    Pm = np.asarray(P, dtype=float)
    if Pm.shape == (3, 3):
        Pm = np.broadcast_to(Pm, (K, 3, 3))
    if Pm.shape != (K, 3, 3) or not np.all(np.isfinite(Pm)):
        raise ValueError(f"P: expected a finite (3, 3) or ({K}, 3, 3) covariance, got {Pm.shape}")
    if not T_c > 0:
        raise ValueError(f"T_c = {T_c!r} s; expected > 0 (003 §6.3: 20 s)")
    if not 0.0 <= gm_fraction <= 1.0:
        raise ValueError(f"gm_fraction = {gm_fraction!r}; expected in [0, 1]")
    if transition == "exact":
        phi = np.exp(-dt / T_c)
    elif transition == "eq42":
        if np.any(dt >= T_c):
            raise ValueError(f"transition 'eq42' (003 eq. (42), phi = 1 - dt/T_c) needs dt < T_c = "
                             f"{T_c} s; largest step {dt.max()} s: use transition='exact'")
        phi = 1.0 - dt / T_c
    else:
        raise ValueError(f"transition = {transition!r}; expected 'exact' or 'eq42'")
    if runs is not None and (int(runs) != runs or runs < 1):
        raise ValueError(f"runs = {runs!r}; expected None or a positive integer")
    shape = (K, 3) if runs is None else (K, int(runs), 3)
    a = np.concatenate([[0.0], phi])
    drive = np.concatenate([[1.0], np.sqrt(1.0 - phi * phi)])
    eta = rng.standard_normal(shape)
    ex = (slice(None),) + (None,) * (len(shape) - 1)
    x = linear_recurrence(a, drive[ex] * eta)
    w = rng.standard_normal(shape)
    S = psd_sqrt(Pm)
    if runs is None:
        zeta = math.sqrt(gm_fraction) * np.einsum("kij,kj->ki", S, x)
        white = math.sqrt(1.0 - gm_fraction) * np.einsum("kij,kj->ki", S, w)
    else:
        zeta = math.sqrt(gm_fraction) * np.einsum("kij,krj->rki", S, x)
        white = math.sqrt(1.0 - gm_fraction) * np.einsum("kij,krj->rki", S, w)
    v = e + zeta + white
    e_meas = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return DrawnVectors(e_meas=e_meas, P_report=np.array(Pm), zeta=zeta, white=white)
