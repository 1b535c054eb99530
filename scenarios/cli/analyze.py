"""``horizon-nav analyze``: the design analyses of 003 as plots (PNG) and tables (CSV).

- ``visibility``: which horizon conics (ellipse / hyperbola) and when the full Earth can be seen
  versus height and circular FOV (003 §2.7, figs. 6-7; thresholds derived in `vision.design`).
- ``spherical-error``: angle between the ellipsoid normal and the geocentric direction versus
  latitude (003 §2.8, fig. 8).
- ``sensitivity``: roll/pitch 3-sigma errors of the horizon measurement versus height, FOV,
  resolution and atmosphere thickness (003 §4, figs. 19-22).

Files are written atomically (temporary file in the output directory, then rename).
"""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from scenarios.atomic import atomic_output

from scenarios.errors import UserError

NAME = "analyze"
HELP = "design analyses of 003: conic visibility, spherical-Earth error, roll/pitch sensitivity (PNG + CSV)"

_SWEEPS = {  # parameter -> (values in plot units, to SI factor, axis label, file stem, 003 figure)
    "height": (np.arange(50.0, 501.0, 10.0), 1e3, "height H [km]", "fig. 19"),
    "fov": (np.arange(30.0, 170.5, 1.0), 1.0, "field of view [deg]", "fig. 20"),
    "resolution": (np.arange(120.0, 2161.0, 40.0), 1.0, "vertical image resolution [px]", "fig. 21"),
    "atmosphere": (np.arange(0.0, 100.5, 5.0), 1e3, "effective atmosphere thickness d [km]", "fig. 22"),
}


def add_arguments(p) -> None:
    p.add_argument("analysis", choices=["visibility", "spherical-error", "sensitivity"],
                   help="which analysis to run")
    p.add_argument("-o", "--output", required=True, metavar="DIR",
                   help="output directory for the PNG and CSV files (created if missing)")
    p.add_argument("--camera", metavar="CAM.toml",
                   help="camera file: sensitivity uses this fisheye model (FOV = its horizontal FOV, "
                        "resolution = its height) instead of 003's pinhole; visibility marks its FOVs")
    p.add_argument("--param", choices=list(_SWEEPS),
                   help="sensitivity: the parameter to sweep (default: all four)")
    p.add_argument("--form", choices=["auto", "003", "linear", "constrained"], default="auto",
                   help="sensitivity: covariance form (auto: '003' for the pinhole, 'constrained' "
                        "with --camera); see vision/design.py")
    p.add_argument("--aspect", type=float, default=1.0,
                   help="sensitivity: pinhole sensor width/height (default 1: square 1080 x 1080)")
    p.add_argument("--fov-axis", choices=["vertical", "horizontal"], default="vertical",
                   help="sensitivity: the sensor side the pinhole FOV spans (default vertical)")
    p.add_argument("--mounting", choices=["side", "forward"], default="side",
                   help="sensitivity: camera perpendicular to the vehicle's roll axis (side, as on a "
                        "sounding rocket and in 003 §4) or along it (forward); roll = about the roll "
                        "axis")


# ----------------------------------------------------------------------------------------------
# atomic output


_atomic = atomic_output


