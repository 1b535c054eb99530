"""``horizon-nav simulate SCENARIO -o logs/NAME.mcap``: simulate a flight and write its MCAP log.

Writes (docs/log-format.md): IMU (``/imu`` rates or ``/imu_increment``), GPS fixes (``/gps``), the
truth (``/truth/state`` at the IMU rate), per camera ``camera_info``, the ``/tf_static`` mounts
(the *nominal* mounts: the true misalignment is in ``/camera_<k>/truth``) and the per-frame camera
truth, with the scenario TOML, seed and software version as MCAP metadata. The file is written to a
temporary file and renamed when complete (``scenarios.flightlog.writer.LogWriter``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nav.rotation import matrix_to_quat
from scenarios.sim import simulate as sim
from scenarios.errors import UserError
from scenarios.sim.scenario import load_scenario

NAME = "simulate"
HELP = "simulate a flight of a scenario (library name or .toml) and write an MCAP log"


def add_arguments(p) -> None:
    p.add_argument("scenario", help="library scenario name (see `horizon-nav scenarios`) or a .toml file")
    p.add_argument("-o", "--output", required=True, help="output log, e.g. logs/atek.mcap")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--duration", type=float, default=None, help="simulated time [s] (default: the scenario's)")
    p.add_argument("--no-images", dest="images", action="store_false", default=True,
                   help="write the per-frame camera truth only, no rendered images (fast, for studies)")
    p.add_argument("--jpeg-quality", type=int, default=None, help="JPEG quality of rendered frames (default: renderer's)")
    p.add_argument("--truth-rate", type=float, default=None,
                   help="rate of /truth/state [Hz] (default: the IMU rate); must divide the truth rate")
    p.add_argument("--vectors", action="store_true",
                   help="also write /camera_<k>/vectors: truth plus the vision error model (scenarios/sim/truth_vectors.py)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def write_log(flight: sim.FlightData, path: Path, truth_rate_hz: float | None = None, progress=None,
              images=None, vectors=None, masks=None) -> Path:
    """Write a simulated flight as a horizon-nav MCAP log (atomic: temp file, then rename).

    ``images``: optional iterable of ``(camera k, t_ns, jpeg bytes)`` (e.g.
    :func:`scenarios.sim.render.render_flight_images`), consumed as a stream. ``vectors``: optional
    :class:`scenarios.sim.truth_vectors.TruthVectors` written to ``/camera_<k>/vectors``. ``masks``:
    optional ``{k: (H, W) bool}`` payload masks written to ``/camera_<k>/payload_mask``.
    """
    from scenarios.flightlog.writer import LogWriter

    sc = flight.scenario
    tr = flight.truth
    meta = {"scenario": sc.toml_text, "scenario_name": sc.name, "seed": flight.seed,
            "liftoff_utc_ns": tr.liftoff_ns, "kind": "simulated", "duration_s": flight.duration,
            "imu_output": flight.imu.output, "imu_sample": sc.imu.sample}
    rate = truth_rate_hz or sc.imu.rate_hz
    m = int(round(1.0 / (tr.dt * rate)))
    if m < 1 or abs(m * tr.dt * rate - 1.0) > 1e-9:
        raise UserError(f"--truth-rate {rate}: must divide the truth rate {1.0 / tr.dt:g} Hz")
    with LogWriter(path, meta) as w:
        t0 = int(tr.liftoff_ns)
        mounts = {c.k: (np.zeros(3), matrix_to_quat(c.R_bc_nominal)) for c in flight.cameras}
        if mounts:
            w.write_tf_static(np.array([t0], np.int64), mounts)
        for c in flight.cameras:
            w.write_camera(c.k, np.array([t0], np.int64), c.camera)
            if masks and c.k in masks:
                w.write_payload_mask(c.k, t0, masks[c.k])
            ct = c.truth
            n = len(ct.t)
            w.write_camera_truth(c.k, c.t_ns, ct.nadir_c, ct.sun_c, ct.moon_c, ct.horizon_visible,
                                 list(ct.conic_type), ct.sun_in_view, ct.moon_in_view, ct.earth_fraction,
                                 np.broadcast_to(c.psi_c, (n, 3)))
        if vectors is not None:
            vectors.write(w)
        n_images = 0
        for k, t_ns, jpeg in images or ():
            w.write_image(k, np.array([t_ns], np.int64), [jpeg])
            n_images += 1
        if progress:
            progress(0.9, "write imu")
        imu = flight.imu
        t_imu = flight.to_ns(imu.t)
        if imu.output == "increment":
            w.write_imu_increment(t_imu, imu.gyro, imu.accel, imu.dt)
        else:
            w.write_imu(t_imu, imu.gyro, imu.accel)
        g = flight.gps
        if len(g.t):
            w.write_gps(flight.to_ns(g.t), g.position, g.velocity, g.position_cov, g.velocity_cov,
                        num_satellites=g.num_satellites, status=0)
        sel = slice(0, None, m)
        w.write_truth(tr.t_ns[sel], tr.x_e[sel], tr.v_e[sel], tr.q_eb[sel], tr.omega_ib_b[sel], tr.f_b[sel])
    return Path(path)


def rendered_images(flight: sim.FlightData, opts, progress: bool = True):
    """``(images, masks)`` for :func:`write_log`: the flight's frames rendered with ``opts``
    (a stream) and, when the renderer draws the payload, each camera's payload mask."""
    from scenarios.sim.render import payload_mask, render_flight_images

    images = render_flight_images(flight, options=opts, progress=progress)
    masks = None
    if opts.payload_mask is not None:   # what the renderer draws the payload into
        masks = {c.k: payload_mask(c.camera, opts.payload_mask) for c in flight.cameras}
    return images, masks


