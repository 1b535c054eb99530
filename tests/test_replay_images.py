"""Replay with vision from images on a short rendered log (atek T+0..T+64: both cameras at 1 Hz from
T+60, 10 frames): the worker pool gives the in-process result, the geocentric correction is exact
on its model, the vectors given to the filter match the camera truth frame by frame (stamps,
camera numbering and mounts), the recording holds the images and overlays, and a camera without
CameraInfo is a clear error."""
import subprocess
import sys
from pathlib import Path

import threading
import types

import numpy as np
import pytest

from scenarios.errors import UserError
from tests.test_replay import _copy_without, _opt

ROOT = Path(__file__).resolve().parents[1]
RERUN = str(Path(sys.executable).parent / "rerun")


def test_pool_matches_in_process(ilog):
    """Forked workers reading the frames from the log by index (chunks of 2), the same jobs with the
    JPEG bytes shipped, and the in-process path give identical vectors (each frame's RANSAC is
    seeded by its stamp, so the result cannot depend on where it runs)."""
    from scenarios.replay.inputs import load_inputs
    from scenarios.replay.vision_worker import FrameJob, run_vision
    from scenarios.config.vision import load_vision_config
    inp = load_inputs(ilog)
    cams = {k: c.camera for k, c in inp.cameras.items()}
    cfg = load_vision_config(None, camera=inp.cameras[1].camera)
    streams = {k: c.images for k, c in inp.cameras.items()}
    jobs = sorted((int(c.images.t_ns[i]), k, i) for k, c in inp.cameras.items() for i in range(len(c.images)))
    by_index = [FrameJob(k, i, t, None, 65e3, np.radians(68.0)) for t, k, i in jobs]
    with_bytes = [FrameJob(k, i, t, streams[k][i], 65e3, np.radians(68.0)) for t, k, i in jobs]
    done = []
    a = run_vision(by_index, cams, cfg, workers=1, images=streams)
    b = run_vision(by_index, cams, cfg, workers=2, chunk_size=2, images=streams, progress=done.append)
    c = run_vision(with_bytes, cams, cfg, workers=2, chunk_size=2)
    assert sum(done) == len(jobs) == len(a) == len(b) == len(c)
    n_rec = 0
    for x, y, z in zip(a, b, c):
        assert (x.k, x.t_ns) == (y.k, y.t_ns) == (z.k, z.t_ns)
        assert [r.target for r in x.records] == [r.target for r in y.records] == [r.target for r in z.records]
        for r, s, u in zip(x.records, y.records, z.records):
            np.testing.assert_array_equal(r.e_c, s.e_c)
            np.testing.assert_array_equal(r.e_c, u.e_c)
            n_rec += 1
    assert n_rec >= len(jobs) // 2           # the horizon is in view from T+60 on
    with pytest.raises(ValueError, match="no JPEG bytes"):
        run_vision(by_index, cams, cfg, workers=1)


