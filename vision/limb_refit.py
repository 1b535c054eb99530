"""Earth refits with the limb profile (`vision.limb`): the fraction-of-peak edge with the Sun-path
height shifts, and for clipped limb maxima the flank heights or the threshold edge calibrated on
the usable profiles (`vision.config.LimbOptions`)."""
from __future__ import annotations

import math

import numpy as np

from vision.config import TargetConfig
from vision.fitting import fit_cone, median, reselect_inliers, subsample
from vision.limb import (LimbEdgeConfig, flank_heights, fraction_height_shift, limb_edge_points, phase_slope,
                         profile_height_shift, flank_rise_height, resolved_sun_sine, tangent_height_sun,
                         turn_towards)
from vision.oblate import LimbModel

__all__ = ["tilt_corrected_attitude", "limb_refit"]


def tilt_corrected_attitude(R_ec: np.ndarray, e_c: np.ndarray, x_e: np.ndarray) -> np.ndarray:
    """The prior attitude camera -> e turned by the smallest rotation that maps the measured nadir
    ``e_c`` (camera frame) onto the geocentric nadir -x_e/|x_e| (003 eq. (39)).

    The limb's Sun-elevation test and height model (`vision.limb`) need the tangent points in e;
    with a free-inertial attitude prior a few degrees off, the Sun elevation there is off by as
    much, which the steep twilight part of the height model turns into kilometres (a 2 deg
    elevation error near the terminator: ~3 km, ~0.1 deg of nadir). The frame's own horizon fixes
    the two tilt angles of that error to the accuracy of the first fit (~0.1-0.5 deg); the rotation
    about the nadir is left as the prior has it (it moves the tangent points along the limb, which
    changes their Sun elevation by about sin(angle nadir to limb) times the error).
    """
    R = np.asarray(R_ec, dtype=float)
    a0, a1, a2 = (R @ np.asarray(e_c, dtype=float)).tolist()
    b0, b1, b2 = (-np.asarray(x_e, dtype=float)).tolist()
    na, nb = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2), math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    a0, a1, a2, b0, b1, b2 = a0 / na, a1 / na, a2 / na, b0 / nb, b1 / nb, b2 / nb
    # Rodrigues' rotation a -> b about k = a x b / |a x b| (plain floats: numpy's per-call
    # overhead dominates on 3-vectors)
    k0, k1, k2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    s = math.sqrt(k0 * k0 + k1 * k1 + k2 * k2)
    c = a0 * b0 + a1 * b1 + a2 * b2
    if s < 1e-15:
        return R
    k0, k1, k2 = k0 / s, k1 / s, k2 / s
    d = 1.0 - c                        # I + s K + (1 - c) K^2 = c I + s K + (1 - c) k k^T
    rot = np.array([[c + d * k0 * k0, d * k0 * k1 - s * k2, d * k0 * k2 + s * k1],
                    [d * k0 * k1 + s * k2, c + d * k1 * k1, d * k1 * k2 - s * k0],
                    [d * k0 * k2 - s * k1, d * k1 * k2 + s * k0, c + d * k2 * k2]])
    return rot @ R


#: angle [rad] a limb ray is turned towards the body to find the Sun elevation's change down its
#: profile (~2 km of tangent height from a few hundred km up: the change is linear over it)
_PROFILE_STEP_RAD = 1e-3
#: the profile model runs on every this-many-th point along the edge, its correction to eq. (5)
#: interpolated between them (it varies smoothly along the limb; eq. (5) stays per point)
_PROFILE_STRIDE = 8


def _profile_correction(rays_e, h_t, mu, nadir_e, x_e, sun_e, dh_eq5, tc: TargetConfig, min_drop):
    """`vision.limb.profile_height_shift` minus eq. (5) (``dh_eq5``) for limb points in edge order:
    the Sun elevation's change down each profile, dmu/dh from the tangent point of the ray turned
    towards the body by `_PROFILE_STEP_RAD`; computed on every `_PROFILE_STRIDE`-th point and the
    last, linearly interpolated along the edge between them (0 where no profile model exists:
    a profile in the Earth's shadow)."""
    n = mu.size
    sub = np.arange(0, n, _PROFILE_STRIDE)
    if sub[-1] != n - 1:
        sub = np.append(sub, n - 1)
    turned = turn_towards(rays_e[sub], nadir_e, _PROFILE_STEP_RAD)
    h_b, mu_b = tangent_height_sun(turned, x_e, sun_e)
    corr = profile_height_shift(mu[sub], (mu_b - mu[sub]) / (h_b - h_t[sub]), tc.limb.fraction,
                                tc.limb.scale_height_m, tc.limb.height_m, min_drop) - dh_eq5[sub]
    fin = np.isfinite(corr)
    if not fin.any():
        return np.zeros(n)
    return np.interp(np.arange(n), sub[fin], corr[fin])


