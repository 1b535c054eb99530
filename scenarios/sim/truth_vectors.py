"""Vector measurements from the simulator's truth plus the vision error model (no images).

For fast studies and for logs without images: at every camera frame where the horizon (or the Sun)
is in view, :func:`vision.error_model.predict_vision` traces the visible arc of the limb through
the camera model and gives the covariance the vision front end would report for it (003 eq. (33)
with the correlated pixel noise of eqs. (34)-(36) for the horizon and (38) for the Sun; the
spherical overbound of eq. (37) is reported as ``covariance_overbound``). Frames whose visible arc
is too short for a covariance (``predict_vision``'s ``min_pixels``) give no vector, as the front
end would reject them. :func:`vision.error_model.draw_vector_errors` then perturbs the true
direction with a first-order Gauss-Markov error of correlation time T_c = 20 s (003 §6.3, eqs.
(41)-(45)) plus an optional white part, whose sum has the predicted covariance at every epoch.

The Earth's cone half-angle is 003 eq. (5) with the true geometric radius below the camera
(``CameraTruth.alpha``); the Sun's is its apparent radius times a bloom factor
(:func:`vision.error_model.bloomed_alpha`, 003 §5: the saturated disc is larger than the Sun).

Outputs (:class:`TruthVectors`) use the log's conventions (cameras numbered from 1, targets
``"earth"``/``"sun"``): :meth:`TruthVectors.write` calls ``LogWriter.write_vectors`` per camera,
:meth:`TruthVectors.vector_data` gives :class:`nav.navigator.VectorData` (camera index 0-based in
the order of the filter's mountings, targets ``"hor"``/``"sun"``).

The Earth's edge height. ``alpha_earth`` is the cone of the true edge height ``h`` (the
simulator's ``horizon_atmosphere_m``). With ``edge_ref_m`` given, the vectors are those of a
vision front end that fits the nadir with the edge at ``edge_ref_m`` instead (a fixed-height
constrained fit, `vision.nadir.nadir_from_horizon`): on the visible arc, the cone half-angle it
assumes differs by ``(edge_ref_m - h) dalpha/dh``, ``dalpha/dh = 1 / (d cos alpha)`` (003 eq. (5),
``sin alpha = (r + h) / d``, d the distance from the Earth's centre), which tilts the nadir by
``g_fit = de/dalpha dalpha/dh`` per metre (`vision.fitting.alpha_sensitivity`: zero for a full
circle, largest for a short arc). The measured vector is
``e_true + g_c (h - edge_ref_m)`` plus the noise, with ``g_c = -g_fit = d e_c / d h_e`` the
sensitivity the filter's edge-height state uses (``dedge_c``, ``edge_ref_m`` in
:class:`nav.navigator.VectorData`); ``P_c`` is the pixel noise's (no height term).

Random numbers: one generator per (camera, target) stream, ``SeedSequence(seed, spawn_key=(200 + 10 k
+ j,))`` with j = 0 for the Earth and 1 for the Sun, independent of the simulator's sensor streams.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nav.ephemeris import SUN_RADIUS
from vision.error_model import HORIZON_NOISE, SUN_NOISE, T_C, bloomed_alpha, draw_vector_errors, predict_vision

__all__ = ["TruthVectors", "DEFAULT_SUN_BLOOM", "camera_truth_vectors", "flight_truth_vectors",
           "log_truth_vectors", "LOG_TO_NAV_TARGET"]

#: Bloom factor of the Sun disc in the rendered images: the vision front end's Sun fits report an
#: apparent radius of about twice the geometric 0.27 deg (003 §5; the default
#: `vision.config.VisionConfig` accepts Sun radii of 0.2-4.0 deg).
DEFAULT_SUN_BLOOM = 2.0
#: log target name -> filter target name (nav.navigator.VectorData).
LOG_TO_NAV_TARGET = {"earth": "hor", "sun": "sun", "moon": "moon"}
_STREAM_BASE = 200


@dataclass
class TruthVectors:
    """Simulated vision vectors of all cameras, in time order.

    ``t_ns`` (N,) frame stamps (camera clock, as the images would be stamped); ``camera`` (N,)
    camera number k (1-based, as in the log); ``target`` (N,) "earth" / "sun"; ``e_c`` (N, 3)
    measured unit vectors in the camera frame; ``P_c`` (N, 3, 3) the reported covariance (003 eq.
    (33)); ``P_overbound`` (N, 3, 3) eq. (37); ``e_true`` (N, 3) the true directions; ``n_pixels``
    (N,) length of the visible arc [samples]; ``conic_type`` (N,) str. ``skipped`` counts frames
    with the body in view but no vector, by reason. ``dedge_c`` (N, 3) and ``edge_ref_m`` (N,):
    the edge-height sensitivity and the height the Earth vectors were fitted at (module
    docstring; NaN for the Sun), None when the vectors were made without ``edge_ref_m``.
    """
    t_ns: np.ndarray
    camera: np.ndarray
    target: np.ndarray
    e_c: np.ndarray
    P_c: np.ndarray
    P_overbound: np.ndarray
    e_true: np.ndarray
    n_pixels: np.ndarray
    conic_type: np.ndarray
    skipped: dict
    dedge_c: np.ndarray | None = None
    edge_ref_m: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t_ns.size)

    def write(self, writer) -> None:
        """Write ``/camera_<k>/vectors`` for every camera (``scenarios.flightlog.writer.LogWriter``;
        with ``edge_ref_m``, the edge sensitivity and the height fitted at)."""
        for k in np.unique(self.camera):
            m = self.camera == k
            edge = {} if self.dedge_c is None else {"edge_sensitivity": self.dedge_c[m], "edge_height": self.edge_ref_m[m]}
            writer.write_vectors(int(k), self.t_ns[m], list(self.target[m]), self.e_c[m], self.P_c[m],
                                 self.P_overbound[m], pixel_count=self.n_pixels[m], inlier_count=self.n_pixels[m],
                                 conic_type=list(self.conic_type[m]), **edge)

    def vector_data(self, cameras=None):
        """:class:`nav.navigator.VectorData`; ``cameras``: the camera numbers k in the order of the
        filter's ``R_bc`` list (default: sorted numbers present). Vectors of other cameras are left out."""
        from nav.navigator import VectorData
        ks = sorted(set(int(k) for k in self.camera)) if cameras is None else [int(k) for k in cameras]
        index = {k: i for i, k in enumerate(ks)}
        m = np.isin(self.camera, ks)
        return VectorData(self.t_ns[m].astype(np.int64), np.array([index[int(k)] for k in self.camera[m]], int),
                          np.array([LOG_TO_NAV_TARGET[str(t)] for t in self.target[m]], dtype=object).astype(str),
                          self.e_c[m], self.P_c[m], None if self.dedge_c is None else self.dedge_c[m],
                          None if self.edge_ref_m is None else self.edge_ref_m[m])


