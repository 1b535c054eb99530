"""The vectors the filter is given: the log's own ``/camera_<k>/vectors``, or the vision front end
on the camera images.

On the image path every frame in the window is decoded and processed by
:func:`vision.frontend.process_frame` in worker processes (:mod:`.vision_worker`) with the GPS
position and the INS attitude as prior: the ellipsoid Earth model (geocentric nadir, 003 eq.
(39)), the exposure-invariant limb edge (:mod:`vision.limb`) and the Sun gate around the
predicted Sun direction. TRIAD needs vectors before any attitude exists: :func:`triad_pass` runs
the vision without attitude prior (substitute sphere of 003 §2.8 with the Gaussian radius at the
GPS latitude, no Sun gate) on one frame per camera every :data:`TRIAD_SEARCH_DT_S` seconds until
it finds an epoch with a horizon and a Sun vector (a few percent of the frames); the free-inertial
INS from the initial state then gives every frame its attitude prior (:func:`attach_priors`).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from nav import earth
from nav.navigator import VectorData
from scenarios.errors import UserError
from scenarios.replay import inputs as I
from scenarios.replay.inputs import PYTHON, Wording
from scenarios.replay.start import free_inertial_R_eb, gps_at

NS = 1_000_000_000
#: the filter's name of each vision target
NAV_TARGET = {"earth": "hor", "sun": "sun", "moon": "moon"}
#: spacing [s] of the frames the TRIAD search looks at (the vision runs there without attitude)
TRIAD_SEARCH_DT_S = 5.0
#: frames per batch of the TRIAD search (it stops at the first batch that gives a TRIAD epoch)
TRIAD_SEARCH_BATCH = 16


def vector_data(rows) -> VectorData | None:
    """Rows ``(t_ns, camera index, target, e_c, P_c[, dedge_c, edge_ref_m[, edge_data_m,
    edge_data_sigma_m[, edge_ref_sigma_m]]])`` -> VectorData in (time, camera, target) order (with ``dedge_c``,
    ``edge_ref_m`` and the arc's own height and sigma when a row has a sensitivity, NaN for the
    others); None without rows."""
    if not rows:
        return None
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    c = list(zip(*rows))
    vd = VectorData(np.array(c[0], np.int64), np.array(c[1], int), np.array(c[2], dtype=str),
                    np.array(c[3], float).reshape(-1, 3), np.array(c[4], float).reshape(-1, 3, 3))
    if any(len(r) > 5 and r[5] is not None for r in rows):
        vd.dedge_c = np.array([r[5] if len(r) > 5 and r[5] is not None else np.full(3, np.nan) for r in rows], float)
        vd.edge_ref_m = np.array([r[6] if len(r) > 5 and r[5] is not None else np.nan for r in rows], float)
        vd.edge_data_m = np.array([r[7] if len(r) > 8 and r[5] is not None else np.nan for r in rows], float)
        vd.edge_data_sigma_m = np.array([r[8] if len(r) > 8 and r[5] is not None else np.nan for r in rows], float)
        vd.edge_ref_sigma_m = np.array([r[9] if len(r) > 9 and r[5] is not None else np.nan for r in rows], float)
    return vd


def record_row(r, cam_numbers) -> tuple:
    """A front end's VectorRecord as a row of :func:`vector_data` (its edge-height sensitivity,
    `vision.results.VectorRecord.dedge_c`, with the height fitted at and the arc's own height and
    sigma, where it has one)."""
    row = (r.t_ns, cam_numbers.index(r.camera), NAV_TARGET[r.target], r.e_c, r.P_c)
    dedge = getattr(r, "dedge_c", None)
    if dedge is None:
        return row
    return row + (np.asarray(dedge, float), float(r.edge_height_m), float(getattr(r, "edge_data_m", math.nan)),
                  float(getattr(r, "edge_data_sigma_m", math.nan)), float(r.edge_height_sigma_m))


def frame_vectors(frames, cam_numbers) -> VectorData | None:
    """The vectors of the front end's results ``frames`` of the cameras ``cam_numbers``."""
    return vector_data([record_row(r, cam_numbers) for f in frames for r in f.records if r.camera in cam_numbers])


def log_vectors(inp, cam_numbers, targets, a, b, edge_state: bool = False) -> VectorData | None:
    """The log's ``/camera_<k>/vectors`` of ``targets`` in the window [a, b] (camera indices into
    ``cam_numbers``). A vector with an edge sensitivity (DirectionVector version 2) gives it with
    its heights when ``edge_state`` (the filter estimates the edge height), else its covariance
    with the height's part added back (``P + sigma_h^2 g g^T``)."""
    rows = []
    for i, k in enumerate(cam_numbers):
        v = inp.cameras[k].vectors
        if v is None:
            continue
        m = (v["t_ns"] >= a) & (v["t_ns"] <= b) & np.isin(v["target"], list(targets))
        for j in np.flatnonzero(m):
            rows.append(_log_row(v, j, i, edge_state))
    return vector_data(rows)


