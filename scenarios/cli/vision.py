"""``horizon-nav vision``: Earth-nadir, Sun and Moon vectors (with covariance) from camera images.

Per-image metadata (time, height, latitude, position) comes from ``--meta`` (a CSV/JSON sidecar,
`scenarios.config.image_meta`) or applies to every image (``--height``, ``--lat``); ``--earth``,
``--sun``, ``--moon`` (and ``--no-...``) switch the targets without a config file. With a time the
Moon is fitted with its apparent radius from the ephemeris; the Sun found in the same image gives
the Moon's phase geometry (`vision.moon`). ``--json`` prints one object per image and line:
``{"image", "earth", "sun", "moon", "reasons", ...}`` (`image_entry`).

Standalone use has no attitude prior, so the Earth is first fitted on the substitute sphere of 003
§2.8 (radius: the Gaussian radius of curvature at ``--lat``, or the mean Earth radius): its nadir
is the direction to that sphere's centre (close to the local vertical), not the geocentric
direction of the filter's observation (003 eq. (39)); the output says so. With a position and a
time in the sidecar and the Moon or the Sun in the image, the attitude follows from the two
vectors and the Earth is refitted on the ellipsoid (`ellipsoid_refit`): the geocentric nadir.
"""
from __future__ import annotations

import json
import math
import sys
import zlib
from pathlib import Path

import numpy as np

from scenarios.errors import UserError

NAME = "vision"
HELP = "Earth-nadir / Sun / Moon direction vectors with covariance from camera images"
#: below this height [m] a note asks whether the height was given in km (the horizon dips 1 deg at 1 km)
LOW_HEIGHT_M = 1000.0


def add_arguments(p) -> None:
    import argparse

    p.add_argument("images", nargs="+", metavar="IMAGE", help="image files (JPEG, PNG, ...)")
    p.add_argument("--camera", required=True, help="camera file (read by scenarios/config/camera.py; "
                   "examples in scenarios/library/cameras/)")
    p.add_argument("--height", type=float, default=None,
                   help="height above the ellipsoid [m] of every image (the Earth needs it, from here or --meta)")
    p.add_argument("--lat", type=float, default=None,
                   help="geodetic latitude [deg] for the local radius of curvature (default: mean radius)")
    p.add_argument("--meta", default=None, metavar="FILE",
                   help="per-image metadata, CSV or JSON matched by image file name: time, height_m, lat_deg, "
                        "lon_deg or x_m/y_m/z_m (scenarios/config/image_meta.py); overrides --height/--lat")
    for t, on in (("earth", "on"), ("sun", "on"), ("moon", "off")):
        p.add_argument(f"--{t}", action=argparse.BooleanOptionalAction, default=None,
                       help=f"process the {t.capitalize()} or not (default: the config file's, else {on})")
    p.add_argument("--config", default=None, help="vision config TOML of overrides (default: none; example: "
                   "scenarios/library/vision/default.toml)")
    p.add_argument("--mask", default=None, help="payload mask image (non-zero = ignored), the camera's size")
    p.add_argument("--annotate", default=None, metavar="DIR", help="write annotated PNGs into DIR")
    p.add_argument("--json", action="store_true", help="print JSON, one object per image and line")
    p.add_argument("--bit-depth", type=int, default=None, metavar="BITS",
                   help="significant bits of 16-bit images (9-16, the camera's ADC depth); default: per image, the "
                        "smallest of 10/12/14/16 that holds its largest value (a dark image may then be brightened)")
    p.add_argument("--seed", type=int, default=0,
                   help="RANSAC seed (default 0); each image's generator is seeded by it and the image's file name, "
                        "so an image gives the same result alone or in any batch")


def image_rng(seed: int, name: str) -> np.random.Generator:
    """RANSAC generator of one image: seeded by ``seed`` and the image's file ``name`` (CRC-32),
    not by its place in the call, so that its vectors do not depend on the other images."""
    return np.random.default_rng([seed, zlib.crc32(name.encode("utf-8"))])


def _record_dict(r) -> dict:
    return {"target": r.target, "vector_c": [float(v) for v in r.e_c],
            "covariance": np.asarray(r.P_c).round(15).tolist(),
            "covariance_overbound": np.asarray(r.P_overbound).round(15).tolist(),
            "sigma_deg": r.sigma_deg, "residual_rad2": r.residual, "pixel_count": r.pixel_count,
            "inlier_count": r.inlier_count, "conic_type": r.conic_type,
            "alpha_deg": math.degrees(r.alpha), "model": r.model}