def _empty() -> TruthVectors:
    z3 = np.zeros((0, 3))
    return TruthVectors(np.zeros(0, np.int64), np.zeros(0, int), np.zeros(0, str), z3, np.zeros((0, 3, 3)),
                        np.zeros((0, 3, 3)), z3, np.zeros(0, int), np.zeros(0, str), {})


def camera_truth_vectors(camera, k: int, t_ns, nadir_c, sun_c, alpha_earth, horizon_visible, sun_in_view,
                         sun_distance_m, *, seed: int = 0, targets=("earth", "sun"), mask=None,
                         sun_bloom: float = DEFAULT_SUN_BLOOM, gm_fraction: float = 1.0, T_c: float = T_C,
                         min_pixels: int = 30, step_px: float = 1.0, edge_ref_m: float | None = None,
                         edge_height_m: float = 0.0, earth_distance_m=None) -> TruthVectors:
    """Vectors of one camera (k, 1-based) from its per-frame truth (see the module docstring).

    Parameters
    ----------
    camera : `vision.camera.FisheyeCamera`.
    t_ns : (N,) frame stamps [int ns]; nadir_c, sun_c : (N, 3) true unit vectors in the camera.
    alpha_earth : (N,) Earth cone half-angle [rad] (003 eq. (5)).
    horizon_visible, sun_in_view : (N,) bool.
    sun_distance_m : (N,) or scalar camera-Sun distance [m] (apparent radius asin(R_sun / d)).
    seed : base seed of the error draws.
    mask : optional payload mask array for ``predict_vision``.
    gm_fraction : share of the covariance in the Gauss-Markov part (default 1, 003 §6.3).
    step_px : arc sampling [px] for the covariance: 1 px, the edge follower's spacing (a coarser
        sampling changes P: 2 px gave a 28 % larger sigma on an atek horizon, because the white part
        of the pixel noise, 003 eq. (34), averages over fewer samples).
    edge_ref_m, edge_height_m, earth_distance_m : the edge height the Earth vectors are fitted at,
        the true one ``alpha_earth`` was computed with [m], and the camera's distance from the
        Earth's centre (N,) or scalar [m] (module docstring); ``edge_ref_m`` None: the fit at the
        true height (no sensitivity reported).
    """
    if edge_ref_m is not None and earth_distance_m is None:
        raise ValueError("camera_truth_vectors: edge_ref_m needs earth_distance_m (the distance from "
                         "the Earth's centre, for dalpha/dh)")
    t_ns = np.asarray(t_ns, np.int64)
    n = t_ns.size
    dist = np.broadcast_to(np.asarray(sun_distance_m, float), (n,))
    d_earth = None if earth_distance_m is None else np.broadcast_to(np.asarray(earth_distance_m, float), (n,))
    rows = []
    skipped: dict = {}
    for j, (target, vecs, vis, noise) in enumerate((("earth", nadir_c, horizon_visible, HORIZON_NOISE),
                                                    ("sun", sun_c, sun_in_view, SUN_NOISE))):
        if target not in targets:
            continue
        vecs = np.asarray(vecs, float)
        idx, P, Po, npx, conic, g = [], [], [], [], [], []
        for i in np.flatnonzero(np.asarray(vis, bool)):
            if target == "earth":
                alpha, method = float(alpha_earth[i]), "constrained"
            else:
                alpha, method = bloomed_alpha(math.asin(SUN_RADIUS / dist[i]), sun_bloom), "free-alpha"
            pred = predict_vision(camera, vecs[i], alpha, noise[0], noise[1], mask=mask, step_px=step_px,
                                  method=method, min_pixels=max(1, int(round(min_pixels / step_px))))
            if pred.covariance is None:
                key = f"{target}: {pred.reason.split('(')[0].strip()}"
                skipped[key] = skipped.get(key, 0) + 1
                continue
            if target == "earth" and edge_ref_m is not None:
                g.append(_edge_sensitivity(camera, pred.pixels, vecs[i], alpha, float(d_earth[i])))
            idx.append(i)
            P.append(pred.covariance.P_c)
            Po.append(pred.covariance.P_sphere)
            npx.append(int(round(len(pred.pixels) * step_px)))
            conic.append(pred.conic if target == "earth" else "ellipse")
        if not idx:
            continue
        idx = np.array(idx)
        P = np.array(P)
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(_STREAM_BASE + 10 * int(k) + j,)))
        t_s = (t_ns[idx] - t_ns[idx[0]]) / 1e9
        drawn = draw_vector_errors(vecs[idx], P, t_s, rng, T_c=T_c, gm_fraction=gm_fraction)
        e_meas, g_c, ref = drawn.e_meas, np.full((idx.size, 3), np.nan), np.nan
        if g:
            g_c, ref = np.array(g), float(edge_ref_m)
            e_meas = e_meas + g_c * (float(edge_height_m) - ref)
            e_meas = e_meas / np.linalg.norm(e_meas, axis=1, keepdims=True)
        for r, i in enumerate(idx):
            rows.append((int(t_ns[i]), int(k), target, e_meas[r], P[r], Po[r], vecs[i], npx[r], conic[r], g_c[r], ref))
    return _assemble(rows, skipped)


