"""The wrong-edge test (vision/edge_check.py) on rendered ATEK frames.

Truth: the renderer's geocentric nadir per frame, and for the wrong edge the truth pose's rays of
the fitted pixels (`scenarios.sim.render.ray_ellipsoid`: they hit the ground, i.e. the edge is a
brightness edge on the Earth's surface, not the horizon). Frames of the edge-mismatch study
(`scenarios.study.edge_mismatch`): camera 0 at T+173 s, where the Sun is setting at the tangent
points, and camera 1 at T+72 s, sunlit, whose limb edge has two arcs that disagree.
"""
import dataclasses
import math

import numpy as np
import pytest

from scenarios.study import edge_mismatch as em


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    from scenarios.sim import render
    from vision import mask as vmask
    from vision.config import default_config

    fl, frames = em.atek_frames(48)
    cam = fl.cameras[0].camera
    mask = vmask.from_binary(render.payload_mask(cam, render.DEFAULT_PAYLOAD_MASK))
    return frames, cam, mask, default_config(cam.fx), tmp_path_factory.mktemp("edge_check")


def _run(setup, case, index, config=None):
    """(FrameResult, truth e_c, frame truth) of study frame ``index`` rendered as ``case``."""
    from nav import ephemeris
    from scenarios.flightlog.jpeg import decode_frame
    from vision.frontend import FramePrior, process_frame

    frames, cam, mask, cfg, cache = setup
    t_s, k, r = frames[index]
    jpg, e_true = em._render(case, cam, r, k, cache)
    prior = FramePrior(r.x_e, r.R_ec, sun_c=r.R_ec.T @ ephemeris.sun_direction_e(r.t_ns, r.x_e))
    res = process_frame(decode_frame(jpg), cam, cfg if config is None else config, mask=mask, prior=prior,
                        camera_id=k)
    return res, e_true, r


def _err_and_3sigma(rec, e_true):
    err = math.degrees(math.acos(min(1.0, float(rec.e_c @ e_true))))
    return err, 3.0 * math.degrees(math.sqrt(float(np.linalg.eigvalsh(rec.P_c)[-1])))


def test_wrong_edge_on_the_ground_is_rejected(setup):
    """Edge rendered at 0 km, camera 0 at T+173 s (Sun at -5 deg at the tangent points): without
    the test the fit follows a brightness edge on the ground (truth: every fitted pixel's ray hits
    the ellipsoid) and its nadir is outside its own 3 sigma (4.6 deg against 1.8); with the
    defaults the frame has no Earth vector and says why."""
    from scenarios.sim.render import ray_ellipsoid
    from vision.camera import unproject

    frames, cam, _, cfg, _ = setup
    assert frames[14][1] == 0 and abs(frames[14][0] - 173.0) < 1.0
    off = dataclasses.replace(cfg, earth=dataclasses.replace(
        cfg.earth, edge=dataclasses.replace(cfg.earth.edge, arc_gate=0.0)))
    res, e_true, r = _run(setup, em.Case(0.0), 14, off)
    rec, tr = res.record("earth"), res.targets["earth"]
    assert rec is not None
    hit, _, _ = ray_ellipsoid(np.asarray(r.x_e, float), unproject(cam, tr.points[tr.inlier_mask]) @ np.asarray(r.R_ec).T)
    assert hit.mean() > 0.9, hit.mean()
    err, s3 = _err_and_3sigma(rec, e_true)
    assert err > s3, (err, s3)

    res, _, _ = _run(setup, em.Case(0.0), 14)
    assert res.record("earth") is None
    assert "two arcs" in res.reasons["earth"] and "Sun is" in res.reasons["earth"], res.reasons
    assert res.targets["earth"].second_arc.sigmas > cfg.earth.edge.arc_gate


def test_horizon_at_the_same_time_is_kept(setup):
    """The same frame rendered with the default limb (edge at 45 km): the edge is the limb, the
    frame keeps its vector, inside 3 sigma (0.02 deg off)."""
    res, e_true, _ = _run(setup, em.Case(em.NOMINAL_EDGE_M), 14)
    rec = res.record("earth")
    assert rec is not None, res.reasons
    err, s3 = _err_and_3sigma(rec, e_true)
    assert err <= min(s3, 0.2), (err, s3)


