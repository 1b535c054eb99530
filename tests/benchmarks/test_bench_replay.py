"""Replay benchmarks: real-time factor of `horizon-nav replay` with vision from images on
the demo log and on a two-camera 30 frames/s coast log, and the attitude accuracy of the image path
against the truth-vector path on the same flight.

Logs (simulated by the CLI as a user would, cached under $TMPDIR/horizon-nav-bench-replay-<version>;
delete the folder to simulate again):

* demo: ``horizon-nav simulate atek`` with images (both cameras at 1 Hz, T+60..T+430), replayed as
  ``horizon-nav demo`` does (``--from T+60 --to T+430``); QUICK: ``--duration 130``, replayed
  T+60..T+130.
* truth vectors of the same flight (``--no-images --vectors``: 003 eq. (33)-(38) error model), the
  in-run baseline of the attitude RMS.
* video30: ``scenarios/library/atek.toml`` with both cameras at ``rate_hz = 30`` over
  T+200..T+230 (``truth_rate_hz = 1200``: a camera rate must divide it), JPEG quality as rendered,
  replayed over T+200..T+230; QUICK: T+200..T+204.

Figures (``bench.json``):

* ``replay.realtime_factor_demo`` and ``replay.realtime_factor_video30``: flight seconds replayed
  / wall seconds of the whole ``replay()`` call (read, vision in worker processes, init, filter,
  smoother, solution MCAP, Rerun recording; the interpreter start-up excluded), with the per-stage
  wall seconds, shares and CPU seconds (this process and its children: the vision workers, the
  Rerun recording process) as extra keys. The original targets were >= 100x (demo) and >= 5x
  (video30, see docs/performance.md). On 2 cores the vision front end's CPU time per frame bounds
  the demo's factor: ``stages.vision.cpu_s / frames`` is that figure.
  ``decode_ms_per_frame_1core``: the JPEG decode of some of the run's frames timed alone in the
  same run, the machine's speed at the time (it drifts by 20-40 % between runs). The baseline is
  the decode-bound factor of the same run: flight seconds / (frames x that decode time / cores),
  the factor a replay that only decoded its frames on every core would reach; the ratio is the
  share of it reached, the figure least moved by the machine's drift.
* ``replay.realtime_factor_video30_vision5hz``: the same with ``--vision-rate 5`` (every 6th frame
  of each camera through the front end).
* ``replay.demo_att_rms_deg``: forward-filter attitude error RMS against the truth over the aided
  phase, image path; baseline: the truth-vector path on the same flight.
"""
from __future__ import annotations

import logging
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CACHE_VERSION = 3   # 2: logs with /camera_<k>/payload_mask; 3: twilight Sun path with the erf air mass (renderer)


def _cache() -> Path:
    d = Path(tempfile.gettempdir()) / f"horizon-nav-bench-replay-{CACHE_VERSION}"
    d.mkdir(parents=True, exist_ok=True)
    return d


def _simulate(out: Path, scenario: str, *args: str) -> Path:
    if not out.is_file():
        subprocess.run([sys.executable, "-m", "scenarios.cli", "simulate", scenario, "-o", str(out), "--quiet", *args],
                       check=True, cwd=ROOT, capture_output=True)
    return out


def video30_scenario(path: Path, start_s: float, end_s: float) -> Path:
    """The ATEK scenario with both cameras at 30 frames/s over ``start_s..end_s`` (a scenario
    override file, written to ``path``)."""
    text = (ROOT / "scenarios" / "library" / "atek.toml").read_text()
    head, *cams = text.split("[[cameras]]")
    sub = [(r"(?m)^rate_hz = [0-9.]+", "rate_hz = 30.0"), (r"(?m)^start_s = [0-9.]+", f"start_s = {start_s}"),
           (r"(?m)^end_s = [0-9.]+", f"end_s = {end_s}")]
    for i, c in enumerate(cams):
        for pat, rep in sub:
            c, n = re.subn(pat, rep, c)
            assert n == 1, (pat, "atek.toml [[cameras]] changed: update video30_scenario")
        cams[i] = c
    text = "[[cameras]]".join([head] + cams).replace('name = "atek"', 'name = "atek_video30"')
    text, n = re.subn(r"(?m)^truth_rate_hz = [0-9.]+", "truth_rate_hz = 1200.0", text)
    assert n == 1
    path.write_text(text)
    return path


def _run(log: Path, tag: str, t_from: str, t_to: str, **kw):
    from scenarios.replay.pipeline import ReplayOptions, replay
    logging.getLogger("nav.navigator").setLevel(logging.ERROR)
    d = _cache()
    opt = ReplayOptions(t_from=t_from, t_to=t_to, output=str(d / f"{tag}.solution.mcap"), rrd=str(d / f"{tag}.rrd"),
                        progress=False, **kw)
    t = time.perf_counter()
    rr = replay(log, opt)
    wall = time.perf_counter() - t
    return rr, wall