def write_csv(path: Path, header: list[str], rows: np.ndarray, comment: str = "") -> None:
    """CSV with a '#' comment line, a header and float rows, written atomically."""
    lines = [f"# {c}" for c in comment.splitlines()] if comment else []
    lines.append(",".join(header))
    lines += [",".join(f"{v:.10g}" for v in r) for r in np.atleast_2d(rows)]

    def w(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write("\n".join(lines) + "\n")

    _atomic(path, w)


def save_png(fig, path: Path) -> None:
    _atomic(path, lambda tmp: fig.savefig(tmp, format="png", dpi=120, bbox_inches="tight"))


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ----------------------------------------------------------------------------------------------
# analyses


def run_visibility(out: Path, camera=None) -> list[Path]:
    from matplotlib.patches import Patch

    from vision.design import earth_alpha, visibility_map, visibility_thresholds

    plt = _pyplot()
    fov = np.linspace(0.0, 180.0, 721)
    panels = [("a) 003 fig. 6", np.logspace(4, 8, 600), True),
              ("b) 003 fig. 7: heights below 800 km", np.linspace(1e3, 800e3, 600), False)]
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2))
    colors = ["#4c72b0", "#55a868", "#dd8452"]  # only hyperbola, both, only ellipse
    for ax, (title, H, logx) in zip(axes, panels):
        vm = visibility_map(H, np.radians(fov))
        cls = np.where(vm["ellipse"] & vm["hyperbola"], 1, np.where(vm["ellipse"], 2, 0)).T
        x = H / 1e3
        ax.contourf(x, fov, cls, levels=[-0.5, 0.5, 1.5, 2.5], colors=colors)
        ax.contourf(x, fov, vm["full"].T.astype(float), levels=[0.5, 1.5], colors="none",
                    hatches=["//"])
        ax.contour(x, fov, vm["full"].T.astype(float), levels=[0.5], colors="k", linewidths=0.8)
        if camera is not None:
            for name, val in (("camera horizontal FOV", _camera_hfov(camera)),
                              ("camera diagonal FOV", 2 * math.degrees(camera.fov_theta))):
                ax.axhline(val, color="k", ls="--", lw=1)
                ax.text(x[0] * (1.1 if logx else 1) + (0 if logx else 10), val + 1.5, name, fontsize=8)
        if logx:
            ax.set_xscale("log")
        ax.set_xlabel("height above the spherical Earth H [km]")
        ax.set_ylabel("circular field of view gamma [deg]")
        ax.set_ylim(0, 180)
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    handles = [Patch(color=colors[0], label="only hyperbolae (gamma < 4 alpha - 180 deg)"),
               Patch(color=colors[1], label="ellipses or hyperbolae"),
               Patch(color=colors[2], label="only ellipses (gamma < 180 deg - 4 alpha)"),
               Patch(facecolor="white", edgecolor="k", hatch="//",
                     label="full Earth in view (gamma > 2 alpha)")]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=9, frameon=False)
    fig.suptitle("Visibility of the horizon conic sections (003 §2.7, r = 6371 km, d = 0)")
    fig.subplots_adjust(bottom=0.2)
    png = out / "visibility.png"
    save_png(fig, png)
    plt.close(fig)
    H = np.concatenate([np.arange(10e3, 1000e3, 10e3), np.logspace(6, 8, 41)])
    alpha = earth_alpha(H)
    thr = visibility_thresholds(alpha)
    rows = np.column_stack([H / 1e3, np.degrees(alpha), np.degrees(thr["full"]),
                            np.degrees(thr["ellipse"]), np.degrees(thr["hyperbola"])])
    csv = out / "visibility.csv"
    write_csv(csv, ["height_km", "alpha_deg", "min_fov_full_earth_deg", "min_fov_ellipse_deg",
                    "min_fov_hyperbola_deg"], rows,
              "003 §2.7: a kind is visible iff the circular FOV exceeds its minimum (vision/design.py)")
    lim = float(np.degrees(visibility_thresholds(earth_alpha(800e3))["full"]))
    print(f"visibility: full Earth needs FOV > {lim:.1f} deg at 800 km; at 238 km: ellipse needs "
          f"FOV > {np.degrees(visibility_thresholds(earth_alpha(238e3))['ellipse']):.1f} deg")
    return [png, csv]


def _camera_hfov(camera) -> float:
    from vision.camera import fov_deg

    return fov_deg(camera)[0]


def run_spherical_error(out: Path) -> list[Path]:
    from vision.design import spherical_earth_error

    plt = _pyplot()
    lat = np.linspace(-90.0, 90.0, 721)
    heights = [0.0, 238e3, 1000e3]
    err = np.array([np.degrees(spherical_earth_error(np.radians(lat), h)) for h in heights])
    fig, ax = plt.subplots(figsize=(8, 4.8))
    for h, e in zip(heights, err):
        ax.plot(lat, e, label=f"height {h / 1e3:.0f} km")
    i = int(np.argmax(err[0]))
    ax.annotate(f"max {err[0, i]:.4f} deg at {lat[i]:.1f} deg", (lat[i], err[0, i]),
                xytext=(lat[i] + 8, err[0, i] - 0.09), arrowprops={"arrowstyle": "->"})
    ax.set_xlabel("geodetic latitude [deg]")
    ax.set_ylabel("angle error about East [deg]")
    ax.set_title("Ellipsoid normal vs direction to the Earth's centre (003 §2.8, fig. 8; WGS-84)")
    ax.set_xlim(-90, 90)
    ax.grid(True, alpha=0.3)
    ax.legend()
    png = out / "spherical_error.png"
    save_png(fig, png)
    plt.close(fig)
    csv = out / "spherical_error.csv"
    write_csv(csv, ["lat_deg"] + [f"error_deg_h{h / 1e3:.0f}km" for h in heights],
              np.column_stack([lat, err.T]),
              "geodetic minus geocentric latitude (vision.design.spherical_earth_error)")
    print(f"spherical-error: max {err[0].max():.4f} deg at latitude {lat[int(np.argmax(err[0]))]:.1f} deg "
          f"(h = 0)")
    return [png, csv]


