"""Model-mismatch study of the Earth's edge height on a full flight: the pinhole-orbit scenario
(scenarios/library/pinhole-orbit.toml, a 25 deg pinhole at 500 km with the half-lit Moon in view
for part of the pass) simulated, rendered with the limb's brightness edge at heights the front end
does not assume, and replayed end to end (vision on the images, filter, smoother) with the front
end's defaults plus the Moon and the tuning scenarios/library/tuning/pinhole-orbit.toml (the edge
height a filter state, `[states.edge_height] mode = "E"`, describing the threshold edge: `edge =
"threshold"`, docs/vision.md "Which edge the state describes").

The renderer's limb air is lifted by ``height - NOMINAL_EDGE_M`` (`edge_mismatch.Case`,
`scenarios.sim.render.RenderOptions.limb_shift_m`); a second brightness profile (thin-6km) changes
its shape. The figures of one case (`flight_figures`):

* ``edge_truth_km``: the edge height the rendered frames' fits have, from the truth: the filter's
  measurement model ``e_c = e_true + g (h - h_ref)`` (g = ``dedge_c``, docs/vision.md; ``h_ref``
  the height the vision fitted at) solved for h by least squares over the frames with the
  simulator's true nadir; ``edge_render_km`` the
  nominal rendered height ``NOMINAL_EDGE_M + shift`` (the ATEK fisheye's threshold edge);
* ``edge_smoothed_km`` and its 1 sigma: the smoother's ``h_e``;
* ``nadir_rms_raw_deg``: the Earth vectors (fitted at the vision's prior height) against the true
  nadir; ``nadir_rms_deg``: the same vectors moved to the smoothed height (``- g (h_s - h_ref)``;
  frames whose vector carries no sensitivity, ``frames - frames_with_sensitivity``, stay as they are);
  split into ``nadir_rms_state_deg`` (the frames with the sensitivity, moved) and
  ``nadir_rms_other_deg`` (those without: on the ATEK fisheye, frames whose limb edge is unusable,
  twilight mostly, fall back to the threshold edge, which a state describing the limb edge does not
  describe); ``nadir_rms_fits_height_deg``: the frames with the sensitivity moved to
  ``edge_truth_km`` instead, what one height per camera can do at best;
* ``containment_prior``: per-frame 3-sigma containment of the raw vectors with the height
  uncertainty the vision had (``P_c + sigma_ref^2 g g^T``, ``sigma_ref`` = ``edge_ref_sigma_m``:
  before anything is learned); ``containment``: of the
  moved vectors with the smoothed height's (``P_c + sigma_s^2 g g^T``), both against
  ``3 sqrt(lambda_max)``;
* ``nees_in_band``: fraction of the forward filter's measurement epochs whose attitude NEES
  ``psi^T P_psi^-1 psi`` (3 dof) is inside the chi-square 95 % band [0.216, 9.35], over the flight
  and from the first Moon vector on (``nees_in_band_moon``: before it the rotation about the
  nadir is seen by no vector, and a filter started at the truth has an error far inside its
  2 deg initial sigma); ``nees_above_band``: the fraction above it (the filter optimistic);
  ``nees_mean``;
* ``att_rms_forward_deg``, ``att_rms_smoothed_deg`` against the truth; ``att_inside_3sigma_smoothed``:
  the fraction of the smoother's epochs whose attitude error is inside 3 sigma on every axis;
* ``moon_found`` / ``moon_frames`` (frames whose true Moon centre is in the image), ``moon_rms_deg``.

Run: ``python -m scenarios.study.orbit_mismatch [--rate HZ] [--out FILE.json]``;
tests/test_orbit_replay.py runs one case on a shortened flight, and the whole study under ``-m slow``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import tempfile
from pathlib import Path

import numpy as np
from scipy.stats import chi2

from scenarios.atomic import atomic_write_text
from scenarios.study.edge_mismatch import HEIGHTS_M, PROFILES, Case, cases, quiet_filter_log

__all__ = ["SCENARIO", "TUNING", "VISION", "TARGETS", "orbit_scenario", "simulate_log", "replay_log",
           "flight_figures", "run_study", "main"]

SCENARIO = "pinhole-orbit"
_LIB = Path(__file__).resolve().parent.parent / "library"
TUNING = _LIB / "tuning" / "pinhole-orbit.toml"
VISION = _LIB / "vision" / "moon.toml"
TARGETS = ("earth", "sun", "moon")
NEES_BAND = tuple(chi2.ppf([0.025, 0.975], 3))


def orbit_scenario(duration_s: float | None = None, rate_hz: float | None = None):
    """The library scenario, optionally shortened and with another frame rate."""
    from scenarios.sim.scenario import load_scenario

    sc = load_scenario(SCENARIO)
    if duration_s is not None:
        sc.simulation = dataclasses.replace(sc.simulation, duration_s=float(duration_s))
    if rate_hz is not None:
        sc.cameras = [dataclasses.replace(c, rate_hz=float(rate_hz)) for c in sc.cameras]
    return sc


def simulate_log(path: Path, case: Case = Case(45e3), *, sc=None, flight=None, seed: int = 0) -> Path:
    """Simulate (or reuse ``flight``) and render the scenario ``sc`` with the limb edge of ``case``
    into the log ``path`` (what ``horizon-nav simulate --images`` writes, payload masks included)."""
    from scenarios.cli.simulate import rendered_images, write_log
    from scenarios.sim.render import scenario_render_options
    from scenarios.sim.simulate import simulate_flight

    sc = orbit_scenario() if sc is None else sc
    flight = simulate_flight(sc, seed) if flight is None else flight
    opts = dataclasses.replace(scenario_render_options(sc), limb_shift_m=case.shift_m, **PROFILES[case.profile])
    images, masks = rendered_images(flight, opts, progress=False)
    return write_log(flight, Path(path), None, None, images=images, masks=masks)


def replay_log(path: Path, out: Path, workers: int = 1):
    """``horizon-nav replay`` of an orbit log with the scenario's tuning, the Moon and no Rerun file."""
    from scenarios.replay.pipeline import ReplayOptions, replay

    opt = ReplayOptions(tuning=str(TUNING), vision_config=str(VISION), targets=TARGETS, output=str(out),
                        rrd="", progress=False, workers=workers)
    return replay(path, opt)


