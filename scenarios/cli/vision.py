"""``horizon-nav vision``: Earth-nadir, Sun and Moon vectors (with covariance) from camera images.

Standalone use has no position or attitude prior, so the Earth is the substitute sphere of 003
§2.8 (radius: the Gaussian radius of curvature at ``--lat``, or the mean Earth radius) and the
nadir is the direction to that sphere's centre (close to the local vertical), not the geocentric
direction of the filter's observation (003 eq. (39)); the output says so.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from scenarios.errors import UserError

NAME = "vision"
HELP = "Earth-nadir / Sun / Moon direction vectors with covariance from camera images"


def add_arguments(p) -> None:
    p.add_argument("images", nargs="+", metavar="IMAGE", help="image files (JPEG, PNG, ...)")
    p.add_argument("--camera", required=True, help="camera file (TOML, scenarios/library/cameras/)")
    p.add_argument("--height", type=float, required=True, help="height above the ellipsoid [m]")
    p.add_argument("--lat", type=float, default=None,
                   help="geodetic latitude [deg] for the local radius of curvature (default: mean radius)")
    p.add_argument("--config", default=None, help="vision config TOML of overrides (default: none; example: "
                   "scenarios/library/vision/default.toml)")
    p.add_argument("--mask", default=None, help="payload mask image (non-zero = ignored), the camera's size")
    p.add_argument("--annotate", default=None, metavar="DIR", help="write annotated PNGs into DIR")
    p.add_argument("--json", action="store_true", help="print JSON (one object per image)")
    p.add_argument("--seed", type=int, default=0, help="RANSAC seed (default 0)")


def _record_dict(r) -> dict:
    return {"target": r.target, "vector_c": [float(v) for v in r.e_c],
            "covariance": np.asarray(r.P_c).round(15).tolist(),
            "covariance_overbound": np.asarray(r.P_overbound).round(15).tolist(),
            "sigma_deg": r.sigma_deg, "residual_rad2": r.residual, "pixel_count": r.pixel_count,
            "inlier_count": r.inlier_count, "conic_type": r.conic_type,
            "alpha_deg": math.degrees(r.alpha), "model": r.model}


def run(args) -> int:
    import cv2

    from scenarios.config.camera import load_camera, read_payload_mask
    from scenarios.flightlog.jpeg import decode_frame
    from scenarios.config.vision import load_vision_config
    from vision import mask as vmask
    from vision.frontend import FramePrior, process_frame

    cam = load_camera(args.camera)
    if not args.json:
        from vision.camera import describe
        print(describe(cam))
    cfg = load_vision_config(args.config, camera=cam)
    if not (math.isfinite(args.height) and 0 < args.height < 5e7):
        raise UserError(f"--height {args.height}: expected the height above the ellipsoid in metres (> 0)")
    lat = None
    if args.lat is not None:
        if not -90.0 <= args.lat <= 90.0:
            raise UserError(f"--lat {args.lat}: expected a latitude in degrees, -90..90")
        lat = math.radians(args.lat)
    mask = None
    if args.mask:
        mask = vmask.from_binary(read_payload_mask(args.mask, cam, f"--mask {args.mask}"))
    out_dir = Path(args.annotate) if args.annotate else None
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    model_note = ("sphere of radius " + ("the Gaussian radius of curvature at --lat" if lat is not None
                                          else "the mean Earth radius")
                  + " (no position/attitude prior: the nadir is the substitute sphere's centre, "
                    "003 §2.8, not the geocentric direction)")
    rng = np.random.default_rng(args.seed)
    results = []
    for path in args.images:
        p = Path(path)
        if not p.is_file():
            raise UserError(f"{path}: image file not found")
        data = np.fromfile(p, dtype=np.uint8)
        img = decode_frame(data.tobytes()) if data.size else None
        if img is None:
            raise UserError(f"{path}: not an image OpenCV can decode (expected JPEG, PNG, ...)")
        if img.shape[:2] != (cam.height, cam.width):
            raise UserError(f"{path}: size {img.shape[1]}x{img.shape[0]}, but camera file {args.camera} "
                            f"is {cam.width}x{cam.height}")
        res = process_frame(img, cam, cfg, height_m=args.height, mask=mask,
                            prior=FramePrior(lat=lat) if lat is not None else None, rng=rng)
        if out_dir is not None:
            from vision.annotate import annotate_frame

            ann = out_dir / (p.stem + "_vision.png")
            if not cv2.imwrite(str(ann), annotate_frame(img, cam, res)):
                raise UserError(f"--annotate {args.annotate}: could not write {ann}")
        entry = {"image": str(path), "model": res.model, "vectors": [_record_dict(r) for r in res.records],
                 "no_vector": dict(res.reasons),
                 "time_ms": {k: round(v * 1e3, 3) for k, v in res.timings.items()}}
        results.append(entry)
        if not args.json:
            print(f"{path}:")
            for r in res.records:
                v = ", ".join(f"{c:+.6f}" for c in r.e_c)
                print(f"  {r.target:5s} e_c = [{v}]  sigma {r.sigma_deg:.3f} deg (1s, eq. 37)  "
                      f"residual {r.residual:.3g} rad^2  {r.inlier_count}/{r.pixel_count} px  "
                      f"{r.conic_type}  alpha {math.degrees(r.alpha):.3f} deg")
            for t, why in res.reasons.items():
                print(f"  {t:5s} no vector: {why}")
            if res.model == "sphere":
                print(f"  earth model: {model_note}")
    if args.json:
        print(json.dumps(results if len(results) > 1 else results[0], indent=1))
    return 0