def test_sunlit_disagreeing_arcs_keep_the_vector(setup):
    """Camera 1 at T+72 s, default limb: the threshold edge's two arcs disagree (the limb's
    brightness, hence its edge height, changes along it towards the Sun): with the shadow limit
    raised to 90 deg (every arc counts as in the shadow) the frame is rejected. The fitted arc is
    sunlit (+16 deg), so with the defaults it is not a ground edge: the vector stays, within 0.2
    deg and 3 sigma of the truth."""
    frames, _, _, cfg, _ = setup
    assert frames[1][1] == 1
    every = dataclasses.replace(cfg, earth=dataclasses.replace(
        cfg.earth, edge=dataclasses.replace(cfg.earth.edge, arc_shadow_el_deg=90.0)))
    res, _, _ = _run(setup, em.Case(em.NOMINAL_EDGE_M), 1, every)
    assert res.record("earth") is None and "two arcs" in res.reasons["earth"], res.reasons
    res, e_true, _ = _run(setup, em.Case(em.NOMINAL_EDGE_M), 1)
    rec = res.record("earth")
    assert rec is not None, res.reasons
    err, s3 = _err_and_3sigma(rec, e_true)
    assert err <= min(s3, 0.2), (err, s3)


def _arc_pixels(camera, e, alpha, phi_deg, rng, noise_px):
    """Pixels (noisy, ``noise_px`` per axis) of the cone (e, alpha) at azimuths ``phi_deg``
    about e, their unit rays and Jacobians (`vision.camera.unproject_jacobian`)."""
    from nav._kernels import tangent_basis
    from vision.camera import project, unproject_jacobian

    T = tangent_basis(np.asarray(e, float))
    phi = np.radians(phi_deg)
    rays = (math.cos(alpha) * e[None, :] + math.sin(alpha) * (np.cos(phi)[:, None] * T[:, 0]
                                                              + np.sin(phi)[:, None] * T[:, 1]))
    uv = project(camera, rays) + rng.normal(0.0, noise_px, (phi.size, 2))
    return unproject_jacobian(camera, uv)


@pytest.mark.parametrize("tilt_deg", [0.0, 1.0])
def test_second_arc_on_exact_cones(tilt_deg):
    """Synthetic arcs on the ATEK fisheye from 400 km (spherical Earth, edge at 45 km), white pixel
    noise of 0.3 px (below the model's R = 0.2 px^2): one cone cut in two arcs gives
    m < 3 in every one of 20 draws (m is a 2-dof Mahalanobis distance: P(m > 3) = e^-4.5 = 1 %
    with the model's noise, less with this noise); a second arc from a cone tilted by 1 deg (a
    ground edge's typical 1-8 deg) gives m > 3 in every draw."""
    from vision.camera import atek_camera
    from vision.edge_check import second_arc
    from vision.nadir import nadir_from_horizon
    from vision.oblate import sphere_model

    cam = atek_camera()
    model = sphere_model(400e3, 6371e3, 45e3)
    e = np.array([0.0, 0.62, 0.78])
    e /= np.linalg.norm(e)
    t = math.radians(tilt_deg)
    e2 = np.array([math.sin(t), e[1] * math.cos(t), e[2] * math.cos(t)])
    rng = np.random.default_rng(3)
    ms = []
    for _ in range(20):
        r1, J1 = _arc_pixels(cam, e, model.alpha, np.linspace(-150.0, -110.0, 160), rng, 0.3)
        r2, J2 = _arc_pixels(cam, e2, model.alpha, np.linspace(-105.0, -85.0, 80), rng, 0.3)
        rays, J = np.vstack([r1, r2]), np.concatenate([J1, J2])
        inl = np.arange(rays.shape[0]) < r1.shape[0]
        fit = nadir_from_horizon(rays[inl], model.alpha)
        arc = second_arc(model, rays, J, rays, inl, fit.e_c, model.alpha, 20e3, 3e3, 0.2, 100.0,
                         2.0 * 9e-4, 0.15, 4e-6)
        assert arc is not None
        ms.append(arc.sigmas)
    if tilt_deg == 0.0:
        assert max(ms) < 3.0, ms
    else:
        assert min(ms) > 3.0, ms