def _log_row(v: dict, j: int, i: int, edge_state: bool) -> tuple:
    """Row ``j`` of a camera's log vectors ``v`` (:func:`log_vectors`) for :func:`vector_data`."""
    row = (int(v["t_ns"][j]), i, NAV_TARGET[str(v["target"][j])], v["vector"][j], v["covariance"][j])
    g = v["edge_sensitivity"][j] if "edge_sensitivity" in v else None
    if g is None or not np.all(np.isfinite(g)):
        return row
    if edge_state:
        return row + (g, float(v["edge_height"][j]), float(v["edge_height_arc"][j]),
                      float(v["edge_height_arc_sigma"][j]), float(v["edge_height_sigma"][j]))
    s = float(v["edge_height_sigma"][j])
    return row[:4] + (row[4] + (s * s if np.isfinite(s) else 0.0) * np.outer(g, g),)


@dataclass
class ImagePlan:
    """The frames to process (time order) with their jobs, cameras and the vision configuration."""

    jobs: list            #: vision_worker.FrameJob
    cams: dict            #: camera number -> FisheyeCamera
    config: object        #: vision.config.VisionConfig
    images: dict          #: camera number -> image stream
    cam_numbers: list
    masks: dict = field(default_factory=dict)   #: camera number -> vision.mask.PayloadMask
    targets: tuple = ("earth", "sun")
    workers: int = 0
    limb_offsets: list = field(default_factory=list)  #: vision.limb_offset.LimbOffset per camera (run_images)


def image_plan(flight, targets, *, vision_config=None, vision_rate_hz=None, masks=None, workers=0,
               wording: Wording = PYTHON, edge_state: bool | str = False) -> ImagePlan:
    """The frames of ``flight``'s window (at most ``vision_rate_hz`` per camera) with their GPS
    position and height priors. ``edge_state``: the filter estimates each camera's edge height
    (``Tuning.edge_height`` on): the Earth vectors are given the height, with their sensitivity
    (`vision.config.EdgeHeightOptions.filter_state`); a string names the edge the state
    describes (``EdgeHeightOptions.state_edge``, ``Tuning.edge_height_edge``; True: "limb")."""
    from scenarios.config.vision import load_vision_config
    from scenarios.replay.vision_worker import FrameJob
    inp, cam_numbers, a, b = flight.inputs, flight.cam_numbers, flight.t_from, flight.t_to
    rows, cams, configs = [], {}, {}
    for k in cam_numbers:
        c = inp.cameras[k]
        cams[k] = c.camera
        configs[k] = load_vision_config(vision_config, camera=c.camera)
        for i in I.frames_in(c.images.t_ns, a, b, vision_rate_hz):
            rows.append((int(c.images.t_ns[i]), k, int(i)))
    rows.sort()
    # one config per camera only differs through the focal length; the worker takes one config
    cfg = _targets_only(configs[cam_numbers[0]], targets) if cam_numbers else None
    if cfg is not None and edge_state:
        cfg = dataclasses.replace(cfg, earth=dataclasses.replace(
            cfg.earth, edge=dataclasses.replace(cfg.earth.edge, filter_state=True,
                                                state_edge=edge_state if isinstance(edge_state, str) else "limb")))
    plan = ImagePlan([], cams, cfg, {k: inp.cameras[k].images for k in cam_numbers}, cam_numbers,
                     payload_masks(inp, cam_numbers, masks or {}, wording), tuple(targets), workers)
    if not rows:
        return plan
    t_all = np.array([r[0] for r in rows], np.int64)
    if inp.gps is not None:
        x = gps_at(inp, t_all)
    elif inp.truth is not None:
        x = np.stack([np.interp(t_all.astype(float), inp.truth.t_ns.astype(float), inp.truth.x_e[:, i]) for i in range(3)], -1)
    else:
        raise UserError(f"{wording.set('vision', 'images')}: the Earth fit needs the height (003 eq. (5)); "
                        "the log has neither GPS nor truth")
    lat, _, h = earth.ecef_to_geodetic(x)
    plan.jobs = [FrameJob(k, i, t, None, float(h[n]), float(lat[n]), x_e=x[n]) for n, (t, k, i) in enumerate(rows)]
    return plan


def payload_masks(inp, cam_numbers, files: dict, wording: Wording = PYTHON) -> dict:
    """Camera -> `vision.mask.PayloadMask`: the image file ``files[k]`` where given, else the log's
    ``/camera_<k>/payload_mask``; cameras without either are searched without a mask."""
    from scenarios.config.camera import read_payload_mask
    from vision import mask as vmask
    unknown = sorted(set(files) - set(cam_numbers))
    if unknown:
        raise UserError(f"{wording.name('masks')}: camera(s) {unknown} are not replayed (cameras: {cam_numbers})")
    out = {}
    for k in cam_numbers:
        m = inp.cameras[k].mask
        if k in files:
            what = f"--mask {k}={files[k]}" if wording.cli else f"masks[{k}] {files[k]}"
            m = read_payload_mask(files[k], inp.cameras[k].camera, what, f"camera {k}'s")
        if m is not None:
            out[k] = vmask.from_binary(m)
    return out


