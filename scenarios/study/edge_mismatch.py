"""Model-mismatch study of the Earth's edge height: ATEK flight frames rendered with a limb whose
brightness edge sits at heights the front end does not assume, processed with its defaults.

The renderer's limb air is lifted by ``shift`` (`scenarios.sim.render.RenderOptions.limb_shift_m`),
which moves the threshold edge and the limb's fraction-of-peak crossing by as much; the rendered
effective edge height of the threshold edge is ``NOMINAL_EDGE_M + shift`` (45 km: where the
default threshold cuts the default limb, docs/vision.md). A second limb brightness profile
(`PROFILES`: scale height 6 km, thinner air) changes the profile's shape as well. Per height the
study reports the nadir error against the renderer's truth (RMS, worst), the per-frame 3-sigma
containment of the reported covariance (error <= 3 sqrt(lambda_max(P_c)), the bound the filter's
overbound (003 eq. (37)) uses), and the estimated edge height against the height of the edge
pixels the fit used (their tangent heights from the truth pose; minus the Sun-path shift on the
limb edge, whose rays the front end turns to the overhead-Sun height).

Run: ``python -m scenarios.study.edge_mismatch [--frames N] [--span T0 T1] [--out FILE.json]``; the slow test
tests/test_edge_mismatch.py runs the full study, a fast test a few frames.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scenarios.atomic import atomic_savez, atomic_write_bytes, atomic_write_text

__all__ = ["CACHE_VERSION", "default_cache", "NOMINAL_EDGE_M", "HEIGHTS_M", "PROFILES", "Case", "FrameOutcome", "atek_frames", "run_case",
           "summarise", "run_study", "main"]

#: version of the rendered-frame cache (`default_cache`): raised when the renderer's output changes
#: (2: the twilight Sun path with the erf air mass, the payload drawn by the [render] table)
CACHE_VERSION = 2

#: effective height [m] of the default threshold edge on the default renderer (docs/vision.md)
NOMINAL_EDGE_M = 45e3
#: rendered effective heights of the threshold edge [m]
HEIGHTS_M = (0.0, 10e3, 25e3, 45e3, 60e3)
#: limb brightness profiles: name -> RenderOptions overrides
PROFILES = {"standard": {}, "thin-6km": {"atmosphere_scale_height_m": 6000.0,
                                        "atmosphere_tau": (0.06, 0.10, 0.18)}}


@dataclass(frozen=True)
class Case:
    """One rendering of the flight frames: edge height [m] and limb profile name."""

    height_m: float
    profile: str = "standard"

    @property
    def shift_m(self) -> float:
        return self.height_m - NOMINAL_EDGE_M

    @property
    def name(self) -> str:
        return f"{self.profile}_{self.height_m / 1e3:.0f}km"


def cases(heights=HEIGHTS_M, profiles=tuple(PROFILES), progress: bool = False):
    """The studies' (profile, height) cases in their order; with ``progress`` a progress bar on
    stderr naming the case under way."""
    todo = [Case(float(h), p) for p in profiles for h in heights]
    if not progress:
        yield from todo
        return
    from tqdm import tqdm
    bar = tqdm(todo, unit="case", dynamic_ncols=True)
    for c in bar:
        bar.set_description(c.name)
        yield c


def _not_a_rejection(record) -> bool:
    from nav.updates import REJECTED_MESSAGE
    return record.msg != REJECTED_MESSAGE


def quiet_filter_log() -> None:
    """Keep the filter's per-measurement rejections (a warning per gated vector) off a study's
    terminal: the figures count them, and the progress bar stays readable. The filter's other
    warnings (recoveries, repaired IMU samples) still show: the figures do not hold them."""
    import logging
    logging.getLogger("nav.navigator").addFilter(_not_a_rejection)


@dataclass(frozen=True)
class FrameOutcome:
    """The front end's Earth result on one frame (NaN/None fields when it gave no vector)."""

    t_s: float
    camera: int
    found: bool
    err_deg: float = math.nan
    sigma3_deg: float = math.nan
    edge_m: float = math.nan
    edge_sigma_m: float = math.nan
    edge_truth_m: float = math.nan
    from_arc: bool = False
    path: str = ""
    reason: str = ""


def _flight():
    from scenarios.sim import render
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight

    fl = simulate_flight(load_scenario("atek"), seed=0, duration=431.0, imu_errors=False)
    return fl, render.flight_frame_truths(fl)


def atek_frames(n_frames: int, t0: float = 64.0, t1: float = 430.0):
    """(flight, [(t_s, camera index, FrameTruth)]) for ``n_frames`` frames of the ATEK coast,
    alternating cameras, evenly spread over [t0, t1] s after liftoff."""
    fl, recs = _flight()
    lo = fl.truth.liftoff_ns
    out = []
    for i, t in enumerate(np.linspace(t0, t1, n_frames)):
        k = i % 2
        r = min((q for q in recs if q.camera_index == k), key=lambda q: abs((q.t_ns - lo) * 1e-9 - t))
        out.append((float((r.t_ns - lo) * 1e-9), k, r))
    return fl, out