def _target_dict(r, cov_c: bool = True) -> dict:
    """The ``--json`` entry of one target: vector, covariance [rad^2], overbound, fit figures."""
    return {"vector_c": [float(v) for v in r.e_c], "cov_c": np.asarray(r.P_c).round(18).tolist(),
            "cov_overbound_c": np.asarray(r.P_overbound).round(18).tolist(), "sigma_deg": r.sigma_deg,
            "alpha_deg": math.degrees(r.alpha), "residual_rad2": r.residual, "pixel_count": r.pixel_count,
            "inlier_count": r.inlier_count, "conic_type": r.conic_type}


def image_entry(name: str, res, cfg, attitude: str | None = None) -> dict:
    """One image's ``--json`` object: ``{"image", "earth", "sun", "moon"}`` (each target's
    vector and covariance, or null with its reason in ``"reasons"``; the Earth with the edge
    height fitted with its nadir, `VectorRecord.edge_height_m`, its model, and ``attitude_from``,
    the body whose direction oriented the ellipsoid (`ellipsoid_refit`) or null), plus the model,
    the vector records and the stage timings."""
    out = {"image": name}
    for t in ("earth", "sun", "moon"):
        r = res.record(t)
        out[t] = None if r is None else _target_dict(r)
    if out["earth"] is not None:
        r = res.record("earth")
        out["earth"].update(model=res.model, attitude_from=attitude, edge_height_m=float(r.edge_height_m),
                            edge_height_sigma_m=float(r.edge_height_sigma_m))
    out["reasons"] = dict(res.reasons)
    for t in ("earth", "sun", "moon"):
        if not cfg.target(t).enabled:
            out["reasons"][t] = f"not processed (--no-{t} or the config's [{t}] enabled = false)"
    out.update(model=res.model, vectors=[_record_dict(r) for r in res.records],
               time_ms={k: round(v * 1e3, 3) for k, v in res.timings.items()})
    return out


def _config(args, cam):
    """The vision config of the call: the file's, with --earth/--sun/--moon switched."""
    import dataclasses

    from scenarios.config.vision import load_vision_config

    cfg = load_vision_config(args.config, camera=cam)
    kw = {t: dataclasses.replace(cfg.target(t), enabled=on)
          for t, on in (("earth", args.earth), ("sun", args.sun), ("moon", args.moon)) if on is not None}
    return dataclasses.replace(cfg, **kw) if kw else cfg


def _frame_inputs(path: Path, meta, args, lat_cli):
    """(height_m, FramePrior or None, --meta's row or None) of one image from --meta's row (if any)
    and --height/--lat; with a time, the Moon's apparent radius from the ephemeris distance (from
    the position when known, else from the Earth's centre: within 1.7 % below 6400 km)."""
    from nav import ephemeris
    from vision.frontend import FramePrior

    m = None
    if meta is not None:
        m = meta.get(path.name)
        if m is None:
            raise UserError(f"--meta {args.meta}: no row for image {path.name}")
    h = m.height_m if m is not None and m.height_m is not None else args.height
    lat = m.lat if m is not None and m.lat is not None else lat_cli
    moon_alpha = None
    if m is not None and m.time_ns is not None:
        try:
            moon_e = ephemeris.moon_position_e(m.time_ns)
        except ValueError as exc:
            raise UserError(f"--meta {args.meta}, image {path.name}, column time: {exc}") from None
        x = m.x_e if m.x_e is not None else np.zeros(3)
        moon_alpha = float(ephemeris.apparent_radius(moon_e, x, ephemeris.MOON_RADIUS))
    kw = {k: v for k, v in (("lat", lat), ("moon_alpha", moon_alpha)) if v is not None}
    return h, (FramePrior(**kw) if kw else None), m


