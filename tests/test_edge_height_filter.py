"""The filter's Earth edge height state h_e (nav/error_state.py, nav/updates.py CameraVectors) and the
truth vectors fitted at an assumed edge height (scenarios/sim/truth_vectors.py)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from nav.error_state import build_layout
from nav.filter_state import FilterState
from nav.navigator import ImuData, VectorData, run
from nav.tuning import StateGroupTuning, Tuning, tuning_from_toml

TRUE_EDGE_M, PRIOR_EDGE_M = 10e3, 45e3   #: the flight's edge height and the one its vectors assume


def test_sensitivity_is_the_refit():
    """g_c of the truth vectors (closed form: -de/dalpha dalpha/dh, dalpha/dh = 1/(d cos alpha)) against
    the constrained fit itself (vision.nadir.nadir_from_horizon) at a height 1 km off, on a partial
    arc (40 deg below the axis: 188 px) and long ones: the refit's nadir shift is g_c times -1 km to
    1 % (the second-order term of a 1 km change is ~1e-4 relative; the rest is the linearisation
    about e_true instead of the fitted direction)."""
    from scenarios.sim.truth_vectors import _edge_sensitivity
    from vision.camera import atek_camera, unproject_jacobian
    from vision.error_model import predict_vision
    from vision.nadir import nadir_from_horizon
    cam, d, r = atek_camera(), 6601e3, 6371e3
    for ang in (40.0, 60.0, 75.0):
        e = np.array([0.0, math.sin(math.radians(ang)), math.cos(math.radians(ang))])
        a_true, a_ref = math.asin((r + TRUE_EDGE_M) / d), math.asin((r + TRUE_EDGE_M + 1e3) / d)
        px = predict_vision(cam, e, a_true).pixels
        rays, _ = unproject_jacobian(cam, px)
        shift = nadir_from_horizon(rays, a_ref).e_c - e
        g = _edge_sensitivity(cam, px, e, a_true, d)
        np.testing.assert_allclose(g * -1e3, shift, rtol=0, atol=0.01 * np.linalg.norm(shift))


def test_tuning_table():
    """[states.edge_height]: mode, sigma_km and correlation_time_s; an unknown key names itself."""
    t = tuning_from_toml('[states.edge_height]\nmode = "E"\nsigma_km = 30\ncorrelation_time_s = 600\n')
    assert t.edge_height == StateGroupTuning("E", 30e3) and t.edge_height_tau_s == 600.0
    assert Tuning().edge_height.mode == "off" and Tuning().edge_height_tau_s == 0.0
    with pytest.raises(ValueError, match="edge_height.*height_km"):
        tuning_from_toml('[states.edge_height]\nheight_km = 3\n')
    lay = build_layout(t, 2)
    assert [g.name for g in lay.groups][-2:] == ["h_e_0", "h_e_1"] and lay["h_e_1"].stop == lay.n


def test_gauss_markov_propagation():
    """A Gauss-Markov h_e (tau 300 s) over one 0.1 s block: P equals Phi P0 Phi^T + q dt + (1 - phi^2)
    sigma^2 on h_e with Phi from the block's recorded transition, whose h_e entry is exp(-dt/tau)
    (closed form); the estimate relaxes towards its start as m0 + phi (m - m0)."""
    tun = Tuning().with_(edge_height=StateGroupTuning("E", 20e3), edge_height_tau_s=300.0, vector_gm_mode="off")
    lay = build_layout(tun, 1)
    n = lay.n
    rng = np.random.default_rng(1)
    B = rng.normal(size=(n, n)) * 1e-2
    P0 = B @ B.T + np.diag(np.diag(lay.initial_covariance()))
    x = np.array([6.6e6, 0.0, 0.0])
    st = FilterState(lay, tun, x, [0.0, 7.5e3, 0.0], [0.0, 0.0, 0.0, 1.0], P0.copy(), np.eye(3)[None], np.zeros(1),
                     [PRIOR_EDGE_M])
    st.edge_hat[0] = 40e3
    ts = np.array([0.0, 0.1])
    fw = np.zeros((2, 2, 3))
    fw[:, 1, 2] = 0.01
    A, d = np.empty((9, n)), np.empty(n)
    st.propagate(ts, fw, np.empty((2, 10)), 0, 1, True, A, d)
    i = lay["h_e_0"].start
    phi = math.exp(-0.1 / 300.0)
    assert d[i] == pytest.approx(phi, rel=1e-15)
    Phi = np.diag(d)
    Phi[:9] = A
    P_exp = Phi @ P0 @ Phi.T + np.diag(st.model[3:] * 0.1)
    P_exp[i, i] += (1 - phi ** 2) * 20e3 ** 2
    np.testing.assert_allclose(st.P, P_exp, rtol=1e-12, atol=1e-12 * np.abs(P_exp).max())
    assert st.edge_hat[0] == pytest.approx(PRIOR_EDGE_M + phi * (40e3 - PRIOR_EDGE_M), rel=1e-14)
    # the numpy reference forms (error_dynamics + discrete_transition, TransitionBuilder) agree
    from nav.error_state import TransitionBuilder, discrete_transition, error_dynamics
    F = error_dynamics(lay, x, np.eye(3), fw[1, 0], fw[1, 1], tun.correlation_time_s, 300.0)
    assert discrete_transition(lay, F, 0.1)[i, i] == pytest.approx(phi, rel=1e-15)
    assert TransitionBuilder(lay, tun.correlation_time_s, 300.0)(x, np.eye(3), fw[1, 0], fw[1, 1], 0.1).d[i] == d[i]


def edge_flight(t_end: float = 140.0, seed: int = 3):
    """atek-nav-grade with the Earth's edge at TRUE_EDGE_M, its vectors fitted at PRIOR_EDGE_M
    (truth vectors, no rendering), from T+60 to ``t_end``: (flight inputs, VectorData with dedge_c)."""
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    from scenarios.sim.truth_vectors import flight_truth_vectors
    from tests.test_navigator import flight_inputs
    sc = load_scenario("atek-nav-grade")
    sc = dataclasses.replace(sc, simulation=dataclasses.replace(sc.simulation, horizon_atmosphere_m=TRUE_EDGE_M))
    fl = simulate_flight(sc, seed=seed, duration=t_end)
    fi = flight_inputs(fl, 60.0, seed=seed)
    vd = flight_truth_vectors(fl, edge_ref_m=PRIOR_EDGE_M).vector_data([c.k for c in fl.cameras])
    m = vd.t_ns >= fi.imu.t_ns[fi.start_idx]
    vd = VectorData(vd.t_ns[m], vd.camera[m], vd.target[m], vd.e_c[m], vd.P_c[m], vd.dedge_c[m], vd.edge_ref_m[m])
    return fi, vd


def edge_height_acceptance(t_end: float = 140.0) -> dict:
    """The smoothed edge height of each camera of :func:`edge_flight` with the state estimated
    (constant, prior 45 +- 20 km): per camera the smoothed value at the start [m], its sigma, and
    the error against the truth."""
    from nav.smoother import rts_smooth
    from tests.test_navigator import truth_init
    fi, vd = edge_flight(t_end)
    tun = Tuning().with_(edge_height=StateGroupTuning("E", 20e3))
    res = run(fi.imu, truth_init(fi), tun, gps=fi.gps, vectors=vd, R_bc=fi.R_bc_nominal, unaided=False)
    sm = rts_smooth(res)
    idx = [res.layout[res.layout.edge_name(c)].start for c in range(len(fi.R_bc_nominal))]
    h = sm.estimates[0, idx]
    return {"smoothed_m": h, "sigma_m": np.sqrt(sm.P[0, idx]), "error_m": h - TRUE_EDGE_M,
            "forward_m": res.estimates[-1, idx], "hor_accepted": np.mean([x.accepted for x in res.innovations
                                                                           if x.kind == "hor"])}


def test_flight_teaches_its_edge_height():
    """Truth 10 km, prior 45 km (35 km, 1.75 prior sigma, off): after T+60..T+140 of the atek coast
    (two cameras, the Sun in view, the vehicle's rotation) the smoothed h_e of each camera is within
    3 km of the truth (the issue's acceptance) and within 3 of its own sigma (a 1-D Gaussian
    leaves it with probability 0.3 %); every horizon vector is accepted."""
    a = edge_height_acceptance()
    print(f"smoothed edge heights {np.round(a['smoothed_m'] / 1e3, 2)} km, sigma {np.round(a['sigma_m'] / 1e3, 2)} km, "
          f"truth {TRUE_EDGE_M / 1e3} km")
    assert np.all(np.abs(a["error_m"]) < 3e3)
    assert np.all(np.abs(a["error_m"]) < 3 * a["sigma_m"])
    assert a["hor_accepted"] == 1.0


def test_state_off_ignores_the_sensitivity():
    """With the state off (the default tuning), vectors carrying dedge_c give the bit-identical run
    of the same vectors without it (the edge column is never formed)."""
    from tests.test_navigator import truth_init
    fi, vd = edge_flight(75.0, seed=4)
    end = fi.start_idx + 400 * 15
    imu = ImuData(fi.imu.t_ns[:end], fi.imu.f_b[:end], fi.imu.w_b[:end], fi.imu.sample)
    plain = VectorData(vd.t_ns, vd.camera, vd.target, vd.e_c, vd.P_c)
    kw = dict(gps=fi.gps, R_bc=fi.R_bc_nominal, unaided=False)
    a = run(imu, truth_init(fi), Tuning(), vectors=vd, **kw)
    b = run(imu, truth_init(fi), Tuning(), vectors=plain, **kw)
    assert not a.layout.has("h_e_0")
    for name in ("x_e", "v_e", "q_eb", "P_diag", "P_full", "estimates"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_solution_columns_and_summary_report_it():
    """A short run with h_e estimated: the solution export (scenarios/replay/table.py) has
    ``h_e_<k>`` and ``h_e_<k>_sd`` (camera numbers k) equal to the smoother's estimate and the
    root of its variance, and the summary's edge heights are those values in km."""
    from nav.smoother import rts_smooth
    from scenarios.replay.summary import edge_heights
    from scenarios.replay.table import smoothed_columns
    from tests.test_navigator import truth_init
    fi, vd = edge_flight(75.0, seed=4)
    end = fi.start_idx + 400 * 15
    imu = ImuData(fi.imu.t_ns[:end], fi.imu.f_b[:end], fi.imu.w_b[:end], fi.imu.sample)
    tun = Tuning().with_(edge_height=StateGroupTuning("E", 20e3))
    res = run(imu, truth_init(fi), tun, gps=fi.gps, vectors=vd, R_bc=fi.R_bc_nominal, unaided=False)
    sm = rts_smooth(res)
    cols = smoothed_columns(sm, res.layout, np.zeros(len(sm.t_ns)), cam_numbers=[1, 2])
    for c, k in enumerate((1, 2)):
        i = res.layout[f"h_e_{c}"].start
        np.testing.assert_array_equal(cols[f"h_e_{k}"], sm.estimates[:, i])
        np.testing.assert_array_equal(cols[f"h_e_{k}_sd"], np.sqrt(sm.P[:, i]))
        s = edge_heights(res, sm, [1, 2])[f"camera_{k}"]
        assert s["smoothed_km"] == sm.estimates[0, i] / 1e3 and s["smoothed_sigma_km"] == np.sqrt(sm.P[0, i]) / 1e3
    # the vectors moved it from the 45 km prior (15 s: a weaker pull than the full coast's)
    assert np.all(sm.estimates[0, [res.layout[f"h_e_{c}"].start for c in range(2)]] < PRIOR_EDGE_M - 1e3)


@pytest.fixture(scope="module")
def rendered_horizon():
    """One geometric atek frame (no atmosphere: the edge at 0 km; 230 km, looking 20 deg down: a
    partial arc), no Sun in the prior (the threshold edge)."""
    from scenarios.sim import render
    from tests.poses import pose
    from tests.test_frontend import CAM, SUN
    R, x = pose(0.0, 20.0, h=230e3)
    fr = render.render_frame(CAM, R, x, SUN, None, options=render.RenderOptions.geometric())
    return CAM, R, x, fr.image


def _edge_config(cam, **edge):
    """The defaults with the edge at the geometric frame's 0 km (prior sigma 20 km), the limb model
    off (the threshold edge is the one the filter's state describes) and ``edge`` options."""
    from vision.frontend import default_config
    cfg = default_config(cam.fx)
    return dataclasses.replace(cfg, earth=dataclasses.replace(
        cfg.earth, atmosphere_m=0.0, atmosphere_sigma_m=20e3, limb=dataclasses.replace(cfg.earth.limb, fraction=0.0),
        edge=dataclasses.replace(cfg.earth.edge, **edge)))


def test_vision_filter_state_vector(rendered_horizon):
    """``edge.filter_state``: the joint (direction, height) fit's vector and height (the same as
    without it), its covariance given the height (``P - c c^T / sigma_h^2``, c the covariance with
    the height: 003's marginal covariance without the height's part), ``dedge_c = -c / sigma_h^2``.
    Independent check of ``dedge_c``: fixed-height fits (``estimate = false``) at 0 and 4 km (the
    fitted height is within 1 km of 0) differ by ``dedge_c`` x 4 km to 10 % (the inliers of the
    two fits differ by a few rays; the cone's second-order term over 4 km is below 1 %), with the
    sign of ``d e_c / d h_e``: a fit that assumes a higher edge than the true one moves by
    ``-dedge_c`` per metre."""
    from vision.frontend import FramePrior, process_frame
    cam, R, x, img = rendered_horizon
    prior = FramePrior(x, R)
    joint = process_frame(img, cam, _edge_config(cam), prior=prior)
    st = process_frame(img, cam, _edge_config(cam, filter_state=True), prior=prior)
    a, b = joint.record("earth"), st.record("earth")
    assert a.dedge_c is None and b.dedge_c is not None and b.edge_height_m == a.edge_height_m
    c, s2 = st.targets["earth"].edge_cov_c, b.edge_height_sigma_m ** 2
    np.testing.assert_array_equal(a.e_c, b.e_c)
    np.testing.assert_allclose(b.dedge_c, -c / s2, rtol=1e-12)
    np.testing.assert_allclose(a.P_c - b.P_c, np.outer(c, c) / s2, rtol=1e-9, atol=1e-15)
    assert np.isfinite(b.edge_data_m) and b.edge_data_sigma_m > 0 and np.isnan(a.edge_data_m)
    assert np.degrees(np.linalg.norm(b.dedge_c)) * 1e3 > 1e-3     # a partial arc: > 0.001 deg per km
    fixed = [process_frame(img, cam, _fixed_height(cam, h), prior=prior).record("earth") for h in (0.0, 4e3)]
    np.testing.assert_allclose(fixed[1].e_c - fixed[0].e_c, -b.dedge_c * 4e3, atol=0.1 * np.linalg.norm(b.dedge_c) * 4e3)


def test_threshold_state_edge(rendered_horizon):
    """``edge.state_edge = "threshold"`` with the limb model on: the record is the threshold
    edge's, bit-identical in direction, covariance, sensitivity and fitted height to the
    filter-state record with the limb model off (the threshold edge the state then describes),
    and it carries no arc's own height (NaN, inf: the filter gets no height row); without
    ``filter_state`` the option changes nothing. A value other than "limb" or "threshold" is an
    error naming it."""
    from vision.config import EdgeHeightOptions
    from vision.frontend import FramePrior, process_frame
    cam, R, x, img = rendered_horizon
    prior = FramePrior(x, R)
    cfg = _edge_config(cam, filter_state=True)
    limb_on = dataclasses.replace(cfg, earth=dataclasses.replace(
        cfg.earth, limb=dataclasses.replace(cfg.earth.limb, fraction=0.5),
        edge=dataclasses.replace(cfg.earth.edge, state_edge="threshold")))
    ref, thr = (process_frame(img, cam, c, prior=prior).record("earth") for c in (cfg, limb_on))
    for k in ("e_c", "P_c", "dedge_c"):
        np.testing.assert_array_equal(getattr(thr, k), getattr(ref, k))
    assert thr.edge_height_m == ref.edge_height_m and np.isfinite(ref.edge_data_sigma_m)
    assert np.isnan(thr.edge_data_m) and thr.edge_data_sigma_m == np.inf
    off = [dataclasses.replace(limb_on, earth=dataclasses.replace(limb_on.earth, edge=dataclasses.replace(
        limb_on.earth.edge, filter_state=False, state_edge=e))) for e in ("limb", "threshold")]
    a, b = (process_frame(img, cam, c, prior=prior).record("earth") for c in off)
    np.testing.assert_array_equal(a.e_c, b.e_c)
    np.testing.assert_array_equal(a.P_c, b.P_c)
    with pytest.raises(ValueError, match="state_edge"):
        EdgeHeightOptions(state_edge="disc")


def test_tuning_edge_choice():
    """``[states.edge_height] edge`` sets ``Tuning.edge_height_edge`` (default "limb"); another
    value is an error naming the key."""
    assert Tuning().edge_height_edge == "limb"
    t = tuning_from_toml('[states.edge_height]\nmode = "E"\nsigma_km = 25\nedge = "threshold"\n')
    assert t.edge_height_edge == "threshold" and t.edge_height.sigma == 25e3 and t.edge_height.on
    with pytest.raises(ValueError, match=r"\[states.edge_height\] edge"):
        tuning_from_toml('[states.edge_height]\nedge = "disc"\n')


def _fixed_height(cam, h_m: float):
    """`_edge_config` with the height not estimated, fixed at ``h_m``."""
    cfg = _edge_config(cam, estimate=False)
    return dataclasses.replace(cfg, earth=dataclasses.replace(cfg.earth, atmosphere_m=h_m))


def test_vision_rows_carry_the_sensitivity(rendered_horizon):
    """The replay's vector rows (scenarios/replay/sight.py): a record with ``dedge_c`` gives
    ``VectorData.dedge_c`` and ``edge_ref_m`` (its fitted height) in time order, NaN for the others;
    rows without any leave both None (the state then has no column)."""
    from scenarios.replay.sight import record_row, vector_data
    from vision.frontend import FramePrior, process_frame
    cam, R, x, img = rendered_horizon
    rec = process_frame(img, cam, _edge_config(cam, filter_state=True), prior=FramePrior(x, R)).record("earth")
    late = dataclasses.replace(rec, t_ns=rec.t_ns + 10)
    sun = (rec.t_ns + 5, 0, "sun", np.array([0.0, 0.0, 1.0]), np.eye(3) * 1e-8)
    vd = vector_data([record_row(late, [rec.camera]), sun, record_row(rec, [rec.camera])])
    assert vd.target.tolist() == ["hor", "sun", "hor"]
    np.testing.assert_array_equal(vd.dedge_c[[0, 2]], [rec.dedge_c, rec.dedge_c])
    assert np.isnan(vd.dedge_c[1]).all() and np.isnan(vd.edge_ref_m[1]) and vd.edge_ref_m[0] == rec.edge_height_m
    assert vector_data([sun]).dedge_c is None


def test_summary_leaves_out_cameras_without_sensitivity():
    """edge_heights: a camera whose vectors carry no dedge_c is not reported (its state had no
    measurement), one whose vectors do is."""
    from types import SimpleNamespace

    from scenarios.replay.summary import edge_heights
    lay = build_layout(Tuning().with_(edge_height=StateGroupTuning("E", 20e3)), 2)
    P = np.ones((1, lay.n))
    res = SimpleNamespace(layout=lay, estimates=np.full((1, lay.n), 45e3), P_diag=P)
    g = np.array([[1e-7, 0.0, 0.0], [np.nan] * 3])
    vec = SimpleNamespace(t_ns=np.array([1, 2]), camera=np.array([0, 1]), dedge_c=g)
    assert list(edge_heights(res, None, [1, 2], vec)) == ["camera_1"]
    assert list(edge_heights(res, None, [1, 2])) == ["camera_1", "camera_2"]


def test_image_replay_estimates_the_edge_height(ilog, tmp_path):
    """The image replay with ``[states.edge_height] mode = "E"`` (the short rendered atek log, 10
    frames): the vision gives the Earth vectors of the limb edge ("limb" and "flank" paths) their sensitivity at
    their fitted height, and only those;
    the edge heights of the cameras with such vectors are in the summary with a smoothed sigma no larger than the 20 km
    prior's, and the solution log names the states ``h_e_1``, ``h_e_2``."""
    from scenarios.flightlog import read_log
    from scenarios.replay.pipeline import replay
    from scenarios.replay.summary import format_table, summarize
    from tests.test_replay import _opt
    tun = tmp_path / "edge.toml"
    tun.write_text('[states.edge_height]\nmode = "E"\nsigma_km = 20\n')
    out = tmp_path / "e.solution.mcap"
    rr = replay(ilog, _opt(output=str(out), workers=1, tuning=str(tun)))
    hor = rr.vectors.target == "hor"
    has = hor & np.all(np.isfinite(rr.vectors.dedge_c), axis=1)
    assert has.sum() >= 1 and np.array_equal(has, hor & np.isfinite(rr.vectors.edge_ref_m))
    s = summarize(rr)
    seen = {f"camera_{rr.cam_numbers[c]}" for c in set(rr.vectors.camera[has].tolist())}
    assert "camera_2" in seen and set(s["edge_height"]) == seen    # a camera without limb-edge frames: not reported
    for d in s["edge_height"].values():
        assert np.isfinite(d["smoothed_km"]) and 0 < d["smoothed_sigma_km"] <= 20.0 + 1e-9
    assert "Earth edge height" in format_table(s)
    sm = read_log(out).nav["smoothed"]
    assert {"h_e_1", "h_e_2"} <= set(sm.state_names)
    j = sm.state_names.index("h_e_2")
    assert np.asarray(sm.state)[0, j] / 1e3 == pytest.approx(s["edge_height"]["camera_2"]["smoothed_km"], rel=1e-12)


def test_summary_moves_vectors_to_the_learned_height():
    """vector_errors: Earth vectors built as ``truth + dedge_c (h_true - ref)`` (the measurement model)
    and a smoothed h_e of h_true: the ``camera_1/earth*`` row (moved to the learned height) is on the
    truth to the arccos's resolution (sqrt(2 eps) rad = 1.2e-6 deg; the normalisation's second-order
    term is 1e-12 rad), the unmoved row off by |dedge_c| (h_true - ref) (0.015 deg here)."""
    from types import SimpleNamespace

    from scenarios.replay.summary import vector_errors
    lay = build_layout(Tuning().with_(edge_height=StateGroupTuning("E", 20e3)), 1)
    rng = np.random.default_rng(4)
    n = 20
    tru = rng.normal(size=(n, 3))
    tru /= np.linalg.norm(tru, axis=1, keepdims=True)
    g = np.cross(tru, [0.0, 0.0, 1.0])
    g *= math.radians(0.001) / 1e3 / np.linalg.norm(g, axis=1, keepdims=True)   # 0.001 deg per km
    ref = np.full(n, 45e3)
    e = tru + g * (TRUE_EDGE_M + 20e3 - ref)[:, None]      # true edge 30 km: 15 km below the fit's
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    t = np.arange(n, dtype=np.int64)
    vec = VectorData(t, np.zeros(n, int), np.array(["hor"] * n), e, np.tile(np.eye(3) * 1e-8, (n, 1, 1)), g, ref)
    est = np.zeros((1, lay.n))
    est[0, lay["h_e_0"].start] = TRUE_EDGE_M + 20e3
    rr = SimpleNamespace(vectors=vec, cam_numbers=[1], nav=SimpleNamespace(layout=lay),
                         smooth=SimpleNamespace(estimates=est),
                         inputs=SimpleNamespace(cameras={1: SimpleNamespace(truth={"t_ns": t, "nadir_c": tru})}))
    ve = vector_errors(rr)
    assert ve["camera_1/earth*"]["rms_deg"] < 1e-5 and ve["camera_1/earth*"]["n"] == n
    assert ve["camera_1/earth"]["rms_deg"] == pytest.approx(0.015, rel=1e-3)