def test_overlay_conic_is_the_visible_horizon(ilog):
    """The overlay's Earth conic is the cone of the visible horizon about the vector: unprojected,
    its points make the median angle of the front end's inliers with the vector (within 1e-4 rad:
    the inlier overlay is a subsample of ~600 pixels, whose median scatters ~2e-5 rad, and the
    points are float32 pixels), and it runs along the inlier pixels (median distance < 2.5 px; the
    horizon of the ellipsoid is not exactly a circular cone about the geocentric nadir). With the
    attitude prior the vector is the geocentric nadir of the ellipsoid model, whose cone angle
    (the record's alpha) differs from the visible horizon's by up to ~1e-3 rad on these frames."""
    from nav import earth
    from nav.rotation import quat_to_matrix
    from scenarios.replay.inputs import load_inputs
    from scenarios.replay.vision_worker import FrameJob, run_vision
    from scenarios.config.vision import load_vision_config
    from vision.camera import unproject
    inp = load_inputs(ilog)
    cams = {k: c.camera for k, c in inp.cameras.items()}
    cfg = load_vision_config(None, camera=inp.cameras[1].camera)
    streams = {k: c.images for k, c in inp.cameras.items()}
    tr = inp.truth
    jobs = []
    for k, c in inp.cameras.items():
        for i in range(len(c.images)):
            t = int(c.images.t_ns[i])
            j = int(np.searchsorted(tr.t_ns, t))
            lat, _, h = earth.ecef_to_geodetic(tr.x_e[j][None])
            jobs.append(FrameJob(k, i, t, None, float(h[0]), float(lat[0]), x_e=tr.x_e[j],
                                 R_ec=quat_to_matrix(tr.q_eb[j]) @ c.R_bc))
    n = 0
    for f in run_vision(jobs, cams, cfg, workers=1, images=streams):
        o = f.overlay.get("earth", {})
        if "conic" not in o:
            continue
        e_c = next(r.e_c for r in f.records if r.target == "earth")
        poly = o["conic"][np.all(np.isfinite(o["conic"]), axis=1)].astype(float)

        def angles(px):
            return np.arccos(np.clip(unproject(cams[f.k], px) @ e_c, -1, 1))
        assert abs(np.median(angles(poly)) - np.median(angles(o["inliers"].astype(float)))) < 1e-4, (f.k, f.t_ns)
        seg_a, d = poly[:-1], poly[1:] - poly[:-1]
        p = o["inliers"].astype(float)[:, None, :]
        u = np.clip(np.sum((p - seg_a) * d, axis=-1) / np.maximum(np.sum(d * d, axis=-1), 1e-12), 0, 1)
        dist = np.linalg.norm(p - (seg_a + u[..., None] * d), axis=-1).min(axis=1)
        assert np.median(dist) < 2.5, (f.k, f.t_ns, np.median(dist))
        n += 1
    assert n >= len(jobs) // 2


def test_geocentric_correction_is_exact_on_its_model():
    """A substitute-sphere nadir that points exactly along the geodetic normal (-n) becomes exactly
    the geocentric nadir -x/|x| (003 eq. (39)), for any camera attitude; the correction is the
    angle between the two normals (0.19 deg at 45 deg latitude, 0 at the pole and the equator)."""
    from nav import earth
    from nav.rotation import rotvec_to_matrix
    from scenarios.replay.vision_worker import geocentric_correction
    rng = np.random.default_rng(1)
    lat = np.radians([0.0, 45.0, 67.9, 89.9, -30.0])
    lon = np.radians([10.0, -100.0, 21.1, 0.0, 150.0])
    x = earth.geodetic_to_ecef(lat, lon, np.full(5, 150e3))
    n = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)
    R_ce = rotvec_to_matrix(rng.normal(size=(5, 3)))
    e_sphere = np.einsum("nij,nj->ni", R_ce, -n)
    e = geocentric_correction(e_sphere, x, R_ce)
    want = np.einsum("nij,nj->ni", R_ce, -x / np.linalg.norm(x, axis=1, keepdims=True))
    np.testing.assert_allclose(e, want, atol=1e-15)
    moved = np.degrees(np.arccos(np.clip(np.sum(e * e_sphere, 1), -1, 1)))
    assert moved[0] < 1e-6 and 0.15 < moved[1] < 0.2


