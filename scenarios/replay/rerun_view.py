"""Rerun recording of a replay (rerun-sdk 0.41.0), laid out for inspection (003 figs. 36-44).

Entities (timelines ``utc`` = absolute time and ``mission_time`` = T+ seconds):

* ``world/earth`` WGS-84 ellipsoid, ``world/trajectory`` the forward solution (ECEF, metres);
  ``world/vehicle/aided`` and ``world/vehicle/unaided`` the body axes x (red), y (green), z (blue)
  of the filter and of the free-inertial INS, ``world/vehicle/att_3sigma`` spheres at the aided
  axis tips whose radius is the 3-sigma attitude bound times the axis length (fig. 40),
  ``world/vehicle/camera_<k>/earth|sun`` the measured Earth-nadir and Sun vectors rotated into e
  with the solution's attitude and mounting, ``world/vehicle/sun`` the Sun direction from the
  ephemeris, ``world/vehicle/rcs`` the measured specific force when above 0.7 mg during the coast
  (RCS thrust, fig. 38: the logs carry no thruster state, the accelerometer sees the firing).
  Drawn once per second of flight.
* ``camera_<k>/image`` each frame as its JPEG bytes (EncodedImage) with ``.../<target>/edges``
  (candidates), ``inliers``, ``outliers``, ``conic`` (fitted cone through the distorted camera model)
  and ``point`` (vector image point), 003 figs. 15, 27.
* time series (send_columns): ``innovation/<source>/<i>`` with ``+3sigma``/``-3sigma`` (fig. 41),
  ``angle_residual/<aided|unaided>/camera_<k>/<target>`` measured-vs-predicted angle (fig. 42),
  ``misalignment/camera_<k>/<axis>`` with 3 sigma (fig. 43), ``attitude_3sigma/<axis>`` (fig. 40),
  ``aided_minus_unaided/<axis>`` (fig. 39), ``triad_minus_solution/<axis>`` (fig. 44),
  ``error/attitude/<axis>`` and ``error/position``, ``error/velocity`` when the log has truth.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nav import earth
from nav.ephemeris import sun_position_e
from nav.rotation import matrix_to_rotvec, quat_to_matrix
from scenarios.replay.solution_log import source_name
from scenarios.replay.summary import attitude_error

NS = 1_000_000_000
AXIS_LEN = 60e3         # body-axis arrows [m] (the scene spans the Earth)
VEC_LEN = 90e3
RGB = np.array([[230, 60, 60], [60, 200, 60], [70, 110, 240]], np.uint8)
AXES = "xyz"


def _times(rr, inp, t_ns):
    t = np.asarray(t_ns, np.int64)
    return [rr.TimeColumn("utc", timestamp=t.astype("datetime64[ns]")),
            rr.TimeColumn("mission_time", duration=inp.mission_time(t))]


def _series(rec, rr, inp, path, t_ns, values):
    v = np.asarray(values, float)
    if v.size == 0:
        return
    rec.send_columns(path, indexes=_times(rr, inp, t_ns), columns=rr.Scalars.columns(scalars=v))


def _set_time(rec, inp, t):
    rec.set_time("utc", timestamp=np.datetime64(int(t), "ns"))
    rec.set_time("mission_time", duration=float(inp.mission_time(t)))


def blueprint(cam_numbers):
    import rerun.blueprint as rrb
    cams = [rrb.Spatial2DView(origin=f"camera_{k}", name=f"camera {k}") for k in cam_numbers]
    ts = [rrb.TimeSeriesView(origin="innovation", name="innovations ±3σ (fig. 41)"),
          rrb.TimeSeriesView(origin="angle_residual", name="measured − predicted angle (fig. 42)"),
          rrb.TimeSeriesView(origin="misalignment", name="misalignment ±3σ (fig. 43)"),
          rrb.TimeSeriesView(origin="attitude_3sigma", name="attitude 3σ (fig. 40)"),
          rrb.TimeSeriesView(origin="aided_minus_unaided", name="aided − unaided (fig. 39)"),
          rrb.TimeSeriesView(origin="triad_minus_solution", name="TRIAD − solution (fig. 44)"),
          rrb.TimeSeriesView(origin="error", name="error vs truth")]
    left = rrb.Vertical(rrb.Spatial3DView(origin="world", name="3D (fig. 38)"),
                        rrb.Horizontal(*cams) if cams else rrb.TextDocumentView(origin="notes"), row_shares=[3, 2])
    return rrb.Blueprint(rrb.Horizontal(left, rrb.Tabs(*ts), column_shares=[3, 2]), collapse_panels=True)


def record(inp, res, smooth, vectors, cam_numbers, frames, path: Path | None, *, spawn: bool = False):
    """Write the recording to ``path`` (.rrd) and/or spawn the viewer."""
    import rerun as rr
    rec = rr.RecordingStream("horizon-nav", recording_id=f"replay-{Path(inp.path).stem}")
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(path).with_name("." + Path(path).name + ".tmp")
        rec.save(str(tmp), default_blueprint=blueprint(cam_numbers))
    if spawn:
        rec.spawn(default_blueprint=blueprint(cam_numbers))
    _static(rec, rr, inp, res)
    _scene(rec, rr, inp, res, vectors, cam_numbers)
    _images(rec, rr, inp, frames, cam_numbers)
    _timeseries(rec, rr, inp, res, smooth, cam_numbers)
    rec.flush()
    if path is not None:
        rec.disconnect()
        tmp.replace(path)
    return path


def _static(rec, rr, inp, res):
    rec.log("world/earth", rr.Ellipsoids3D(half_sizes=[[earth.A, earth.A, earth.B]], colors=[[40, 90, 160]],
                                           line_radii=[2000.0]), static=True)
    step = max(1, len(res.t_ns) // 4000)
    rec.log("world/trajectory", rr.LineStrips3D([res.x_e[::step]], colors=[[255, 200, 0]], radii=[800.0]), static=True)
    if len(res.unaided_x_e):
        rec.log("world/trajectory_unaided", rr.LineStrips3D([res.unaided_x_e[::step]], colors=[[160, 160, 160]],
                                                             radii=[500.0]), static=True)
    for k, c in inp.cameras.items():
        if c.camera is not None:
            rec.log(f"camera_{k}/image", rr.Pinhole(image_from_camera=np.asarray(c.camera.K if hasattr(c.camera, "K") else
                                                                                   _K(c.camera)), width=c.camera.width,
                                                   height=c.camera.height), static=True)


def _K(cam):
    from vision.camera import to_opencv
    return to_opencv(cam)[0]


def _scene(rec, rr, inp, res, vectors, cam_numbers):
    t = res.t_ns
    sel = np.unique(np.searchsorted(t, np.arange(t[0], t[-1] + 1, NS)).clip(0, len(t) - 1))
    R = quat_to_matrix(res.q_eb[sel])
    Ru = quat_to_matrix(res.unaided_q_eb[sel]) if len(res.unaided_q_eb) else None
    sig = np.sqrt(res.P_diag[:, res.layout["psi"]])
    ci = np.clip(np.searchsorted(res.cov_t_ns, t[sel]), 0, len(res.cov_t_ns) - 1)
    sun = sun_position_e(t[sel])
    f_b = np.asarray(inp.imu.f_b)
    fi = np.clip(np.searchsorted(inp.imu.t_ns, t[sel]), 0, len(inp.imu.t_ns) - 1)
    vt = {}
    if vectors is not None:
        for n in range(len(vectors.t_ns)):
            vt.setdefault(int(vectors.t_ns[n]) // NS, []).append(n)
    R_bc = [inp.cameras[k].R_bc for k in cam_numbers]
    for j, i in enumerate(sel):
        _set_time(rec, inp, t[i])
        x = res.x_e[i]
        ax = R[j].T * AXIS_LEN
        rec.log("world/vehicle/aided", rr.Arrows3D(origins=np.tile(x, (3, 1)), vectors=ax, colors=RGB, radii=[900.0]))
        if Ru is not None:
            rec.log("world/vehicle/unaided", rr.Arrows3D(origins=np.tile(res.unaided_x_e[i], (3, 1)), vectors=Ru[j].T * AXIS_LEN,
                                                         colors=RGB // 2, radii=[600.0]))
        r3 = 3 * sig[ci[j]].max() * AXIS_LEN
        rec.log("world/vehicle/att_3sigma", rr.Ellipsoids3D(centers=x + ax, half_sizes=np.full((3, 3), r3), colors=RGB,
                                                            line_radii=[300.0]))
        s = sun[j] - x
        rec.log("world/vehicle/sun", rr.Arrows3D(origins=[x], vectors=[s / np.linalg.norm(s) * VEC_LEN],
                                                 colors=[[255, 230, 80]], radii=[500.0]))
        f = f_b[fi[j]]
        if np.linalg.norm(f) > 0.7e-3 * 9.80665 and np.linalg.norm(f) < 0.05 * 9.80665:
            rec.log("world/vehicle/rcs", rr.Arrows3D(origins=[x], vectors=[R[j] @ f / np.linalg.norm(f) * AXIS_LEN * 0.7],
                                                     colors=[[255, 0, 255]], radii=[1200.0]))
        else:
            rec.log("world/vehicle/rcs", rr.Clear(recursive=False))
        for n in vt.get(int(t[i]) // NS, []):
            c = int(vectors.camera[n])
            name = {"hor": "earth"}.get(str(vectors.target[n]), str(vectors.target[n]))
            d = R[j] @ R_bc[c] @ vectors.e_c[n]
            rec.log(f"world/vehicle/camera_{cam_numbers[c]}/{name}",
                    rr.Arrows3D(origins=[x], vectors=[d * VEC_LEN], colors=[[0, 220, 255] if name == "earth" else [255, 150, 0]],
                                radii=[500.0]))


def _images(rec, rr, inp, frames, cam_numbers):
    if frames:
        for f in frames:
            if f.k not in cam_numbers:
                continue
            _set_time(rec, inp, f.t_ns)
            st = inp.cameras[f.k].images
            i = int(np.searchsorted(st.t_ns, f.t_ns))
            base = f"camera_{f.k}/image"
            rec.log(base, rr.EncodedImage(contents=st[i], media_type="image/jpeg"))
            for target in ("earth", "sun", "moon"):
                o = f.overlay.get(target, {})
                p = f"{base}/{target}"
                col = [0, 220, 255] if target == "earth" else [255, 150, 0]
                for name, arche in (("edges", lambda a: rr.Points2D(a, colors=[[150, 150, 150]], radii=[1.0])),
                                    ("inliers", lambda a: rr.Points2D(a, colors=[[0, 255, 0]], radii=[1.5])),
                                    ("outliers", lambda a: rr.Points2D(a, colors=[[255, 0, 0]], radii=[1.5])),
                                    ("conic", lambda a: rr.LineStrips2D(_split(a), colors=[col], radii=[1.5])),
                                    ("point", lambda a: rr.Points2D(a, colors=[col], radii=[8.0]))):
                    if name in o and len(o[name]):
                        rec.log(f"{p}/{name}", arche(o[name]))
                    else:
                        rec.log(f"{p}/{name}", rr.Clear(recursive=False))


def _split(poly):
    ok = np.all(np.isfinite(poly), axis=1)
    segs, cur = [], []
    for p, g in zip(poly, ok):
        if g:
            cur.append(p)
        elif cur:
            segs.append(np.array(cur)); cur = []
    if cur:
        segs.append(np.array(cur))
    return [s for s in segs if len(s) > 1]


def _timeseries(rec, rr, inp, res, smooth, cam_numbers):
    # innovations with +-3 sigma (fig. 41) and angle residuals (fig. 42)
    groups = {}
    for inn in res.innovations:
        groups.setdefault(source_name(inn.kind, inn.camera, cam_numbers), []).append(inn)
    for src, lst in groups.items():
        lst = [i for i in lst if np.all(np.isfinite(i.s))]
        if not lst:
            continue
        t = np.array([i.t_ns for i in lst], np.int64)
        s = np.array([i.s for i in lst])
        S = np.array([np.sqrt(np.clip(np.diag(i.S), 0, None)) for i in lst])
        for c in range(s.shape[1]):
            _series(rec, rr, inp, f"innovation/{src}/{c}", t, s[:, c])
            _series(rec, rr, inp, f"innovation/{src}/{c}_+3sigma", t, 3 * S[:, c])
            _series(rec, rr, inp, f"innovation/{src}/{c}_-3sigma", t, -3 * S[:, c])
        if src.startswith("camera_"):
            _series(rec, rr, inp, f"angle_residual/aided/{src}", t, np.degrees(np.linalg.norm(s, axis=1)))
    # unaided angle residuals: predicted with the free-inertial attitude
    if len(res.unaided_q_eb) and hasattr(res, "_vectors_for_view"):
        pass
    # misalignment (fig. 43)
    for c, k in enumerate(cam_numbers):
        if len(res.misalignment_t_ns):
            for a in range(3):
                m = np.degrees(res.misalignment[:, c, a])
                s3 = np.degrees(3 * res.misalignment_sigma[:, c, a])
                _series(rec, rr, inp, f"misalignment/camera_{k}/{AXES[a]}", res.misalignment_t_ns, m)
                _series(rec, rr, inp, f"misalignment/camera_{k}/{AXES[a]}_3sigma", res.misalignment_t_ns, s3)
    # attitude 3 sigma (fig. 40)
    sig = np.degrees(3 * np.sqrt(res.P_diag[:, res.layout["psi"]]))
    for a in range(3):
        _series(rec, rr, inp, f"attitude_3sigma/forward/{AXES[a]}", res.cov_t_ns, sig[:, a])
    if smooth is not None:
        ss = np.degrees(3 * np.sqrt(smooth.P[:, res.layout["psi"]]))
        for a in range(3):
            _series(rec, rr, inp, f"attitude_3sigma/smoothed/{AXES[a]}", smooth.t_ns, ss[:, a])
    ci = res.cov_idx
    if len(res.unaided_q_eb):
        d = np.degrees(attitude_error(res.unaided_q_eb[ci], res.q_eb[ci]))  # aided - unaided, rotation in e
        for a in range(3):
            _series(rec, rr, inp, f"aided_minus_unaided/{AXES[a]}", res.cov_t_ns, d[:, a])
    if len(res.triad_t_ns):
        j = np.clip(np.searchsorted(res.t_ns, res.triad_t_ns), 0, len(res.t_ns) - 1)
        d = np.degrees(matrix_to_rotvec(quat_to_matrix(res.triad_q_eb) @ np.swapaxes(quat_to_matrix(res.q_eb[j]), -1, -2)))
        for a in range(3):
            _series(rec, rr, inp, f"triad_minus_solution/{AXES[a]}", res.triad_t_ns, d[:, a])
    tr = inp.truth
    if tr is not None:
        for name, t, x, v, q in (("forward", res.cov_t_ns, res.x_e[ci], res.v_e[ci], res.q_eb[ci]),
                                 ("smoothed", *(() if smooth is None else (smooth.t_ns, smooth.x_e, smooth.v_e, smooth.q_eb)))):
            if smooth is None and name == "smoothed":
                continue
            j = np.searchsorted(tr.t_ns, t)
            ok = j < tr.t_ns.size
            ok[ok] = tr.t_ns[j[ok]] == t[ok]
            if not ok.any():
                continue
            jj = j[ok]
            psi = np.degrees(attitude_error(q[ok], tr.q_eb[jj]))
            for a in range(3):
                _series(rec, rr, inp, f"error/attitude/{name}/{AXES[a]}", t[ok], psi[:, a])
            _series(rec, rr, inp, f"error/position/{name}", t[ok], np.linalg.norm(x[ok] - tr.x_e[jj], axis=1))
            _series(rec, rr, inp, f"error/velocity/{name}", t[ok], np.linalg.norm(v[ok] - tr.v_e[jj], axis=1))
        # attitude error 3-sigma envelope for comparison
        for a in range(3):
            _series(rec, rr, inp, f"error/attitude/forward/{AXES[a]}_3sigma", res.cov_t_ns, sig[:, a])