def _render(case: Case, cam, r, k: int, cache: Path):
    """(jpeg bytes, truth e_c of the Earth) of one frame, cached under ``cache``."""
    from nav import ephemeris
    from scenarios.sim import render

    key = cache / f"{case.name}_{k}_{r.t_ns}"
    jpg, npz = key.with_suffix(".jpg"), key.with_suffix(".npz")
    if not (jpg.exists() and npz.exists()):
        opts = render.RenderOptions(limb_shift_m=case.shift_m, **PROFILES[case.profile])
        fr = render.render_frame(cam, r.R_ec, r.x_e, ephemeris.sun_position_e(r.t_ns),
                                 ephemeris.moon_position_e(r.t_ns), seed=render._frame_seed(0, k, r.t_ns),
                                 options=opts, omega_c=r.omega_c, cloud_seed=0)
        # npz before jpg, each renamed into place: a found jpg means both are whole, also
        # while another process (pytest-xdist's other worker) renders the same frame
        atomic_savez(npz, e_c_earth=fr.e_c_earth)
        atomic_write_bytes(jpg, render.encode_jpeg(fr.image, opts.jpeg_quality))
    return jpg.read_bytes(), np.load(npz)["e_c_earth"]


def _edge_truth(tr, cam, r, shift_sun_m: float) -> float:
    """Median tangent height [m] of the winner's inlier pixels (truth pose) minus the Sun-path
    shift the limb edge turned them by; NaN on the flank and calibrated paths (their rays are
    turned per pixel by fitted heights)."""
    from scenarios.sim.render import ray_ellipsoid
    from vision.camera import unproject

    if tr.points is None or tr.limb_path in ("flank", "calibrated"):
        return math.nan
    uv = tr.points[tr.inlier_mask]
    rays_e = unproject(cam, uv) @ np.asarray(r.R_ec).T
    _, _, h_t = ray_ellipsoid(np.asarray(r.x_e, float), rays_e)
    return float(np.median(h_t)) - shift_sun_m


def run_case(case: Case, frames, cam, mask, config, cache: Path) -> list[FrameOutcome]:
    """The front end (``config``, the full prior the replay gives: truth position and attitude,
    predicted Sun) on the frames of ``case``, with each camera's limb edge height offset learned
    over the frames as the replay does (`vision.limb_offset.refine_limb_height`)."""
    from nav import ephemeris
    from scenarios.flightlog.jpeg import decode_frame
    from vision.frontend import FramePrior, process_frame
    from vision.limb_offset import limb_edge, refine_limb_height

    runs = []
    rng = np.random.default_rng(0)
    for t_s, k, r in frames:
        jpg, e_true = _render(case, cam, r, k, cache)
        prior = FramePrior(r.x_e, r.R_ec, sun_c=r.R_ec.T @ ephemeris.sun_direction_e(r.t_ns, r.x_e))
        runs.append((t_s, k, r, e_true, process_frame(decode_frame(jpg), cam, config, mask=mask, prior=prior,
                                                      rng=rng, camera_id=k)))
    fits = [(res.record("earth"), limb_edge(res.targets.get("earth"))) for *_, res in runs
            if res.record("earth") is not None]
    refined = dict(zip([id(f[0]) for f in fits], refine_limb_height(fits, config.earth.edge)[0]))
    out = []
    for t_s, k, r, e_true, res in runs:
        rec = res.record("earth")
        rec = refined.get(id(rec), rec)
        if rec is None:
            out.append(FrameOutcome(t_s, k, False, reason=res.reasons.get("earth", "")))
            continue
        tr = res.targets["earth"]
        err = math.degrees(math.acos(min(1.0, float(rec.e_c @ e_true))))
        sig3 = 3.0 * math.degrees(math.sqrt(float(np.linalg.eigvalsh(rec.P_c)[-1])))
        out.append(FrameOutcome(t_s, k, True, err, sig3, rec.edge_height_m, rec.edge_height_sigma_m,
                                _edge_truth(tr, cam, r, tr.limb_shift_m if tr.limb_path == "limb" else 0.0),
                                bool(tr.edge_from_arc), tr.limb_path or "threshold"))
    return out