def run_plan(plan: ImagePlan, jobs, frames_out=None, progress=None, on_pool_start=None, on_result=None) -> list:
    """The vision on ``jobs``; returns the vector rows (:func:`record_row`) of the plan's targets (for :func:`vector_data`). Each finished chunk of frames goes to
    ``frames_out.extend`` and ``on_result``."""
    from scenarios.replay.vision_worker import run_vision

    def got(res):
        if frames_out is not None:
            frames_out.extend(res)
        if on_result is not None:
            on_result(res)
    out = run_vision(jobs, plan.cams, plan.config, workers=plan.workers, progress=progress, masks=plan.masks,
                     on_result=got, images=plan.images, on_pool_start=on_pool_start)
    return [record_row(r, plan.cam_numbers) for f in out for r in f.records if r.target in plan.targets]


def triad_pass(plan: ImagePlan, imu) -> VectorData | None:
    """Vectors for TRIAD (003 §7.4) before any attitude exists: the vision without attitude prior
    (substitute sphere, no Sun gate) on the first frame of each camera in every
    ``TRIAD_SEARCH_DT_S`` interval, in batches, until a batch gives an epoch with a horizon and a
    Sun vector. Costs a few percent of the frames; every frame is processed again with the prior."""
    from nav.initialise import first_triad_epoch
    if not plan.jobs or not {"earth", "sun"} <= set(plan.targets):
        return None
    t0 = plan.jobs[0].t_ns
    seen, pick = set(), []
    for j in plan.jobs:
        key = (j.k, (j.t_ns - t0) // int(TRIAD_SEARCH_DT_S * NS))
        if key not in seen:
            seen.add(key)
            pick.append(j)
    not_before = int(imu.t_ns[min(1, imu.t_ns.size - 1)])
    rows: list = []
    for i in range(0, len(pick), TRIAD_SEARCH_BATCH):
        rows += run_plan(plan, pick[i:i + TRIAD_SEARCH_BATCH])
        vd = vector_data(rows)
        try:
            if vd is not None:
                first_triad_epoch(vd, not_before)
                return vd
        except ValueError:
            pass            # no epoch with both vectors yet: the next batch
    return vector_data(rows)


def attach_priors(plan: ImagePlan, imu, init, inp) -> None:
    """Attitude prior of every job: the free-inertial INS from the initial state with the nominal
    mounting (a few degrees at most: enough for the ellipsoid model, the limb's Sun-elevation test
    and the Sun gate), the predicted Sun and Moon directions in the camera frame and the Moon's
    apparent radius (`vision.moon`: the Moon's search rows, gate and limb radius)."""
    from nav import ephemeris
    if not plan.jobs:
        return
    t = np.array([j.t_ns for j in plan.jobs], np.int64)
    R_eb = free_inertial_R_eb(imu, init, t)
    x = np.array([j.x_e for j in plan.jobs])
    s_e = ephemeris.sun_direction_e(t, x)
    m_pos = ephemeris.moon_position_e(t)
    m_e = ephemeris.moon_direction_e(t, x)
    m_alpha = ephemeris.apparent_radius(m_pos, x, ephemeris.MOON_RADIUS)
    for n, j in enumerate(plan.jobs):
        R_ec = R_eb[n] @ np.asarray(inp.cameras[j.k].R_bc, float)
        plan.jobs[n] = dataclasses.replace(j, R_ec=R_ec, sun_c=R_ec.T @ s_e[n], moon_c=R_ec.T @ m_e[n],
                                           moon_alpha=float(m_alpha[n]))


def run_images(plan: ImagePlan, frames_out, progress=None, on_pool_start=None, on_result=None):
    """Every planned frame through the vision (with the priors attached to its job), then each
    camera's limb edge height offset learned over the flight and its limb-edge fits re-weighted
    with it (`vision.limb_offset.refine_limb_height`; the offsets in ``plan.limb_offsets``);
    returns the vectors (None without frames). ``on_result`` sees the frames before the
    re-weighting; ``frames_out`` gets them after."""
    from vision.limb_offset import refine_limb_height
    if not plan.jobs:
        return None
    frames: list = []
    run_plan(plan, plan.jobs, frames, progress, on_pool_start, on_result)
    if not plan.config.earth.edge.filter_state:     # else the filter's h_e states learn the edge height
        fits = [(r, f.limb if r.target == "earth" else None) for f in frames for r in f.records]
        recs, plan.limb_offsets = refine_limb_height(fits, plan.config.earth.edge)
        it = iter(recs)
        for f in frames:
            f.records = [next(it) for _ in f.records]
    frames_out.extend(frames)
    return vector_data([record_row(r, plan.cam_numbers) for f in frames for r in f.records
                        if r.target in plan.targets])


def _targets_only(cfg, targets):
    ch = {}
    for name in ("earth", "sun", "moon"):
        tc = getattr(cfg, name)
        if tc.enabled and name not in targets:
            ch[name] = dataclasses.replace(tc, enabled=False)
    return dataclasses.replace(cfg, **ch) if ch else cfg
