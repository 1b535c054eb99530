"""``horizon-nav render``: one synthetic camera frame of a scenario at a mission time (PNG or JPEG)."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from scenarios.errors import UserError

NAME = "render"
HELP = "render the synthetic image of one camera of a scenario at a mission time (T+ seconds)"


def add_arguments(p) -> None:
    p.add_argument("scenario", help="scenario name in the library (e.g. atek) or a TOML path")
    p.add_argument("--time", required=True, help='mission time [s]: "171" or "T+171"')
    p.add_argument("--camera", type=int, default=1, help="camera number, 1-based (default 1)")
    p.add_argument("--seed", type=int, default=0, help="random seed (mount errors, weather, noise)")
    p.add_argument("--clean", action="store_true",
                   help="geometric mode: white Earth on black space, no atmosphere/Sun/noise")
    p.add_argument("--quality", type=int, default=None, help="JPEG quality for a .jpg output")
    p.add_argument("-o", "--output", default="frame.png", help="output image (.png or .jpg)")


def parse_mission_time(text: str) -> float:
    """'171', 'T+171', 'T+171.5' -> 171.0 [s]."""
    m = re.fullmatch(r"\s*(?:T\s*\+\s*)?([0-9]+(?:\.[0-9]*)?)\s*", str(text), flags=re.IGNORECASE)
    if not m:
        raise UserError(f"--time {text!r}: expected mission seconds such as 171 or T+171")
    return float(m.group(1))


def run(args) -> int:
    import cv2

    from scenarios.sim import render
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_cameras
    from scenarios.sim.truth import simulate_truth
    from nav import ephemeris

    t_s = parse_mission_time(args.time)
    sc = load_scenario(args.scenario)
    dur = float(sc.simulation.duration_s)
    if t_s > dur:
        raise UserError(f"--time {args.time}: T+{t_s:g} s is outside the flight of scenario "
                        f"{args.scenario!r} (0 to {dur:g} s)")
    if not 1 <= args.camera <= len(sc.cameras):
        raise UserError(f"--camera {args.camera}: scenario {args.scenario!r} has "
                        f"{len(sc.cameras)} camera(s), numbered from 1")
    out = Path(args.output)
    if out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise UserError(f"-o {args.output}: expected a .png or .jpg file name")
    truth = simulate_truth(sc, min(dur, t_s + 1.0))
    runs = simulate_cameras(sc, truth, args.seed)
    cam_run = runs[args.camera - 1]
    idx = int(round(t_s / truth.dt))
    from nav.rotation import quat_to_matrix

    R_ec = quat_to_matrix(truth.q_eb[idx]) @ cam_run.R_bc
    t_ns = truth.liftoff_ns + int(round(t_s * 1e9))
    opts = render.RenderOptions.geometric() if args.clean else render.RenderOptions()
    fr = render.render_frame(cam_run.camera, R_ec, truth.x_e[idx], ephemeris.sun_position_e(t_ns),
                             ephemeris.moon_position_e(t_ns), seed=args.seed,
                             options=opts, omega_c=truth.omega_ib_b[idx] @ cam_run.R_bc)
    bgr = cv2.cvtColor(fr.image, cv2.COLOR_RGB2BGR)
    params = []
    if out.suffix.lower() in (".jpg", ".jpeg"):
        params = [cv2.IMWRITE_JPEG_QUALITY, int(args.quality or opts.jpeg_quality)]
    if not cv2.imwrite(str(out), bgr, params):
        raise UserError(f"-o {args.output}: could not write the image")
    sun = "in view" if fr.sun_visible > 0 else "not in view"
    print(f"{out}: camera {args.camera} at T+{t_s:g} s, height {fr.height_m / 1e3:.1f} km, "
          f"Earth {np.mean(fr.earth_mask) * 100:.1f} % of pixels, Sun {sun}, "
          f"exposure {fr.exposure:.3g}, saturated {fr.saturated_fraction * 100:.2f} %")
    return 0
