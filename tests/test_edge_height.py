"""Edge height fitted with the nadir (vision/edge_height.py) and the renderer's limb shift.

Truth: exact limb rays of the WGS-84 ellipsoid inflated by a known edge height (tests.poses), seen
by the ATEK fisheye; the fixed-height fit's tilt term (`vision.fitting.alpha_sensitivity`) as the
closed form the prior-dominated case must reduce to; a Monte Carlo of the correlated pixel noise
of 003 eqs. (34)-(35) for the covariance.
"""
import math

import numpy as np
import pytest

from vision.camera import atek_camera, project, unproject_jacobian
from vision.covariance import direction_covariance
from vision.edge_height import fit_edge_height, fit_edge_reselect
from vision.fitting import alpha_sensitivity
from vision.nadir import nadir_from_horizon
from vision.oblate import ellipsoid_model

from tests.poses import ellipsoid_limb_rays, pose

CAM = atek_camera()
D0 = 45e3


def _arc(h, down, d_true, span=None, n=4000):
    """(R, x, pixels, rays, J) of the limb at edge height d_true inside the image; ``span``: keep
    only this many pixels around the middle of the visible arc (a short arc)."""
    R, x = pose(30.0, down, h=h)
    rays = ellipsoid_limb_rays(x, R, n, d_true)
    with np.errstate(invalid="ignore"):
        uv = project(CAM, rays)
    ok = (np.all(np.isfinite(uv), 1) & (uv[:, 0] >= 0) & (uv[:, 0] <= CAM.width - 1) & (uv[:, 1] >= 0)
          & (uv[:, 1] <= CAM.height - 1) & (rays[:, 2] > 0))
    uv = uv[ok]
    uv = uv[np.argsort(uv[:, 0])]
    if span is not None:
        mid = uv.shape[0] // 2
        uv = uv[mid - span // 2: mid + span // 2]
    uv = uv[:: max(1, uv.shape[0] // 512)]
    rays_c, J = unproject_jacobian(CAM, uv)
    return R, x, uv, rays_c, J


def _deg(a, b):
    return math.degrees(math.acos(min(1.0, float(a @ b))))


@pytest.mark.parametrize("d_true", [0.0, 10e3, 60e3])
def test_long_arc_recovers_the_edge_height(d_true):
    """A long exact arc at edge height d_true, the model built at 45 km: the fixed-height fit is
    0.4-2 deg off; the joint fit recovers the height within 0.5 km and the nadir within 0.02 deg
    (the fit frame's z scaling (a + d)/(b + d) is that of 45 km: a residual of order f * dd / R),
    and the arc constrains the height (posterior sigma a few km, far below the 20 km prior)."""
    R, x, uv, rays, J = _arc(200e3, 20.0, d_true)
    m = ellipsoid_model(x, R, D0)
    H = m.to_fit(rays)
    f0 = nadir_from_horizon(H, m.alpha)
    e_true = R.T @ (-x / np.linalg.norm(x))
    assert _deg(m.to_camera(f0.e_c), e_true) > 0.3
    ef = fit_edge_height(m, D0, H, J, f0.e_c, D0, 20e3, 0.2, 300.0)
    assert abs(ef.height_m - d_true) < 500.0, ef.height_m
    assert _deg(m.to_camera(ef.e_fit), e_true) < 0.02
    assert ef.from_arc and ef.sigma_m < 3e3 and ef.sigma_m <= ef.data_sigma_m
    assert np.allclose(ef.P_c, ef.P_c.T) and np.all(np.linalg.eigvalsh(ef.P_c) > -1e-20)


def test_short_arc_takes_the_prior_sigma_into_the_nadir():
    """A short arc (100 px) hardly constrains the height: the posterior sigma stays within 10 % of
    the prior's, and the direction covariance equals the fixed-height fit's pixel term plus
    sigma_post^2 g g^T with g = de/dd (the tilt of the constrained fit, 003 §4) to 10 % (the
    remaining data information on the height and the linearisation)."""
    R, x, uv, rays, J = _arc(200e3, 20.0, D0, span=100)
    m = ellipsoid_model(x, R, D0)
    H = m.to_fit(rays)
    f0 = nadir_from_horizon(H, m.alpha)
    ef = fit_edge_height(m, D0, H, J, f0.e_c, D0, 20e3, 0.2, 300.0)
    assert not ef.from_arc
    assert 0.9 * 20e3 < ef.sigma_m <= 20e3
    e_c = m.to_camera(f0.e_c)
    P_pix = direction_covariance(rays, J, e_c, 0.2, 300.0, method="constrained").P_c
    g_fit = alpha_sensitivity(H, f0.e_c, f0.alpha) * m.alpha_rate
    g = (m.to_camera(f0.e_c + 1e-6 * g_fit) - e_c) / 1e-6
    P_ref = P_pix + ef.sigma_m**2 * np.outer(g, g)
    lam, lam_ref = np.linalg.eigvalsh(ef.P_c)[-1], np.linalg.eigvalsh(P_ref)[-1]
    assert abs(lam / lam_ref - 1.0) < 0.1, (lam, lam_ref)
    # the height and the tilt are correlated through g: cov(e, h) ~ g sigma_h^2
    assert float(ef.cov_c @ g) > 0.9 * ef.sigma_m**2 * float(g @ g)


def _ar1(rng, m, rho, sd):
    """(m,) first-order Gauss-Markov sequence along the edge, stationary sd (003 eqs. (34)-(35))."""
    w = rng.standard_normal(m) * sd * math.sqrt(1.0 - rho * rho)
    out = np.empty(m)
    out[0] = rng.standard_normal() * sd
    for j in range(1, m):
        out[j] = rho * out[j - 1] + w[j]
    return out


def test_covariance_matches_a_monte_carlo_of_correlated_pixel_noise():
    """Pixels perturbed by AR(1) noise (R = 1 px^2, L = 60 px), 300 draws: the scatter of the
    estimated height and of the nadir agree with the reported sigmas within 20 % (the Monte Carlo
    standard error of a variance from 300 correlated-free draws is ~8 %; the rest is the
    linearisation), for a long arc at a height the prior (45 +- 20 km) does not hold."""
    rng = np.random.default_rng(3)
    R, x, uv, rays, J = _arc(200e3, 20.0, 10e3)
    m = ellipsoid_model(x, R, D0)
    m_pts = uv.shape[0]
    L = 60.0
    rho = 1.0 - 1.0 / L
    hs, es = [], []
    ref = None
    for _ in range(300):
        duv = np.column_stack([_ar1(rng, m_pts, rho, 1.0), _ar1(rng, m_pts, rho, 1.0)])
        r2, J2 = unproject_jacobian(CAM, uv + duv)
        H = m.to_fit(r2)
        f0 = nadir_from_horizon(H, m.alpha)
        ef = fit_edge_height(m, D0, H, J2, f0.e_c, D0, 20e3, 1.0, L)
        ref = ef if ref is None else ref
        hs.append(ef.height_m)
        es.append(m.to_camera(ef.e_fit))
    hs, es = np.array(hs), np.array(es)
    assert abs(np.std(hs) / ref.sigma_m - 1.0) < 0.2, (np.std(hs), ref.sigma_m)
    d = es - es.mean(0)
    P_mc = d.T @ d / (len(es) - 1)
    r = np.trace(P_mc) / np.trace(ref.P_c)
    assert abs(r - 1.0) < 0.2, r


def test_reselection_takes_back_the_whole_arc():
    """The fixed-height cone (45 km) with a 2 px-like threshold keeps only part of an arc whose
    edge sits at 0 km; re-selecting on the joint fit's cone takes back every ray."""
    R, x, uv, rays, J = _arc(200e3, 20.0, 0.0)
    m = ellipsoid_model(x, R, D0)
    H = m.to_fit(rays)
    f0 = nadir_from_horizon(H, m.alpha)
    thr = 2.0 / CAM.fx
    from vision.nadir import within_cone
    inl = within_cone(H, f0.e_c, f0.alpha, thr)
    assert inl.mean() < 0.6
    ef, inl2 = fit_edge_reselect(m, D0, H, J, inl, f0.e_c, D0, 20e3, 0.2, 300.0, thr, 20)
    assert inl2.all()
    assert abs(ef.height_m) < 500.0


def test_render_limb_shift_moves_the_profile():
    """`limb_profile` with limb_shift_m = s at height h + s equals the default profile at h (the air
    lifted by s: the identity the renderer's kernel implements for the limb rays)."""
    from scenarios.sim import render

    h = np.linspace(0.0, 80e3, 81)
    for s in (-45e3, 15e3):
        a = render.limb_profile(h + s, render.RenderOptions(limb_shift_m=s), sun_elevation_deg=20.0)
        b = render.limb_profile(h, render.RenderOptions(), sun_elevation_deg=20.0)
        assert np.allclose(a, b, rtol=1e-12, atol=0.0)
    with pytest.raises(ValueError, match="limb_shift_m"):
        render.RenderOptions(limb_shift_m=1e6)


def test_render_limb_shift_moves_the_rendered_edge():
    """Rendered frames (fixed exposure, no noise, no clouds): the space pixels whose brightness is
    near a threshold sit at tangent heights (truth geometry) higher by the shift, within 1.5 km
    (pixel footprint ~2 km at the limb from 200 km, and the illumination varies along the limb)."""
    from nav import ephemeris, timescales
    from scenarios.sim import render
    from vision.camera import pixel_rays

    t = timescales.parse_utc("2019-06-13T02:24:40Z")
    R, x = pose(30.0, 20.0, h=200e3)
    rays_e = pixel_rays(CAM).reshape(-1, 3) @ R.T
    _, _, h_t = render.ray_ellipsoid(x, rays_e)
    meds = []
    for s in (0.0, -20e3):
        o = render.RenderOptions(limb_shift_m=s, exposure=20.0, noise=False, clouds=False, sun_disc=False,
                                 sun_bloom=False, sun_glare=False, lens_flare=False, payload_mask=None,
                                 motion_blur=False, vignetting=0.0)
        fr = render.render_frame(CAM, R, x, ephemeris.sun_position_e(t), None, options=o)
        v = fr.image.reshape(-1, 3).astype(float).mean(1)
        sel = (np.abs(v - 60.0) < 6.0) & (h_t > 1e3)
        meds.append(float(np.median(h_t[sel])))
    assert abs((meds[1] - meds[0]) - (-20e3)) < 1.5e3, meds


def test_narrow_pinhole_orbit_keeps_the_error_inside_three_sigma():
    """A 25 deg pinhole camera at 500 km looking at the horizon, the edge at 5 km (real orbital
    photographs: 0-10 km), the defaults' prior 45 +- 20 km: the fixed-height fit at 45 km is off by
    several tenths of a degree, far outside its pixel-noise covariance; the joint fit's nadir error
    is inside 3 sigma of its marginal covariance (the short arc leaves most of the prior's sigma,
    which the covariance carries)."""
    from vision.pinhole import PinholeCamera
    fx = 960.0 / math.tan(math.radians(12.5))
    cam = PinholeCamera(width=1920, height=1080, fx=fx, fy=fx, cx=959.5, cy=539.5)
    R, x = pose(30.0, 21.0, h=500e3)
    rays = ellipsoid_limb_rays(x, R, 20000, 5e3)
    with np.errstate(invalid="ignore"):
        uv = project(cam, rays)
    ok = (np.all(np.isfinite(uv), 1) & (uv[:, 0] >= 0) & (uv[:, 0] <= cam.width - 1) & (uv[:, 1] >= 0)
          & (uv[:, 1] <= cam.height - 1) & (rays[:, 2] > 0))
    uv = uv[ok]
    uv = uv[np.argsort(uv[:, 0])][:: max(1, ok.sum() // 512)]
    assert uv.shape[0] > 100
    r_c, J = unproject_jacobian(cam, uv)
    m = ellipsoid_model(x, R, D0)
    H = m.to_fit(r_c)
    f0 = nadir_from_horizon(H, m.alpha)
    e_true = R.T @ (-x / np.linalg.norm(x))
    e0 = m.to_camera(f0.e_c)
    P0 = direction_covariance(r_c, J, e0, 0.2, 300.0, method="constrained").P_c
    err0 = _deg(e0, e_true)
    assert err0 > 0.3 and err0 > 3 * math.degrees(math.sqrt(np.linalg.eigvalsh(P0)[-1])), err0
    ef = fit_edge_height(m, D0, H, J, f0.e_c, D0, 20e3, 0.2, 300.0, along_sigma_m=3e3, along_L=600.0)
    err = _deg(m.to_camera(ef.e_fit), e_true)
    assert err <= 3 * math.degrees(math.sqrt(np.linalg.eigvalsh(ef.P_c)[-1])), (err, ef.P_c)
    # the 25 deg arc hardly separates the height from the tilt: the prior's sigma is what is left
    assert not ef.from_arc and ef.sigma_m > 0.8 * 20e3, ef.sigma_m
    print(f"pinhole: fixed {err0:.3f} deg, joint {err:.3f} deg, 3 sigma "
          f"{3 * math.degrees(math.sqrt(np.linalg.eigvalsh(ef.P_c)[-1])):.3f} deg, h {ef.height_m:.0f} m")