def limb_refit(image, camera, tc: TargetConfig, limb, uv, rays_c, pa, e_c, J=None, info: dict | None = None):
    """Fraction-of-peak limb edge (`vision.limb`) on the winner's inlier pixels (uv, camera rays,
    pixel angles pa, Jacobians J) and the refit with its height, from the threshold edge's nadir
    e_c (camera frame); ``limb`` = (limb model at ``limb.height_m``, R_ec, x_e, Sun direction in
    e). Returns (model, fit, uv, rays, J, inliers, sigma_d, used fraction, mean shift [m], path,
    threshold-edge thickness [m]) (path "limb", "flank" or "calibrated", `TargetResult.limb_path`),
    or None when too few limb points are usable and neither fallback applies, or when the usable
    profiles are not a limb's (`_not_a_limb`) (the caller keeps the threshold edge). ``info``
    (optional dict) receives ``"width_ratio"``, the median flank-width ratio of the usable profiles
    (`_flank_widths`; NaN when not measured).

    With ``limb.sun_path`` each usable point's crossing height is predicted from the Sun
    elevation at its tangent point (`vision.limb.fraction_height_shift`, eq. (5) of `vision.limb`)
    and its ray is turned towards the body by ``alpha(d + dh) - alpha(d)``
    (`LimbModel.cone_angle_change`), so
    that all points sit at the overhead-Sun height ``limb.height_m`` of the fit (one cone angle);
    the covariance term is then ``sigma_d^2 = limb.height_sigma_m^2 + (limb.sun_path_sigma *
    mean dh)^2`` (the model's measured error grows with the shift, docs/vision.md)."""
    model_l, R_ec, x_e, sun_e = limb
    lc = LimbEdgeConfig(fraction=tc.limb.fraction, channel=tc.limb.channel)
    R_t = tilt_corrected_attitude(R_ec, e_c, x_e)
    slope = phase_slope(rays_c, e_c, pa, R_t.T @ sun_e, tc.limb.aerosol_weight, tc.limb.aerosol_g)
    uvn, rn, ok, Jn, rise = limb_edge_points(image, camera, uv, rays_c, e_c, pa, lc, jacobian=True, phase_slope=slope,
                                             rise_level=_RISE_LEVEL)
    el, twilight, dh, ratio = _usable(ok, rn, rise * pa, model_l, R_t, e_c, x_e, sun_e, tc, lc)
    dh_sun = dh
    if _not_a_limb(ratio, tc, info):
        return None
    n_ok = int(ok.sum())
    m = uv.shape[0]
    used = n_ok / max(m, 1)
    calibrate = (tc.limb.calibrate.below > 0 and used < tc.limb.calibrate.below
                 and n_ok >= tc.limb.calibrate.min_points and J is not None)
    if n_ok < max(20, tc.limb.min_used * m):
        # too few usable profiles (a clipped limb maximum): heights fitted on the flanks, else
        # the threshold edge calibrated on the usable ones, else the threshold edge itself
        if tc.limb.flank.profiles > 0 and J is not None:
            fr = _flank_refit(image, camera, tc, lc, model_l, uv, rays_c, J, pa, e_c, R_t, x_e, sun_e, used)
            if fr is not None:
                # again with the attitude tilted onto this better nadir: the Sun elevations at
                # the tangent points shape the profiles (twilight), and the first fit's nadir
                # (threshold edge) is off by tenths of a degree
                R_t2 = tilt_corrected_attitude(R_ec, model_l.to_camera(fr[1].e_c), x_e)
                fr = _flank_refit(image, camera, tc, lc, model_l, uv, rays_c, J, pa, e_c, R_t2, x_e, sun_e, used) or fr
                return fr
        if not calibrate:
            return None
    if not (tc.limb.sun_path and n_ok):
        dh = np.zeros(n_ok)
    twi = 0.0
    if tc.limb.sun_path and n_ok and len(tc.limb.twilight_el_deg):
        kn = np.radians(np.asarray(tc.limb.twilight_el_deg, dtype=float))
        dh = dh + np.interp(el, kn, np.asarray(tc.limb.twilight_dh_m, dtype=float), left=0.0, right=0.0)
        twi = float(np.mean(el < kn[-1]))
    if calibrate:
        return _calibrated_threshold_refit(tc, model_l, uv, rays_c, J, pa, e_c, rn[ok], ok, dh, used)
    J2 = Jn[ok]
    thr = tc.limb.refit_threshold_px * pa[ok]
    rays2 = turn_towards(rn[ok], e_c, model_l.cone_angle_change(dh))
    r = _refit_turned(model_l, rays2, e_c, thr)
    if r is not None and twilight:
        # twilight: the shifts again with the attitude tilted onto this first limb fit's nadir (a
        # Sun elevation a tenth of a degree off moves the predicted heights by ~0.15 km there, and
        # the threshold edge's nadir that tilted R_t is off by tenths of a degree)
        R_t2 = tilt_corrected_attitude(R_ec, model_l.to_camera(r[0].e_c), x_e)
        dh2 = dh + (_sun_path_shifts(rn[ok], R_t2, e_c, x_e, sun_e, tc, lc, keep_all=True)[1] - dh_sun)
        rays3 = turn_towards(rn[ok], e_c, model_l.cone_angle_change(dh2))
        r2 = _refit_turned(model_l, rays3, e_c, thr)
        if r2 is not None:
            r, rays2, dh = r2, rays3, dh2
    if r is None:
        return None
    fit, inl = r
    shift = float(np.mean(dh[inl]))
    sigma_d = math.sqrt(tc.limb.height_sigma_m**2 + (tc.limb.sun_path_sigma * shift)**2
                        + (twi * tc.limb.twilight_sigma_m)**2)
    return model_l, fit, uvn[ok], rays2, J2, inl, sigma_d, used, shift, "limb", math.nan