def _edge_sensitivity(camera, pixels, e_true, alpha: float, d: float) -> np.ndarray:
    """``g_c = d e_c / d h_e`` [1/m] of the fixed-height constrained fit on the arc ``pixels``
    (module docstring): ``-de/dalpha dalpha/dh`` with ``dalpha/dh = 1 / (d cos alpha)``."""
    from vision.camera import unproject_jacobian
    from vision.fitting import alpha_sensitivity
    rays, _ = unproject_jacobian(camera, np.asarray(pixels, float))
    return -alpha_sensitivity(rays, np.asarray(e_true, float), alpha) / (d * math.cos(alpha))


def _assemble(rows, skipped) -> TruthVectors:
    if not rows:
        out = _empty()
        out.skipped = skipped
        return out
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    col = list(zip(*rows))
    g, ref = np.array(col[9], float).reshape(-1, 3), np.array(col[10], float)
    with_edge = bool(np.isfinite(ref).any())
    return TruthVectors(np.array(col[0], np.int64), np.array(col[1], int), np.array(col[2], dtype=str),
                        np.array(col[3]), np.array(col[4]), np.array(col[5]), np.array(col[6]),
                        np.array(col[7], int), np.array(col[8], dtype=str), skipped,
                        g if with_edge else None, ref if with_edge else None)