def summarise(case: Case, outcomes: list[FrameOutcome]) -> dict:
    """Per-case figures: frames, found, frames rejected as a wrong edge (`vision.edge_check`;
    counted as not found), nadir RMS / max [deg], 3-sigma containment over the found frames, edge
    height error (estimate - truth of the edge used) RMS [km] and its normalised RMS,
    arc-constrained fraction, paths used."""
    ok = [o for o in outcomes if o.found]
    err = np.array([o.err_deg for o in ok])
    inside = np.array([o.err_deg <= o.sigma3_deg for o in ok])
    dh = np.array([o.edge_m - o.edge_truth_m for o in ok if math.isfinite(o.edge_truth_m)])
    dz = np.array([(o.edge_m - o.edge_truth_m) / o.edge_sigma_m for o in ok
                   if math.isfinite(o.edge_truth_m) and o.edge_sigma_m > 0])
    paths: dict[str, int] = {}
    for o in ok:
        paths[o.path] = paths.get(o.path, 0) + 1
    return dict(case=case.name, profile=case.profile, height_km=case.height_m / 1e3, frames=len(outcomes),
                found=len(ok), wrong_edge=sum("two arcs" in o.reason for o in outcomes), nadir_rms_deg=float(np.sqrt(np.mean(err**2))) if ok else math.nan,
                nadir_max_deg=float(err.max()) if ok else math.nan,
                containment=float(inside.mean()) if ok else math.nan,
                edge_err_rms_km=float(np.sqrt(np.mean(dh**2)) / 1e3) if dh.size else math.nan,
                edge_err_mean_km=float(np.mean(dh) / 1e3) if dh.size else math.nan,
                edge_nrms=float(np.sqrt(np.mean(dz**2))) if dz.size else math.nan,
                edge_est_median_km=float(np.median([o.edge_m for o in ok]) / 1e3) if ok else math.nan,
                edge_truth_median_km=float(np.median([o.edge_truth_m for o in ok if math.isfinite(o.edge_truth_m)]) / 1e3)
                if dh.size else math.nan,
                from_arc=float(np.mean([o.from_arc for o in ok])) if ok else math.nan, paths=paths)


def default_cache() -> Path:
    """The rendered frames' cache directory: the temporary directory's
    horizon-nav-edge-mismatch-<`CACHE_VERSION`>."""
    return Path(tempfile.gettempdir()) / f"horizon-nav-edge-mismatch-{CACHE_VERSION}"


def run_study(n_frames: int = 48, heights=HEIGHTS_M, profiles=tuple(PROFILES), config=None,
              cache: Path | None = None, span_s: tuple = (64.0, 430.0), progress: bool = False) -> list[dict]:
    """`summarise` of every (profile, height) case on ``n_frames`` ATEK frames spread over
    ``span_s`` = (t0, t1) [s after liftoff] (`atek_frames`) with the front end's defaults (or
    ``config``). Rendered frames are cached under ``cache`` (default: `default_cache`);
    ``progress``: a progress bar, and a note when the cache is empty."""
    from scenarios.sim import render
    from vision import mask as vmask
    from vision.config import default_config

    fl, frames = atek_frames(n_frames, *span_s)
    cam = fl.cameras[0].camera
    config = default_config(cam.fx) if config is None else config
    mask = vmask.from_binary(render.payload_mask(cam, render.DEFAULT_PAYLOAD_MASK))
    cache = default_cache() if cache is None else cache
    cache.mkdir(parents=True, exist_ok=True)
    if progress and not any(cache.iterdir()):
        print(f"first run: rendering the frames into {cache} (minutes; later runs read them from there)",
              file=sys.stderr, flush=True)
    return [summarise(case, run_case(case, frames, cam, mask, config, cache))
            for case in cases(heights, profiles, progress)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m scenarios.study.edge_mismatch",
                                 description="Edge-height model-mismatch study on rendered ATEK frames.")
    ap.add_argument("--frames", type=int, default=48, help="frames over the coast (default 48)")
    ap.add_argument("--span", type=float, nargs=2, default=(64.0, 430.0), metavar=("T0", "T1"),
                    help="frames spread over T0..T1 s after liftoff (default 64 430; the 40 held-out "
                         "frames: --frames 40 --span 68 426)")
    ap.add_argument("--out", type=Path, help="write the per-case figures as JSON here")
    a = ap.parse_args(argv)
    if a.frames < 2:
        ap.error(f"--frames {a.frames}: expected at least 2")
    if not a.span[0] < a.span[1]:
        ap.error(f"--span {a.span[0]:g} {a.span[1]:g}: expected T0 < T1")
    rows = run_study(a.frames, span_s=tuple(a.span), progress=True)
    print(f"{'case':<18}{'found':>7}{'wrong':>6}{'RMS deg':>9}{'max deg':>9}{'3sig in':>9}{'h est km':>10}"
          f"{'h true km':>10}{'dh rms km':>10}{'arc':>6}")
    for r in rows:
        print(f"{r['case']:<18}{r['found']:>4}/{r['frames']:<2}{r['wrong_edge']:>6}{r['nadir_rms_deg']:>9.4f}{r['nadir_max_deg']:>9.4f}"
              f"{r['containment']:>9.3f}{r['edge_est_median_km']:>10.1f}{r['edge_truth_median_km']:>10.1f}"
              f"{r['edge_err_rms_km']:>10.2f}{r['from_arc']:>6.2f}  {r['paths']}")
    if a.out:
        atomic_write_text(a.out, json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