def run(args) -> int:
    sc = load_scenario(args.scenario)
    out = Path(args.output)
    if out.suffix != ".mcap":
        raise UserError(f"-o {out}: expected a .mcap file name")
    if args.duration is not None and not args.duration > 0:
        raise UserError(f"--duration {args.duration}: expected a positive number of seconds")
    bar = None
    if not args.quiet:
        from tqdm import tqdm
        bar = tqdm(total=100, desc=f"simulate {sc.name}", unit="%", bar_format="{l_bar}{bar}| {elapsed}")

    def progress(frac, label):
        if bar is not None:
            bar.set_postfix_str(label)
            bar.update(int(round(frac * 100)) - bar.n)

    try:
        flight = sim.simulate_flight(sc, args.seed, args.duration,
                                     progress=lambda f, label: progress(0.85 * f, label))
        images = masks = None
        if args.images:
            from scenarios.sim.render import scenario_render_options
            images, masks = rendered_images(flight, scenario_render_options(sc, args.jpeg_quality), not args.quiet)
        vectors = None
        if args.vectors:
            from scenarios.sim.truth_vectors import flight_truth_vectors
            progress(0.86, "vectors")
            vectors = flight_truth_vectors(flight)
        write_log(flight, out, args.truth_rate, progress, images=images, vectors=vectors, masks=masks)
        progress(1.0, "done")
    finally:
        if bar is not None:
            bar.close()
    from scenarios.sim.truth import summary
    s = summary(flight.truth)
    print(f"{out}: {sc.name}, seed {args.seed}, {flight.duration:.0f} s; {_height_text(sc, s)}; "
          f"{len(flight.imu.t)} IMU samples, {len(flight.gps.t)} GPS fixes, "
          f"{sum(len(c.t_ns) for c in flight.cameras)} camera frames ({'with images' if args.images else 'truth only'})"
          + (f", {len(vectors)} vectors (truth + vision error model)" if vectors is not None else ""))
    return 0


def _height_text(sc, s: dict) -> str:
    """The flight's height in the summary line: the apogee of a launch, the range of an orbit."""
    if sc.orbit is None:
        return f"apogee {s['apogee_m'] / 1e3:.1f} km at T+{s['apogee_t_s']:.0f} s"
    return f"height {s['min_height_m'] / 1e3:.1f}-{s['apogee_m'] / 1e3:.1f} km"