def _record_rtf(bench, name, rr, wall, target):
    flight = (int(rr.nav.t_ns[-1]) - int(rr.nav.t_ns[0])) / 1e9
    tot = sum(rr.timings.values())
    stages = {k: {"s": round(v, 3), "share": round(v / tot, 3), "cpu_s": round(rr.cpu_timings.get(k, float("nan")), 3)}
              for k, v in rr.timings.items()}
    frames = len(rr.frames)
    decode_ms = _decode_reference(rr)
    cores = os.cpu_count() or 1
    bench(name, flight / wall, "x real time", baseline=flight / (frames * decode_ms / 1e3 / cores),
          baseline_name=f"decode-bound factor: flight s / (frames x JPEG decode of the run's frames / {cores} cores), same run",
          wall_s=round(wall, 3), flight_s=flight, target=target, frames=frames, stages=stages,
          rerun_parts={k: round(v, 3) for k, v in rr.rerun_timings.items()},
          vision_cpu_ms_per_frame=round(1e3 * rr.cpu_timings.get("vision", 0.0) / max(frames, 1), 2),
          decode_ms_per_frame_1core=decode_ms)
    return flight / wall


def _decode_reference(rr, n: int = 40) -> float:
    """The machine's speed in this run: milliseconds to decode one of the replayed JPEG frames
    (``n`` spread over the run, both cameras) in this process alone, the best of 3 passes. The
    decode is the largest per-frame cost of the vision stage and its code is fixed (libjpeg-turbo),
    so it tells how fast the machine ran: this 2-core machine's speed drifts by 20-40 % between
    runs, more than most changes move the real-time factors."""
    from scenarios.flightlog.jpeg import decode_frame
    from scenarios.replay.rerun_view import read_images
    fr = rr.frames[::max(1, len(rr.frames) // n)][:n]
    got = read_images(rr.inputs, fr, rr.cam_numbers)
    jpegs = [bytes(v) for k in rr.cam_numbers for v in got[k]]
    best = float("inf")
    for _ in range(3):
        t = time.perf_counter()
        for j in jpegs:
            decode_frame(j)
        best = min(best, (time.perf_counter() - t) / max(len(jpegs), 1))
    return round(1e3 * best, 3)


def test_bench_replay_demo(bench, is_quick):
    """Demo log with vision from images vs the truth-vector log of the same flight."""
    from scenarios.replay.pipeline import ReplayOptions, replay
    from scenarios.replay.summary import summarize
    d = _cache()
    end = 130 if is_quick else 430
    dur = ["--duration", "130"] if is_quick else []
    img = _simulate(d / ("demo_quick.mcap" if is_quick else "demo.mcap"), "atek", *dur)
    vec = _simulate(d / ("vec_quick.mcap" if is_quick else "vec.mcap"), "atek", "--no-images", "--vectors", *dur)
    rr, wall = _run(img, "demo", "T+60", f"T+{end}")
    assert rr.vision_mode == "images" and len(rr.frames) > 100
    rtf = _record_rtf(bench, "replay.realtime_factor_demo", rr, wall, 100)
    assert rtf > 1.0
    s = summarize(rr)
    rv = replay(vec, ReplayOptions(t_from="T+60", t_to=f"T+{end}", output=str(d / "vec.solution.mcap"), rrd="",
                                   progress=False))
    sv = summarize(rv)
    a_img = s["truth"]["forward"]["att_rms_deg"]
    a_vec = sv["truth"]["forward"]["att_rms_deg"]
    bench("replay.demo_att_rms_deg", a_img, "deg", baseline=a_vec,
          baseline_name="truth-derived vectors (003 eq. (33)-(38)) on the same flight, same run",
          smoothed_deg=s["truth"]["smoothed"]["att_rms_deg"], truth_vectors_smoothed_deg=sv["truth"]["smoothed"]["att_rms_deg"],
          vector_errors=s.get("vector_errors", {}),
          rejected={k: sum(v["rejected"].values()) for k, v in s["measurements"].items()})
    assert a_img < 10.0


def test_bench_replay_video30(bench, is_quick):
    """Two cameras at 30 frames/s: vision + replay of the window."""
    d = _cache()
    end = 204 if is_quick else 230
    sc = video30_scenario(d / f"atek_video30_{end}.toml", 200.0, float(end))
    log = _simulate(d / f"video30_{end}.mcap", str(sc), "--duration", str(end + 2))
    rr, wall = _run(log, "video30", "T+200", f"T+{end}")
    assert rr.vision_mode == "images" and len(rr.frames) >= 2 * 30 * (end - 200)
    rtf = _record_rtf(bench, "replay.realtime_factor_video30", rr, wall, 5)
    assert rtf > 0.2
    rr, wall = _run(log, "video30_5hz", "T+200", f"T+{end}", vision_rate_hz=5.0)
    assert len(rr.frames) == 2 * (5 * (end - 200) + 1)
    _record_rtf(bench, "replay.realtime_factor_video30_vision5hz", rr, wall, 5)