def ellipsoid_refit(img, cam, cfg, res, x_e, t_ns: int, mask=None, rng=None):
    """``(res, note)``: with the image's position ``x_e`` [m] and time ``t_ns`` and the Moon or the
    Sun found beside the Earth, the Earth refitted on the WGS-84 ellipsoid (`vision.oblate`, 003
    §2.8) with the camera attitude by TRIAD (`nav.rotation.triad`: the substitute sphere's nadir,
    the local vertical, matched exactly; the body's direction from the ephemeris fixes the rotation
    about it): the geocentric nadir instead of the sphere's centre, which differs from it by the
    Earth's flattening (up to ~0.18 deg at 45 deg latitude from 500 km). The attitude orients the
    ellipsoid and gates the fit; the nadir itself is the horizon's. ``note`` names the body used;
    ``(res, None)`` when there is nothing to refit with. The sphere's result stands, with the
    reason as ``earth_ellipsoid``, when the refit finds no Earth vector, when the body is within a
    degree of the nadir (no rotation about it), or when the angle between
    the Earth's nadir and the body in the image differs from the one the ephemeris gives at the
    sidecar's time and position by more than 3 sigma of the two vectors (`body_angle_check`: a
    wrong time or position, or a wrong detection)."""
    import dataclasses

    from nav import earth, ephemeris
    from nav.rotation import triad
    from vision.frontend import FramePrior, process_frame

    e = res.record("earth")
    bodies = [r for r in (res.record("moon"), res.record("sun")) if r is not None]
    if e is None or not bodies or res.model != "sphere":
        return res, None
    body = min(bodies, key=lambda r: r.sigma_deg)
    x = np.asarray(x_e, float)
    lat, lon, _ = earth.ecef_to_geodetic(x)
    down = earth.R_en(lat, lon)[:, 2]
    ref = {"moon": ephemeris.moon_direction_e, "sun": ephemeris.sun_direction_e}[body.target](t_ns, x)
    try:
        why = body_angle_check(e, body, down, ref)
        R_ec = None if why else triad(e.e_c, body.e_c, down, ref)
    except ValueError as exc:      # the body within a degree of the nadir: no rotation about it
        why = f"no attitude from the Earth and the {body.target.capitalize()}: {exc}"
    if why:
        return dataclasses.replace(res, reasons=dict(res.reasons, earth_ellipsoid=why)), None
    only_earth = dataclasses.replace(cfg, sun=dataclasses.replace(cfg.sun, enabled=False),
                                     moon=dataclasses.replace(cfg.moon, enabled=False))
    ell = process_frame(img, cam, only_earth, mask=mask, prior=FramePrior(x_e=x, R_ec=R_ec), rng=rng)
    if ell.record("earth") is None:
        reasons = dict(res.reasons, earth_ellipsoid=ell.reasons.get("earth", "no Earth vector"))
        return dataclasses.replace(res, reasons=reasons), None
    records = [ell.record("earth")] + [r for r in res.records if r.target != "earth"]
    targets = dict(res.targets, earth=ell.targets["earth"])
    return dataclasses.replace(res, records=records, targets=targets, model=ell.model), body.target


def body_angle_check(e, body, down_e, body_e) -> str:
    """Empty when the angle between the Earth's nadir ``e`` and ``body`` (`VectorRecord`s, camera
    frame) agrees with the one between the local vertical ``down_e`` and the body's ephemeris
    direction ``body_e`` within 3 sigma (the two vectors' 1-sigma overbounds combined); else the
    reason. The angle needs no attitude, so it checks the sidecar's time and position against
    the image (the Moon moves ~15 deg an hour in the Earth-fixed frame)."""
    from nav.rotation import angle_between

    a_c = math.degrees(float(angle_between(e.e_c, body.e_c)))
    a_e = math.degrees(float(angle_between(down_e, body_e)))
    tol = 3.0 * math.hypot(e.sigma_deg, body.sigma_deg)
    if abs(a_c - a_e) <= tol:
        return ""
    return (f"the Earth-{body.target.capitalize()} angle is {a_c:.2f} deg in the image and {a_e:.2f} deg from the "
            f"ephemeris at the sidecar's time and position ({abs(a_c - a_e):.2f} deg apart, > 3 sigma = {tol:.2f} "
            f"deg): a wrong time (UTC?), position or detection; the sphere's nadir is kept")


def _check_cli(args):
    """--height/--lat checked; returns the latitude [rad] or None."""
    if args.height is not None and not (math.isfinite(args.height) and 0 < args.height < 5e7):
        raise UserError(f"--height {args.height}: expected the height above the ellipsoid in metres (> 0)")
    if args.bit_depth is not None and not 9 <= args.bit_depth <= 16:
        raise UserError(f"--bit-depth {args.bit_depth}: expected the 16-bit images' significant bits, 9..16")
    if args.lat is None:
        return None
    if not -90.0 <= args.lat <= 90.0:
        raise UserError(f"--lat {args.lat}: expected a latitude in degrees, -90..90")
    return math.radians(args.lat)


def _read_image(path: Path, args, cam):
    """The image as the front end takes it (`scenarios.flightlog.jpeg.decode_image`: 8-bit, 16-bit
    data scaled by its significant bits, said on stderr) or a one-line error."""
    from scenarios.flightlog.jpeg import decode_image

    if not path.is_file():
        raise UserError(f"{path}: image file not found")
    data = np.fromfile(path, dtype=np.uint8)
    try:
        img, bits = decode_image(data.tobytes(), str(path), args.bit_depth) if data.size else (None, 0)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    if img is None:
        raise UserError(f"{path}: not an image OpenCV can decode (expected JPEG, PNG, ...)")
    if bits > 8:
        how = "given by --bit-depth" if args.bit_depth else "from its largest value"
        print(f"{path}: 16-bit image, {bits} significant bits ({how}), scaled to 8 bits", file=sys.stderr)
    if img.shape[:2] != (cam.height, cam.width):
        raise UserError(f"{path}: size {img.shape[1]}x{img.shape[0]}, but camera file {args.camera} "
                        f"is {cam.width}x{cam.height}{_orientation_hint(data, cam)}")
    return img