def run_sensitivity(out: Path, params: list[str], camera=None, form: str = "auto",
                    aspect: float = 1.0, fov_axis: str = "vertical",
                    mounting: str = "side") -> list[Path]:
    from vision.design import SensitivityCase, sensitivity_sweep

    plt = _pyplot()
    if form == "auto":
        form = "003" if camera is None else "constrained"
    base = SensitivityCase(form=form, aspect=aspect, fov_axis=fov_axis, camera=camera,
                           mounting=mounting)
    if camera is not None:
        base = replace(base, fov_deg=_camera_hfov(camera), resolution=camera.height)
    where = (f"pinhole {round(aspect * base.resolution)}x{base.resolution} px, FOV across the "
             f"{fov_axis} side" if camera is None else f"camera {camera.name or 'file'} ({camera.model})")
    where += f", {mounting}-looking"
    files = []
    for param in params:
        vals, factor, label, figno = _SWEEPS[param]
        if param == "fov" and camera is not None:
            vals = vals[vals < 2 * math.degrees(camera.max_theta) - 1]
        res = sensitivity_sweep(param, vals * factor, base)
        roll3 = 3 * np.degrees(res["sigma_roll"])
        pitch3 = 3 * np.degrees(res["sigma_pitch"])
        fig, ax = plt.subplots(figsize=(8, 4.8))
        view = "normal to" if mounting == "side" else "along"
        other = "along" if mounting == "side" else "normal to"
        ax.plot(vals, roll3, label=f"roll (about the longitudinal axis, {view} the line of sight)")
        ax.plot(vals, pitch3, label=f"pitch (about the lateral axis, {other} the line of sight)")
        ax.set_xlabel(label)
        ax.set_ylabel("expected angle error, 3 sigma [deg]")
        fixed = {"height": f"H = {base.height / 1e3:.0f} km", "fov": f"FOV = {base.fov_deg:.1f} deg",
                 "resolution": f"{base.resolution} px", "atmosphere": f"d = {base.atmosphere / 1e3:.0f} km"}
        ax.set_title(f"003 §4 {figno}: " + ", ".join(v for k, v in fixed.items() if k != param)
                     + f"\n{where}; R = {base.R_px2:g} px^2, L = {base.L_px:g} px; form '{form}'",
                     fontsize=9)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        ax.legend()
        stem = f"sensitivity_{param}"
        png = out / f"{stem}.png"
        save_png(fig, png)
        plt.close(fig)
        csv = out / f"{stem}.csv"
        unit = {"height": "km", "fov": "deg", "resolution": "px", "atmosphere": "km"}[param]
        write_csv(csv, [f"{param}_{unit}", "roll_3sigma_deg", "pitch_3sigma_deg", "horizon_pixels"],
                  np.column_stack([vals, roll3, pitch3, res["pixels"]]),
                  f"003 §4 {figno}; {where}; form {form}; NaN: horizon not in view")
        files += [png, csv]
        msg = f"sensitivity {param}: roll {np.nanmin(roll3):.4f}..{np.nanmax(roll3):.4f} deg, " \
              f"pitch {np.nanmin(pitch3):.4f}..{np.nanmax(pitch3):.4f} deg (3 sigma)"
        if param == "fov":
            msg += (f"; roll minimal at {vals[np.nanargmin(roll3)]:.0f} deg, pitch minimal at "
                    f"{vals[np.nanargmin(pitch3)]:.0f} deg")
        print(msg)
    return files


def run(args) -> int:
    out = Path(args.output)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"-o {out}: cannot create the output directory ({exc.strerror})") from None
    camera = None
    if args.camera:
        from scenarios.config.camera import load_camera

        camera = load_camera(args.camera)
    if args.analysis != "sensitivity" and (args.param or args.form != "auto"):
        raise UserError(f"--param/--form apply to 'sensitivity', not to '{args.analysis}'")
    if not args.aspect > 0:
        raise UserError(f"--aspect {args.aspect}: expected width/height > 0")
    if args.analysis == "visibility":
        files = run_visibility(out, camera)
    elif args.analysis == "spherical-error":
        files = run_spherical_error(out)
    else:
        if camera is not None and args.form == "003":
            raise UserError("--form 003 (003 eq. (22)-(24) on z = f image points) needs the pinhole "
                            "camera; with --camera use --form linear or constrained")
        params = [args.param] if args.param else list(_SWEEPS)
        files = run_sensitivity(out, params, camera, args.form, args.aspect, args.fov_axis,
                                    args.mounting)
    for f in files:
        print(f"wrote {f}")
    return 0