#: the upper level of the flank width test (`_flank_width_ok`): a fraction of the peak above the
#: crossing's, below the flat top (which noise and JPEG steps make a poor marker)
_RISE_LEVEL = 0.8


def _usable(ok, rn, rise_rad, model_l: LimbModel, R_t, e_c, x_e, sun_e, tc: TargetConfig, lc: LimbEdgeConfig):
    """The limb profiles that are usable (``ok`` (m,) updated in place): by their flank width
    (`_flank_widths`) and the Sun's elevation at their tangent points (`_sun_path_shifts`).
    Returns (el, twilight, dh, ratio) of the usable ones (None, False, None, None when there are
    none; ratio None without the width test)."""
    ratio = None
    if ok.any() and tc.limb.flank_width_max > 0:
        keep, ratio = _flank_widths(rn[ok], rise_rad[ok], model_l, R_t, x_e, sun_e, tc, lc.min_drop)
        ok[ok] = keep
        ratio = ratio[keep]
    if not ok.any():
        return None, False, None, ratio
    keep, dh, el, twilight = _sun_path_shifts(rn[ok], R_t, e_c, x_e, sun_e, tc, lc)
    ok[ok] = keep
    return el, twilight, dh, (ratio[keep] if ratio is not None else None)


def _flank_widths(rays_c, rise_rad, model_l: LimbModel, R_t, x_e, sun_e, tc: TargetConfig, min_drop: float):
    """(usable, ratio) of limb profiles by their flank width: ``ratio`` is the tangent-height drop
    from each crossing (rays_c, camera frame) down to the `_RISE_LEVEL`-of-peak level
    (``rise_rad`` [rad] down the profile, `LimbModel.height_change`) over the width eq. (4) gives
    at the Sun elevation of its tangent point (`vision.limb.flank_rise_height`, attitude R_t);
    ``usable``: at most ``limb.flank_width_max``. A profile whose maximum lies on the Earth's disc
    (a cloud brighter than the limb's flat top under a high Sun) rises past the limb's top to it:
    its flank is wider, and its crossing lies kilometres low. Tested per profile where the Sun is
    high enough for that (`vision.limb.resolved_sun_sine`: the limb's own drop above the surface
    is then below the detector's ``min_drop``, so the drop it finds lies on the disc); lower, the
    limb's own maximum is followed by its own drop, and the profiles are judged together
    (`_not_a_limb`)."""
    _, mu = tangent_height_sun(rays_c @ R_t.T, x_e, sun_e)
    pred = flank_rise_height(mu, tc.limb.fraction, _RISE_LEVEL, tc.limb.scale_height_m)
    mu_res = resolved_sun_sine(tc.limb.fraction, tc.limb.scale_height_m, tc.limb.height_m, min_drop)
    ratio = -model_l.height_change(-rise_rad) / pred
    return (mu <= mu_res) | (ratio <= tc.limb.flank_width_max), ratio