def _orientation_hint(data: np.ndarray, cam) -> str:
    """For a size error: why, when the file's EXIF orientation turns it to the camera's size (the
    image is read as the sensor stored it, and the camera file was made from turned images)."""
    import cv2

    turned = cv2.imdecode(data, cv2.IMREAD_REDUCED_GRAYSCALE_8)
    shown = cv2.imdecode(data, cv2.IMREAD_REDUCED_GRAYSCALE_8 | cv2.IMREAD_IGNORE_ORIENTATION)
    if turned is None or shown is None or turned.shape == shown.shape:
        return ""
    if (turned.shape[0] > turned.shape[1]) != (cam.height > cam.width):
        return ""
    return ("; its EXIF orientation turns it to the camera file's shape, but images are read as the "
            "sensor stored them: calibrate from the images as stored (horizon-nav calibrate does)")


def _print_text(path, res, model_note, attitude: str | None = None) -> None:
    print(f"{path}:")
    for r in res.records:
        v = ", ".join(f"{c:+.6f}" for c in r.e_c)
        print(f"  {r.target:5s} e_c = [{v}]  sigma {r.sigma_deg:.3f} deg (1s, eq. 37)  "
              f"residual {r.residual:.3g} rad^2  {r.inlier_count}/{r.pixel_count} px  "
              f"{r.conic_type}  alpha {math.degrees(r.alpha):.3f} deg")
    for t, why in res.reasons.items():
        if t != "earth_ellipsoid":
            print(f"  {t:5s} no vector: {why}")
    if res.model == "sphere":
        print(f"  earth model: {model_note}")
        if "earth_ellipsoid" in res.reasons:
            print(f"  earth model: no ellipsoid refit: {res.reasons['earth_ellipsoid']}")
    elif attitude is not None:
        print(f"  earth model: WGS-84 ellipsoid, oriented by the attitude from the Earth and the {attitude.capitalize()} "
              f"(TRIAD): the geocentric nadir")


def run(args) -> int:
    import cv2

    from scenarios.config.camera import load_camera, read_payload_mask
    from scenarios.config.image_meta import read_image_meta
    from vision import mask as vmask
    from vision.frontend import process_frame

    cam = load_camera(args.camera)
    if not args.json:
        from vision.camera import describe
        print(describe(cam))
    cfg = _config(args, cam)
    lat_cli = _check_cli(args)
    meta = read_image_meta(args.meta) if args.meta else None
    mask = None
    if args.mask:
        mask = vmask.from_binary(read_payload_mask(args.mask, cam, f"--mask {args.mask}"))
    out_dir = Path(args.annotate) if args.annotate else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    model_note = ("sphere of radius the Gaussian radius of curvature at the latitude, else the mean Earth radius"
                  " (no attitude prior: the nadir is the substitute sphere's centre, "
                  "003 §2.8, not the geocentric direction)")
    for path in args.images:
        p = Path(path)
        rng = image_rng(args.seed, p.name)
        h, prior, row = _frame_inputs(p, meta, args, lat_cli)
        if cfg.earth.enabled and h is None:
            raise UserError(f"{path}: no height for the Earth (003 eq. (5)): give --height, a height_m or "
                            f"position column in --meta, or --no-earth")
        if cfg.earth.enabled and h < LOW_HEIGHT_M:
            print(f"{path}: height {h:g} m above the ellipsoid (heights are in metres: {h:g} km would be "
                  f"{h * 1e3:g}); the Earth's horizon from there is nearly flat", file=sys.stderr)
        img = _read_image(p, args, cam)
        res = process_frame(img, cam, cfg, height_m=h, mask=mask, prior=prior, rng=rng)
        attitude = None
        if row is not None and row.x_e is not None and row.time_ns is not None:
            res, attitude = ellipsoid_refit(img, cam, cfg, res, row.x_e, row.time_ns, mask, rng)
        if out_dir is not None:
            from vision.annotate import annotate_frame

            ann = out_dir / (p.stem + "_vision.png")
            if not cv2.imwrite(str(ann), annotate_frame(img, cam, res)):
                raise UserError(f"--annotate {args.annotate}: could not write {ann}")
        if args.json:
            print(json.dumps(image_entry(p.name, res, cfg, attitude)), flush=True)
        else:
            _print_text(path, res, model_note, attitude)
    return 0