def _truth_rows(rr, target: str, camera: int = 0):
    """(mask into rr.vectors, truth unit vectors) of the vectors of ``target`` of the replay's
    camera index ``camera``."""
    v = rr.vectors
    ct = rr.inputs.cameras[rr.cam_numbers[camera]].truth
    m = np.flatnonzero((v.camera == camera) & (v.target == target))
    j = np.searchsorted(ct["t_ns"], v.t_ns[m])
    ok = (j < ct["t_ns"].size)
    ok[ok] = ct["t_ns"][j[ok]] == v.t_ns[m][ok]
    field = {"hor": "nadir_c", "moon": "moon_c"}[target]
    return m[ok], ct[field][j[ok]]


def _fits_height(g, r, ref) -> float:
    """The edge height h [m] the frames' fits have: the least-squares solution of the measurement
    model ``r_j = e_true_j - e_j = -g_j (h - ref_j)`` over the frames (rows of ``g`` zero where a
    vector carries no sensitivity), ``h = sum_j g_j . (g_j ref_j - r_j) / sum_j |g_j|^2``: the
    frames' own heights ``ref_j - g_j . r_j / |g_j|^2`` weighted by their sensitivity squared."""
    gg = np.sum(g * g, axis=1)
    return float(np.sum(gg * ref - np.sum(g * r, axis=1)) / np.sum(gg))


def _rms(x) -> float:
    """Root mean square of ``x``; NaN when empty."""
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else math.nan


def _angle_deg(a, b):
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))


def _containment(err_deg, P_c, g, sigma_m) -> float:
    P = P_c + np.einsum("n,ni,nj->nij", np.broadcast_to(np.square(sigma_m), len(g)), g, g)
    s3 = 3 * np.degrees(np.sqrt(np.linalg.eigvalsh(P)[:, -1]))
    return float(np.mean(err_deg <= s3))