def _not_a_limb(ratio, tc: TargetConfig, info: dict | None) -> bool:
    """True when the median flank-width ratio (`_flank_widths`) of the usable profiles exceeds
    ``limb.edge_width_max``: eq. (4) makes a limb's flank ``H ln(u_0.8 / u_0.5)`` high whatever the
    exposure, phase function or tau, the Earth's shadow under a set Sun only cuts the profile from
    below (a narrower flank), and a thinner atmosphere narrows it by its scale height; a median
    flank 1.3 times eq. (4)'s is a scale height of 10.4 km, which the air below 50 km does not
    have. Such profiles follow a brightness gradient on the ground (the dim twilight ground inside
    a horizon whose limb is too faint to peak), and their crossings lie on the Earth's disc.
    Judged on at least 20 profiles; the ratio goes to ``info["width_ratio"]``."""
    if ratio is None or ratio.size == 0:
        return False
    width = median(ratio)
    if info is not None:
        info["width_ratio"] = width
    return tc.limb.edge_width_max > 0 and ratio.size >= 20 and width > tc.limb.edge_width_max


def _sun_path_shifts(rays_c, R_t, e_c, x_e, sun_e, tc: TargetConfig, lc: LimbEdgeConfig, keep_all: bool = False):
    """Crossing-height shifts of limb rays (camera frame) with the attitude R_t (camera -> e):
    ``(keep, dh, el, twilight)``: keep the points with the Sun above ``limb.min_sun_elev_deg`` at
    their tangent points (all with ``keep_all``), dh [m] their shifts (eq. (5) of `vision.limb`,
    with the Sun elevation's change down the profile below ``limb.profile_below_deg``; zeros
    without ``limb.sun_path``), el [rad] their Sun elevations, twilight: some of them that low."""
    rays_e = rays_c @ R_t.T
    h_t, mu = tangent_height_sun(rays_e, x_e, sun_e)
    keep = np.ones(mu.size, bool) if keep_all else mu >= math.sin(math.radians(tc.limb.min_sun_elev_deg))
    dh = np.zeros(mu.size)
    low = keep & (mu < math.sin(math.radians(tc.limb.profile_below_deg)))
    if tc.limb.sun_path:
        dh = fraction_height_shift(mu, tc.limb.fraction, tc.limb.scale_height_m)
        if low.any():
            dh[low] += _profile_correction(rays_e[low], h_t[low], mu[low], R_t @ e_c, x_e, sun_e, dh[low],
                                           tc, lc.min_drop)
    return keep, dh[keep], np.arcsin(mu[keep]), bool(tc.limb.sun_path and low.any())