def test_image_replay_vectors_and_recording(ilog, tmp_path):
    """The vectors the replay gives the filter against /camera_<k>/truth: every stamp matched and
    errors of a vision front end (a camera-number or mount mix-up would give tens of degrees:
    the two cameras look 180 deg apart in azimuth); the recording holds images and overlays."""
    from scenarios.replay.pipeline import replay
    from scenarios.replay.summary import format_table, summarize
    rrd = tmp_path / "i.rrd"
    rr = replay(ilog, _opt(output=str(tmp_path / "i.solution.mcap"), rrd=str(rrd), workers=2, smoother=False))
    assert rr.vision_mode == "images" and len(rr.frames) == 10
    s = summarize(rr)
    ve = s["vector_errors"]
    assert {"camera_1/earth", "camera_2/earth"} <= set(ve)
    for k, d in ve.items():
        assert d["unmatched"] == 0, k
        assert d["median_deg"] < 3.0, (k, d)
    assert "against the camera truth" in format_table(s)
    assert rr.cpu_timings.keys() == rr.timings.keys()
    out = subprocess.run([RERUN, "rrd", "print", str(rrd)], capture_output=True, text=True).stdout
    for path in ("/camera_1/image", "/camera_1/image/earth/conic", "/camera_1/image/earth/inliers",
                 "/angle_residual/unaided/camera_1/earth", "/angle_residual/aided/camera_1/earth",
                 "/world/vehicle/camera_2/earth", "/triad_minus_unaided/x"):
        assert path in out, path


def test_cameras_without_camera_info(ilog, tmp_path):
    """Images but no CameraInfo: a UserError naming the camera and the topic, with what can still be
    done; leaving that camera out (--cameras 2) replays."""
    from scenarios.replay.pipeline import replay
    p = tmp_path / "noinfo.mcap"
    _copy_without(ilog, p, ["/camera_1/camera_info"])
    with pytest.raises(UserError, match=r"camera 1 has images but no /camera_1/camera_info.*--cameras"):
        replay(p, _opt(output=str(tmp_path / "n.solution.mcap")))
    rr = replay(p, _opt(output=str(tmp_path / "n2.solution.mcap"), cameras=[2], init="truth", smoother=False))
    assert rr.cam_numbers == [2] and rr.vision_mode == "images"


def test_vision_rate_decimates_frames():
    """--vision-rate: the first frame of every 1/rate bucket from the window start (30 frames/s at
    5 Hz: every 6th frame); without it every frame in the window."""
    from scenarios.replay.inputs import frames_in as _frames_in
    t0 = 10 ** 18
    t = t0 + np.round(np.arange(91) * 1e9 / 30).astype(np.int64)
    np.testing.assert_array_equal(_frames_in(t, t0, t0 + 3 * 10 ** 9, 5.0), np.arange(0, 91, 6))
    assert _frames_in(t, t0, t0 + 3 * 10 ** 9).size == 91
    assert _frames_in(t, t0 + 10 ** 9, t0 + 2 * 10 ** 9, 1.0).tolist() == [30, 60]


def test_interrupt_during_vision_keeps_processed_frames(ilog, tmp_path, monkeypatch):
    """Ctrl-C during the vision stage (in-process, at the 5th frame): a valid partial solution log
    with the vectors of the 4 frames processed, marked incomplete with a reason that says so."""
    from scenarios.flightlog.reader import read_log
    from scenarios.replay import vision_worker
    from scenarios.replay.pipeline import replay
    calls = []
    real = vision_worker.process_one

    def once_too_often(job, *a, **k):
        calls.append(job.t_ns)
        if len(calls) == 5:
            raise KeyboardInterrupt
        return real(job, *a, **k)
    monkeypatch.setattr(vision_worker, "process_one", once_too_often)
    out = tmp_path / "p.solution.mcap"
    with pytest.raises(KeyboardInterrupt):
        replay(ilog, _opt(output=str(out), workers=1, init="truth"))
    log = read_log(out)
    assert log.complete is False
    reason = log.metadata["horizon-nav.status"]["reason"]
    assert reason.startswith("KeyboardInterrupt during vision") and "frames processed so far" in reason
    stamps = set()
    for k in (1, 2):
        s = log.cameras[k].vectors if k in log.cameras else None
        if s is not None:
            stamps |= set(np.asarray(s.t_ns).tolist())
    assert stamps and stamps <= set(calls[:4])