def _nees(rr):
    """Attitude NEES (3 dof) of the forward filter at its measurement epochs."""
    from scenarios.replay.summary import attitude_error

    res, tr = rr.nav, rr.inputs.truth
    i = np.searchsorted(res.t_ns, res.meas_t_ns)  # meas_t_ns are IMU epochs
    j = np.searchsorted(tr.t_ns, res.meas_t_ns)
    ok = (j < tr.t_ns.size) & (i < res.t_ns.size)
    ok[ok] = (tr.t_ns[j[ok]] == res.meas_t_ns[ok]) & (res.t_ns[i[ok]] == res.meas_t_ns[ok])
    psi = attitude_error(res.q_eb[i[ok]], tr.q_eb[j[ok]])
    sl = res.layout["psi"]
    P = res.P_full[ok][:, sl, sl]
    return res.meas_t_ns[ok], np.einsum("ni,ni->n", psi, np.linalg.solve(P, psi[..., None])[..., 0])


def _smoothed_inside_3sigma(rr) -> float:
    """Fraction of the smoother's epochs whose attitude error is inside 3 sigma on every axis."""
    from scenarios.replay.summary import attitude_error

    sm, tr = rr.smooth, rr.inputs.truth
    j = np.searchsorted(tr.t_ns, sm.t_ns)
    ok = j < tr.t_ns.size
    ok[ok] = tr.t_ns[j[ok]] == sm.t_ns[ok]
    psi = attitude_error(sm.q_eb[ok], tr.q_eb[j[ok]])
    s3 = 3 * np.sqrt(sm.P[ok][:, rr.nav.layout["psi"]])
    return float(np.mean(np.all(np.abs(psi) <= s3, axis=1)))


def flight_figures(rr, case: Case | None = None, camera: int = 0) -> dict:
    """The figures of one replayed flight (see the module docstring) for the replay's camera
    index ``camera``; the attitude figures are the filter's, the same for every camera."""
    from scenarios.replay.summary import summarize

    v, s = rr.vectors, summarize(rr)
    m, e_true = _truth_rows(rr, "hor", camera)
    has = np.all(np.isfinite(v.dedge_c[m]), axis=1)
    g = np.where(has[:, None], v.dedge_c[m], 0.0)
    ref = np.where(has, v.edge_ref_m[m], 0.0)
    sigma_ref = np.where(has, v.edge_ref_sigma_m[m], 0.0) if v.edge_ref_sigma_m is not None else None
    e = v.e_c[m]
    r = e_true - e
    h_truth = _fits_height(g, r, ref)
    edge = s["edge_height"][f"camera_{rr.cam_numbers[camera]}"]
    h_s, sig_s = edge["smoothed_km"] * 1e3, edge["smoothed_sigma_km"] * 1e3
    moved = e - g * (h_s - ref)[:, None]
    err_raw, err = _angle_deg(e, e_true), _angle_deg(moved, e_true)
    err_fits = _angle_deg(e - g * (h_truth - ref)[:, None], e_true)[has]
    sigma_prior = _prior_sigma() if sigma_ref is None else sigma_ref
    mm, m_true = _truth_rows(rr, "moon", camera)
    t_nees, nees = _nees(rr)
    inside = (nees >= NEES_BAND[0]) & (nees <= NEES_BAND[1])
    after = t_nees >= v.t_ns[mm].min() if len(mm) else np.zeros(len(nees), bool)
    out = dict(frames=int(len(m)), frames_with_sensitivity=int(has.sum()), edge_truth_km=h_truth / 1e3, edge_smoothed_km=h_s / 1e3, edge_smoothed_sigma_km=sig_s / 1e3,
               nadir_rms_raw_deg=_rms(err_raw), nadir_rms_deg=_rms(err),
               nadir_max_deg=float(err.max()), nadir_rms_state_deg=_rms(err[has]), nadir_rms_other_deg=_rms(err[~has]),
               nadir_rms_fits_height_deg=_rms(err_fits),
               containment_prior=_containment(err_raw, v.P_c[m], g, sigma_prior),
               containment=_containment(err, v.P_c[m], g, sig_s),
               nees_in_band=float(np.mean(inside)), nees_above_band=float(np.mean(nees > NEES_BAND[1])),
               nees_in_band_moon=float(np.mean(inside[after])) if after.any() else math.nan,
               nees_mean=float(np.mean(nees)), nees_epochs=int(len(nees)),
               att_rms_forward_deg=s["truth"]["forward"]["att_rms_deg"],
               att_rms_smoothed_deg=s["truth"]["smoothed"]["att_rms_deg"],
               att_inside_3sigma_smoothed=_smoothed_inside_3sigma(rr),
               moon_found=int(len(mm)), moon_frames=_moon_frames(rr, camera),
               moon_rms_deg=_rms(_angle_deg(v.e_c[mm], m_true)))
    if case is not None:
        out = dict(case=case.name, profile=case.profile, edge_render_km=case.height_m / 1e3, **out)
    return out