def _calibrated_threshold_refit(tc: TargetConfig, model_l: LimbModel, uv, rays_c, J, pa, e_c, rays_limb,
                                ok, dh, used):
    """Threshold edge calibrated with the usable limb profiles of the same frame
    (``LimbOptions.calibrate.below``): ``d_i`` = the height whose cone is ``a_i`` wider than
    the cone of ``h_i`` (`LimbModel.height_change`) at the usable points
    (h_i = ``limb.height_m`` + Sun-path shift: the known height of the fraction-of-peak crossing;
    a_i the angle from it out to the threshold pixel), ``d_thr = median(d_i)``, and every
    threshold ray turned towards the body by ``alpha(d_thr) - alpha(limb.height_m)`` so that the
    whole arc fits the cone of ``limb.height_m`` (`LimbModel.cone_angle_change`, as for the Sun-path
    shift). None when the refit keeps fewer than 20 inliers."""
    a = np.arccos(np.clip(np.sum(rays_c[ok] * rays_limb, axis=1), -1.0, 1.0))
    # sign: positive when the limb crossing lies towards the body from the threshold pixel
    a = np.where(rays_limb @ e_c >= rays_c[ok] @ e_c, a, -a)
    d_i = tc.limb.height_m + model_l.height_change(model_l.cone_angle_change(dh) + a)
    d_thr = median(d_i)
    mad = 1.4826 * median(np.abs(d_i - d_thr))
    rays2 = turn_towards(rays_c, e_c, model_l.cone_angle_change(d_thr - tc.limb.height_m))
    r = _refit_turned(model_l, rays2, e_c, tc.limb.refit_threshold_px * pa)
    if r is None:
        return None
    sigma_d = math.sqrt(tc.limb.calibrate.sigma_m**2 + mad**2 / d_i.size)
    return (model_l, r[0], uv, rays2, J, r[1], sigma_d, used, float(np.mean(dh)) if dh.size else 0.0,
            "calibrated", d_thr)


def _refit_turned(model_l: LimbModel, rays2, e_c, thr):
    """The cone of ``model_l`` (d = ``limb.height_m``) fitted to rays already turned to that
    height, from e_c, with the inliers re-selected twice (``thr`` [rad] per ray); (fit, inliers)
    or None below 20 inliers."""
    H2 = model_l.to_fit(rays2)
    e0 = model_l.M @ e_c
    fit = fit_cone(H2, model_l.alpha, e0 / np.linalg.norm(e0))
    fit, inl, ok = reselect_inliers(H2, fit, np.ones(rays2.shape[0], bool), thr,
                                     lambda Hi, f: fit_cone(Hi, model_l.alpha, f.e_c), 2, 20)
    return (fit, inl) if ok else None



def _flank_refit(image, camera, tc: TargetConfig, lc: LimbEdgeConfig, model_l: LimbModel, uv, rays_c, J, pa,
                 e_c, R_t, x_e, sun_e, used):
    """Threshold edge with each pixel's height fitted on the unsaturated flank of its limb profile
    (`vision.limb.flank_heights`; the limb maximum clipped by the exposure): on
    ``limb.flank.profiles`` profiles spread along the edge, the heights more than 3 robust
    sigmas (at least 1 km) from their median dropped, the rest interpolated along the edge; each
    threshold ray turned towards the body by ``alpha(h_i) - alpha(limb.height_m)`` and the cone of
    ``limb.height_m`` fitted. None with fewer than ``limb.flank.min_profiles`` fitted profiles or
    20 inliers. Covariance term ``limb.flank.sigma_m`` with the heights' spread over sqrt(n)."""
    m = uv.shape[0]
    idx = subsample(m, tc.limb.flank.profiles)
    h = flank_heights(image, camera, uv[idx], rays_c[idx], e_c, pa[idx], R_t, x_e, sun_e, lc,
                      height_m=tc.limb.height_m, scale_height_m=tc.limb.scale_height_m,
                      aerosol_weight=tc.limb.aerosol_weight, aerosol_g=tc.limb.aerosol_g)
    fin = np.isfinite(h)
    if fin.sum() < tc.limb.flank.min_profiles:
        return None
    med = median(h[fin])
    mad = 1.4826 * median(np.abs(h[fin] - med))
    fin &= np.abs(h - med) <= max(3.0 * mad, 1000.0)
    if fin.sum() < tc.limb.flank.min_profiles:
        return None
    h_all = np.interp(np.arange(m), idx[fin], h[fin])
    rays2 = turn_towards(rays_c, e_c, model_l.cone_angle_change(h_all - tc.limb.height_m))
    r = _refit_turned(model_l, rays2, e_c, tc.limb.refit_threshold_px * pa)
    if r is None:
        return None
    sigma_d = math.sqrt(tc.limb.flank.sigma_m**2 + mad**2 / fin.sum())
    return model_l, r[0], uv, rays2, J, r[1], sigma_d, used, 0.0, "flank", float(np.mean(h[fin]))