def _merge(parts) -> TruthVectors:
    rows, skipped = [], {}
    for p in parts:
        for key, v in p.skipped.items():
            skipped[key] = skipped.get(key, 0) + v
        n = len(p)
        g = np.full((n, 3), np.nan) if p.dedge_c is None else p.dedge_c
        ref = np.full(n, np.nan) if p.edge_ref_m is None else p.edge_ref_m
        rows.extend(zip(p.t_ns.tolist(), p.camera.tolist(), p.target.tolist(), p.e_c, p.P_c, p.P_overbound,
                        p.e_true, p.n_pixels.tolist(), p.conic_type.tolist(), g, ref.tolist()))
    return _assemble(rows, skipped)


def flight_truth_vectors(flight, seed: int | None = None, edge_ref_m: float | None = None, **kw) -> TruthVectors:
    """Vectors of every camera of a simulated flight (``scenarios.sim.simulate.FlightData``); ``seed``
    defaults to the flight's. ``edge_ref_m``: the edge height the Earth vectors are fitted at (the
    true one is the scenario's ``horizon_atmosphere_m``; module docstring). Keywords as
    :func:`camera_truth_vectors`."""
    from nav.ephemeris import sun_position_e
    seed = flight.seed if seed is None else seed
    parts = []
    for c in flight.cameras:
        ct = c.truth
        true_ns = flight.to_ns(ct.t)
        idx = np.round(ct.t / flight.truth.dt).astype(int)
        dist = np.linalg.norm(sun_position_e(true_ns) - flight.truth.x_e[idx], axis=1)
        edge = {}
        if edge_ref_m is not None:
            edge = dict(edge_ref_m=edge_ref_m, edge_height_m=flight.scenario.simulation.horizon_atmosphere_m,
                        earth_distance_m=np.linalg.norm(flight.truth.x_e[idx], axis=1))
        parts.append(camera_truth_vectors(c.camera, c.k, c.t_ns, ct.nadir_c, ct.sun_c, ct.alpha, ct.horizon_visible,
                                          ct.sun_in_view, dist, seed=seed, **edge, **kw))
    return _merge(parts)


def log_truth_vectors(log, seed: int = 0, **kw) -> TruthVectors:
    """Vectors from a log's per-frame camera truth (``/camera_<k>/truth``), its CameraInfo and
    ``/truth/state`` (position for the Earth's cone half-angle, 003 eq. (5)); for logs written
    with ``--no-images``. Raises ``UserError`` naming what is missing."""
    from nav import earth
    from nav.ephemeris import sun_position_e
    from scenarios.errors import UserError
    from vision.camera import from_camera_info
    if log.truth is None or len(log.truth) == 0:
        raise UserError(f"{log.path}: no /truth/state: truth vectors need the simulated truth")
    parts = []
    tt = log.truth.t_ns
    for k, cl in log.cameras.items():
        if cl.truth is None or len(cl.truth) == 0:
            continue
        if cl.info is None or len(cl.info) == 0:
            raise UserError(f"{log.path}: /camera_{k}/truth but no /camera_{k}/camera_info: the camera "
                            "model is needed for the vision error model")
        cam = from_camera_info(_info_dict(cl.info, 0))
        ct = cl.truth
        t = ct.t_ns
        x = np.stack([np.interp(t.astype(float), tt.astype(float), log.truth.position_e[:, i]) for i in range(3)], -1)
        lat, lon, h = earth.ecef_to_geodetic(x)
        r = np.linalg.norm(x, axis=1)
        alpha = np.arcsin(np.clip((r - h) / r, -1.0, 1.0))
        dist = np.linalg.norm(sun_position_e(t) - x, axis=1)
        parts.append(camera_truth_vectors(cam, k, t, ct.nadir_c, ct.sun_c, alpha, ct.horizon_visible,
                                          ct.sun_in_view, dist, seed=seed, **kw))
    return _merge(parts)


def _info_dict(info, i: int) -> dict:
    d = info.d
    d = d[i] if getattr(d, "dtype", None) == object else (d[i] if np.ndim(d) == 2 else d)
    return {"distortion_model": str(info.distortion_model[i]), "d": np.asarray(d, float),
            "k": np.asarray(info.k[i], float).reshape(9), "r": np.asarray(info.r[i], float).reshape(9),
            "width": int(info.width[i]), "height": int(info.height[i])}