def test_triad_search_then_every_frame_with_the_attitude_prior(ilog, tmp_path, monkeypatch):
    """Default initialisation on an image log: a sparse TRIAD search without attitude (the first
    frame per camera and TRIAD_SEARCH_DT_S interval), then every frame of the window once with the
    free-inertial attitude as prior, which gives the ellipsoid Earth model (geocentric nadir, 003
    eq. (39)) and a predicted Sun direction. The prior is within a few degrees of the truth."""
    from nav.rotation import quat_to_matrix
    from scenarios.replay import pipeline, vision_worker
    from scenarios.replay.inputs import load_inputs
    jobs = []
    real = vision_worker.process_one

    def spy(job, *a, **k):
        jobs.append(job)
        return real(job, *a, **k)
    monkeypatch.setattr(vision_worker, "process_one", spy)
    rr = pipeline.replay(ilog, _opt(output=str(tmp_path / "t.solution.mcap"), workers=1, smoother=False))
    search = [j for j in jobs if j.R_ec is None]
    prior = [j for j in jobs if j.R_ec is not None]
    # 10 frames (T+60..T+64, 2 cameras); search: per camera the buckets [60, 65) -> 1 frame each
    assert len(prior) == 10 and len(search) == 2
    assert all(r.model == "ellipsoid" for f in rr.frames for r in f.records if r.target == "earth")
    inp = load_inputs(ilog)
    tr = inp.truth
    for j in prior:
        i = int(np.argmin(np.abs(tr.t_ns - j.t_ns)))
        R_ec_true = quat_to_matrix(tr.q_eb[i]) @ inp.cameras[j.k].R_bc
        d = np.degrees(np.arccos(np.clip((np.trace(R_ec_true.T @ j.R_ec) - 1) / 2, -1, 1)))
        assert d < 5.0, d   # TRIAD/truth start + free-inertial drift + the nominal mounting (1 deg/axis)


def test_spawned_workers_match(ilog, monkeypatch):
    """Where fork is missing (spawn): the JPEG bytes travel with the jobs and each worker loads the
    front end once; same vectors as in-process."""
    from scenarios.replay import vision_worker as vw
    from scenarios.replay.inputs import load_inputs
    from scenarios.config.vision import load_vision_config
    inp = load_inputs(ilog)
    c = inp.cameras[1]
    cfg = load_vision_config(None, camera=c.camera)
    jobs = [vw.FrameJob(1, i, int(c.images.t_ns[i]), None, 65e3, np.radians(68.0)) for i in range(len(c.images))]
    a = vw.run_vision(jobs, {1: c.camera}, cfg, workers=1, images={1: c.images})
    monkeypatch.setattr(vw, "_fork_context", lambda: None)
    b = vw.run_vision(jobs, {1: c.camera}, cfg, workers=2, chunk_size=2, images={1: c.images})
    assert [x.t_ns for x in a] == [x.t_ns for x in b]
    for x, y in zip(a, b):
        assert len(x.records) == len(y.records)
        for r, s in zip(x.records, y.records):
            np.testing.assert_array_equal(r.e_c, s.e_c)


def test_sun_search_skipped_only_outside_the_field_of_view():
    """The Sun is not searched when its predicted direction lies farther from the optical axis than
    the widest angle in the image (fov_theta, the image corners) plus the Sun gate; just inside
    that, and without a prediction, it is searched."""
    import math

    from scenarios.replay.vision_worker import sun_out_of_view
    from scenarios.config.vision import load_vision_config
    from vision.camera import atek_camera
    cam = atek_camera()
    cfg = load_vision_config(None, camera=cam)
    limit = math.degrees(cam.fov_theta) + cfg.sun.gate_deg
    assert 60.0 < limit < 70.0      # 53.5 deg to the corners + 10 deg gate

    def at(deg):
        a = math.radians(deg)
        return np.array([math.sin(a), 0.0, math.cos(a)])
    for deg, skipped in ((0.0, False), (limit - 0.5, False), (limit + 0.5, True), (120.0, True)):
        c, why = sun_out_of_view(cfg, cam, at(deg))
        assert (not c.sun.enabled) is skipped and bool(why) is skipped, deg
        assert c.earth == cfg.earth
    assert sun_out_of_view(cfg, cam, None) == (cfg, {})