def _moon_frames(rr, camera: int = 0) -> int:
    """Frames of the replay's camera index ``camera`` whose true Moon centre projects into the image."""
    from vision.camera import project

    cs = rr.inputs.cameras[rr.cam_numbers[camera]]
    m = cs.truth["moon_c"]
    with np.errstate(invalid="ignore"):
        uv = project(cs.camera, m)
        inside = (m[:, 2] > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= cs.camera.width - 0.5) \
            & (uv[:, 1] >= -0.5) & (uv[:, 1] <= cs.camera.height - 0.5)
    return int(np.sum(inside))


def _prior_sigma() -> float:
    """The tuning's initial 1 sigma of h_e [m]."""
    from nav.tuning import tuning_from_toml

    return float(tuning_from_toml(TUNING.read_text(encoding="utf-8")).edge_height.sigma)


def run_study(heights=HEIGHTS_M, profiles=tuple(PROFILES), rate_hz: float = 0.5, workdir: Path | None = None,
              progress: bool = False) -> list[dict]:
    """`flight_figures` of every (profile, height) case: one simulated flight, rendered per case;
    ``progress``: a progress bar over the cases."""
    from scenarios.sim.simulate import simulate_flight

    sc = orbit_scenario(rate_hz=rate_hz)
    flight = simulate_flight(sc, 0)
    workdir = Path(tempfile.mkdtemp(prefix="horizon-nav-orbit-")) if workdir is None else workdir
    rows = []
    for case in cases(heights, profiles, progress):
        log = simulate_log(workdir / f"{case.name}.mcap", case, sc=sc, flight=flight)
        rows.append(flight_figures(replay_log(log, workdir / f"{case.name}.solution.mcap"), case))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m scenarios.study.orbit_mismatch",
                                 description="Edge-height model mismatch on the simulated pinhole orbit, replayed end to end.")
    ap.add_argument("--rate", type=float, default=0.5, help="camera frame rate [Hz] (default 0.5, the scenario's: 121 frames)")
    ap.add_argument("--out", type=Path, help="write the per-case figures as JSON here")
    a = ap.parse_args(argv)
    quiet_filter_log()
    rows = run_study(rate_hz=a.rate, progress=True)
    print(f"{'case':<18}{'h true':>8}{'h smooth':>10}{'1sig':>6}{'RMS raw':>9}{'RMS':>8}{'3s prior':>9}{'3s':>6}"
          f"{'NEES in':>8}{'w/ Moon':>8}{'att sm':>8}{'moon':>8}")
    for r in rows:
        print(f"{r['case']:<18}{r['edge_truth_km']:>8.1f}{r['edge_smoothed_km']:>10.1f}{r['edge_smoothed_sigma_km']:>6.1f}"
              f"{r['nadir_rms_raw_deg']:>9.3f}{r['nadir_rms_deg']:>8.3f}{r['containment_prior']:>9.2f}{r['containment']:>6.2f}"
              f"{r['nees_in_band']:>8.2f}{r['nees_in_band_moon']:>8.2f}{r['att_rms_smoothed_deg']:>8.3f}{r['moon_found']:>5}/{r['moon_frames']}")
    if a.out:
        atomic_write_text(a.out, json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