def test_payload_mask_from_the_log_and_from_a_file(ilog, tmp_path):
    """The simulator writes each camera's payload mask (/camera_<k>/payload_mask, PNG) exactly as the
    renderer draws the payload; the replay gives it to the edge search. --mask K=FILE replaces it;
    a mask of the wrong size, an unreadable file or a camera that is not replayed is a clear error."""
    import cv2

    from scenarios.sim import render
    from scenarios.replay.inputs import load_inputs
    from functools import partial

    from scenarios.replay.inputs import CLI
    from scenarios.replay.pipeline import replay
    from scenarios.replay.sight import payload_masks
    _payload_masks = partial(payload_masks, wording=CLI)     # messages worded as the command line's
    inp = load_inputs(ilog)
    for k, c in inp.cameras.items():
        want = render.payload_mask(c.camera, render.DEFAULT_PAYLOAD_MASK)
        assert c.mask is not None and c.mask.shape == (c.camera.height, c.camera.width)
        np.testing.assert_array_equal(c.mask, want)
        assert 0.01 < c.mask.mean() < 0.2       # a strip at the image edge
    masks = _payload_masks(inp, [1, 2], {})
    assert set(masks) == {1, 2}
    np.testing.assert_array_equal(masks[2].mask, inp.cameras[2].mask)
    # a file replaces the log's mask
    f = tmp_path / "m.png"
    half = np.zeros_like(inp.cameras[2].mask, np.uint8)
    half[:, -300:] = 255
    cv2.imwrite(str(f), half)
    np.testing.assert_array_equal(_payload_masks(inp, [1, 2], {2: f})[2].mask, half > 0)
    cv2.imwrite(str(tmp_path / "small.png"), half[:100, :100])
    with pytest.raises(UserError, match=r"--mask 2=.*small.png: 100x100 px, expected camera 2's 1920x1080"):
        _payload_masks(inp, [1, 2], {2: tmp_path / "small.png"})
    with pytest.raises(UserError, match="not a readable image"):
        _payload_masks(inp, [1, 2], {2: tmp_path / "missing.png"})
    with pytest.raises(UserError, match=r"camera\(s\) \[3\] are not replayed"):
        _payload_masks(inp, [1, 2], {3: f})
    rr = replay(ilog, _opt(output=str(tmp_path / "m.solution.mcap"), workers=1, smoother=False, init="truth",
                           masks={2: str(f)}))
    assert len(rr.frames) == 10


def test_mask_option_syntax():
    import argparse

    from scenarios.cli import replay as cmd
    p = argparse.ArgumentParser()
    cmd.add_arguments(p)
    assert cmd.options_from_args(p.parse_args(["f.mcap", "--mask", "2=a.png", "--mask", "1=b.png"])).masks == \
        {2: "a.png", 1: "b.png"}
    for bad in ("a.png", "x=a.png", "2="):
        with pytest.raises(UserError, match="expected K=FILE"):
            cmd.options_from_args(p.parse_args(["f.mcap", "--mask", bad]))


def test_recording_image_rate(ilog, tmp_path):
    """--rrd-image-rate thins the images and overlays in the recording to the first frame per
    interval and camera; the vectors given to the filter are those of every frame."""
    from scenarios.replay import rerun_view
    from scenarios.replay.pipeline import replay
    from scenarios.replay.vision_worker import FrameOutput
    t0 = 10 ** 18
    frames = [FrameOutput(k, t0 + i * 10 ** 9 // 3 + k, [], {}, {}, {}) for i in range(9) for k in (1, 2)]
    kept = rerun_view._every(frames, [1, 2], 1.0)       # 3 frames/s -> 1 per second and camera
    assert sorted((f.k, f.t_ns) for f in kept) == sorted((k, t0 + i * 10 ** 9 // 3 + k) for i in (0, 3, 6) for k in (1, 2))
    rrd = tmp_path / "r.rrd"
    rr = replay(ilog, _opt(output=str(tmp_path / "r.solution.mcap"), rrd=str(rrd), workers=1, smoother=False,
                           init="truth", rrd_image_rate_hz=0.5))
    assert len(rr.frames) == 10 and rrd.stat().st_size > 0
    with pytest.raises(UserError, match="--rrd-image-rate"):
        replay(ilog, _opt(output=str(tmp_path / "x.solution.mcap"), rrd_image_rate_hz=0.0))


def _entity_times(rrd, suffix) -> dict:
    """entity path -> sorted mission times of its rows, for the entities ending in ``suffix``."""
    from rerun.chunk import RrdReader
    out: dict = {}
    for ch in RrdReader(str(rrd)).store().stream():
        if ch.entity_path.endswith(suffix) and not ch.is_static:
            out.setdefault(ch.entity_path, []).extend(ch.to_record_batch().column("mission_time").to_numpy().tolist())
    return {k: sorted(v) for k, v in out.items()}


def test_overlays_drawn_in_parts_match_the_shown_images(ilog, tmp_path, monkeypatch):
    """The recording process draws the overlays in parts as the frames come (here every 3 frames,
    with the images thinned to 0.5 per second): each camera's overlay rows are at exactly the times
    of its shown images, the same rows as drawn in one part."""
    from scenarios.replay import recording_process
    from scenarios.replay.pipeline import replay
    got = {}
    for batch in (3, 10_000):
        monkeypatch.setattr(recording_process, "OVERLAY_BATCH", batch)
        rrd = tmp_path / f"b{batch}.rrd"
        replay(ilog, _opt(output=str(tmp_path / f"b{batch}.solution.mcap"), rrd=str(rrd), workers=2, smoother=False,
                          init="truth", rrd_image_rate_hz=0.5))
        images = _entity_times(rrd, "/image")
        inliers = _entity_times(rrd, "/earth/inliers")
        assert images and inliers
        for path, t in inliers.items():
            assert t == images[path.removesuffix("/earth/inliers")], path
        got[batch] = (images, inliers)
    assert got[3] == got[10_000]


def test_chunks_partition_the_jobs_in_order():
    """The vision tasks cover every job once, in order, none larger than the chunk size, and the
    tail of 2 x workers x size frames is split into quarter-size tasks."""
    from scenarios.replay.vision_worker import _chunks
    for n in range(0, 120, 7):
        for size in (1, 2, 16):
            for workers in (1, 2, 3):
                c = _chunks(list(range(n)), size, workers)
                assert sum(c, []) == list(range(n))
                assert all(0 < len(x) <= size for x in c)
    c = _chunks(list(range(100)), 16, 2)
    assert [len(x) for x in c] == [16, 16, 4] + [4] * 16


def _recorded_images(rrd, cams) -> dict:
    """camera -> the JPEG bytes of its ``camera_<k>/image`` rows in a recording, in time order,
    read with Rerun's own reader."""
    from rerun.chunk import RrdReader
    rows = {k: [] for k in cams}
    for ch in RrdReader(str(rrd)).store().stream():
        for k in cams:
            if ch.entity_path == f"/camera_{k}/image" and not ch.is_static:
                rb = ch.to_record_batch()
                t = rb.column("mission_time").to_numpy()
                col = rb.column("EncodedImage:blob").to_pylist()
                rows[k] += [(t[i], bytes(col[i][0])) for i in range(len(t))]
    return {k: [b for _, b in sorted(v, key=lambda r: r[0])] for k, v in rows.items()}


def test_recording_images_in_batches_are_the_logs_bytes(ilog, tmp_path, monkeypatch):
    """Images sent in batches of ~2 frames (bounded memory for long video logs, Rerun flushed
    between batches): the recording read back with Rerun's own reader holds every frame's JPEG
    bytes of the log, byte for byte, in time order. Abandoned, the recording process leaves no file."""
    from scenarios.replay import rerun_view
    from scenarios.replay.pipeline import replay
    from scenarios.replay.recording_process import RecordingProcess
    from scenarios.replay.inputs import load_inputs
    inp = load_inputs(ilog)
    limit = int(2.5 * max(c.images.sizes.max() for c in inp.cameras.values()))
    monkeypatch.setattr(rerun_view, "IMAGE_BATCH_BYTES", limit)
    rrd = tmp_path / "b.rrd"
    rr = replay(ilog, _opt(output=str(tmp_path / "b.solution.mcap"), rrd=str(rrd), workers=1, smoother=False,
                           init="truth"))
    cams = rr.cam_numbers
    batches = rerun_view.image_batches(rr.inputs, rr.frames, cams)
    assert len(batches) == 5 and sum(len(b) for b in batches) == len(rr.frames) == 10
    want = {}
    for k in cams:
        st = inp.cameras[k].images
        want[k] = [st[int(np.searchsorted(st.t_ns, x))] for x in sorted(f.t_ns for f in rr.frames if f.k == k)]
    assert _recorded_images(rrd, cams) == want
    # the recording process abandoned while it sends the images: it ends, its file is deleted
    jobs = [types.SimpleNamespace(k=f.k, t_ns=f.t_ns) for f in rr.frames]
    rec = RecordingProcess()
    rec.setup(rr.inputs, cams, tmp_path / "p.rrd")
    rec.begin(jobs)
    rec.abandon()
    assert not list(tmp_path.glob("*p.rrd*"))
    # begin told to stop (the replay interrupted): it stops sending, the file is deleted
    stop = threading.Event()
    stop.set()
    with pytest.raises(rerun_view.RecordingStopped):
        rerun_view.begin(rr.inputs, jobs, cams, tmp_path / "t.rrd", stop=stop)
    assert not list(tmp_path.glob(".t.rrd*")) and not (tmp_path / "t.rrd").exists()



def test_image_sends_read_a_few_chunks_at_a_time(tmp_path):
    """The recording's image sends (rerun_view.image_sends) give every frame's JPEG bytes once, at
    most IMAGES_PER_SEND per send, each send's times in order; the frames are read group by group,
    so the peak of Python-allocated memory stays near a group's chunks, not the 12 MB of the log's
    images (each image views its decompressed chunk: reading a whole batch first held every chunk
    of the log, 267 MB for the 30 s video)."""
    import hashlib
    import tracemalloc
    from scenarios.flightlog.reader import read_log
    from scenarios.replay import rerun_view
    from tests.test_log_format import _image_log
    path = tmp_path / "img.mcap"
    _, _, _, imgs = _image_log(path)
    log = read_log(path)
    inp = types.SimpleNamespace(cameras={k: types.SimpleNamespace(images=log.images[k]) for k in (1, 2)})
    frames = [types.SimpleNamespace(k=k, t_ns=int(t)) for k in (1, 2) for t in log.images[k].t_ns]
    list(rerun_view.image_sends(inp, frames[:4], [1, 2]))     # imports before the measurement
    got = {1: [], 2: []}
    tracemalloc.start()
    try:
        for k, t, blobs in rerun_view.image_sends(inp, frames, [1, 2]):
            assert 0 < len(blobs) == len(t) <= rerun_view.IMAGES_PER_SEND and np.all(np.diff(t) > 0)
            got[k] += [(int(x), hashlib.sha1(b).hexdigest()) for x, b in zip(t, blobs)]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # a group is 2 x 8 images of ~100 kB in chunks of ~310 kB: ~6 chunks, ~1.9 MB
    assert peak < 4_000_000, peak
    for k, want in ((1, imgs[0::2]), (2, imgs[1::2])):
        assert [x for x, _ in got[k]] == log.images[k].t_ns.tolist()
        assert [h for _, h in got[k]] == [hashlib.sha1(b).hexdigest() for b in want]
