"""Vision configuration files (TOML) -> `vision.frontend.VisionConfig`.

Format: see scenarios/library/vision/default.toml (one ``[earth]``, ``[sun]``, ``[moon]`` table,
an optional ``[vision]`` table). Keys not given take the `vision.frontend.TargetConfig` defaults.
Errors name the file, the table and the key (`scenarios.errors.UserError`).
"""
from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path
from typing import Any

from scenarios.errors import UserError
from vision.binarize import BinarizeConfig
from vision.borders import SearchConfig, search_line_spacing
from vision.camera import FisheyeCamera
from vision.candidates import DetectionConfig
from vision.frontend import TARGETS, TargetConfig, VisionConfig

__all__ = ["DEFAULT_VISION_FILE", "load_vision_config", "vision_config_from_dict"]

DEFAULT_VISION_FILE = Path(__file__).parent.parent / "library" / "vision" / "default.toml"

_BIN_KEYS = {"threshold": "threshold", "threshold_method": "method", "threshold_factor": "factor",
             "threshold_min": "threshold_min", "threshold_max": "threshold_max",
             "gate_min": "gate_min", "gate_max": "gate_max", "sample_step": "sample_step"}
_TARGET_KEYS = {"enabled", "min_pixels", "max_candidates", "score_rays", "fit_rays",
                "ransac_threshold_px", "ransac_max_hypotheses", "ransac_confidence",
                "min_inlier_fraction", "R_px2", "L_px", "atmosphere_m", "atmosphere_sigma_m",
                "alpha_min_deg", "alpha_max_deg", "side_check_px", "side_check_min",
                "side_check_rays", "edge_offset_px", "direct_outlier_fraction", "compete_fraction", "gate_deg", "curvature_tol_deg",
                "limb_fraction", "limb_channel", "limb_height_m", "limb_height_sigma_m",
                "limb_min_sun_elev_deg", "limb_min_used", "limb_sun_path", "limb_scale_height_m", "limb_profile_below_deg",
                "limb_sun_path_sigma", "limb_twilight_el_deg", "limb_twilight_dh_m",
                "limb_twilight_sigma_m", "limb_refit_threshold_px", "limb_aerosol_weight", "limb_aerosol_g",
                "limb_flank_profiles", "limb_flank_min_profiles", "limb_flank_sigma_m",
                "limb_calibrate_below", "limb_calibrate_min_points",
                "limb_calibrate_sigma_m"}
#: target keys whose values must be integers
_INT_KEYS = ("min_pixels", "max_candidates", "score_rays", "fit_rays", "ransac_max_hypotheses", "side_check_rays",
             "limb_channel", "limb_calibrate_min_points", "limb_flank_profiles", "limb_flank_min_profiles")
_OTHER = {"max_residual_rad2", "min_length_px", "search_alpha_min_deg", "search_line_spacing_px",
          "otsu_range"}


def _target(name: str, d: dict[str, Any], focal_px: float, where: str) -> TargetConfig:
    unknown = set(d) - set(_BIN_KEYS) - _TARGET_KEYS - _OTHER
    if unknown:
        raise UserError(f"{where}: [{name}] unknown key(s) {sorted(unknown)}; expected some of "
                        f"{sorted(set(_BIN_KEYS) | _TARGET_KEYS | _OTHER)}")
    try:
        bkw = {_BIN_KEYS[k]: v for k, v in d.items() if k in _BIN_KEYS}
        if "otsu_range" in d:
            bkw["otsu_range"] = tuple(d["otsu_range"])
        binar = BinarizeConfig(**bkw)
        spacing = d.get("search_line_spacing_px")
        if spacing is None and "search_alpha_min_deg" in d:
            spacing = search_line_spacing(focal_px, math.radians(float(d["search_alpha_min_deg"])))
        det = DetectionConfig(binar, SearchConfig(line_spacing_px=spacing), int(d.get("min_length_px", 20)))
        kw = {k: v for k, v in d.items() if k in _TARGET_KEYS}
        for k in _INT_KEYS:
            if k in kw:
                if not isinstance(kw[k], int) or isinstance(kw[k], bool):
                    raise ValueError(f"{k} = {kw[k]!r}; expected an integer")
        for k in ("limb_twilight_el_deg", "limb_twilight_dh_m"):
            if k in kw:
                if not isinstance(kw[k], list) or any(isinstance(v, bool) or not isinstance(v, (int, float))
                                                      for v in kw[k]):
                    raise ValueError(f"{k} = {kw[k]!r}; expected a list of numbers")
                kw[k] = tuple(float(v) for v in kw[k])
        for k, v in kw.items():
            if k in ("limb_twilight_el_deg", "limb_twilight_dh_m"):
                continue
            if k not in ("enabled", "limb_sun_path") and k not in _INT_KEYS:
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ValueError(f"{k} = {v!r}; expected a number")
                kw[k] = float(v)
        for k in ("enabled", "limb_sun_path"):
            if k in kw and not isinstance(kw[k], bool):
                raise ValueError(f"{k} = {kw[k]!r}; expected true or false")
        if "max_residual_rad2" in d:
            kw["max_residual"] = float(d["max_residual_rad2"])
        return TargetConfig(detection=det, **kw)
    except (ValueError, TypeError) as exc:
        raise UserError(f"{where}: [{name}] {exc}") from None


def vision_config_from_dict(doc: dict[str, Any], camera: FisheyeCamera | None = None,
                            where: str = "vision config") -> VisionConfig:
    """Build a VisionConfig from a parsed TOML document. ``camera`` sets the focal length of the
    Sun/Moon search-line spacing (default: the ATEK lens, 1110 px)."""
    focal = float(min(camera.fx, camera.fy)) if camera is not None else 1110.0
    unknown = set(doc) - set(TARGETS) - {"vision"}
    if unknown:
        raise UserError(f"{where}: unknown table(s) {sorted(unknown)}; expected [vision], "
                        f"[earth], [sun], [moon]")
    kw: dict[str, Any] = {}
    for name in TARGETS:
        if name in doc:
            if not isinstance(doc[name], dict):
                raise UserError(f"{where}: [{name}] must be a table")
            kw[name] = _target(name, doc[name], focal, where)
    v = doc.get("vision", {})
    extra = set(v) - {"sphere_radius_m"}
    if extra:
        raise UserError(f"{where}: [vision] unknown key(s) {sorted(extra)}; expected sphere_radius_m")
    if "sphere_radius_m" in v:
        r = v["sphere_radius_m"]
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not 6.3e6 < r < 6.4e6:
            raise UserError(f"{where}: [vision] sphere_radius_m = {r!r}; expected an Earth radius in m")
        kw["sphere_radius_m"] = float(r)
    return VisionConfig(**kw)


def load_vision_config(path: str | os.PathLike | None = None,
                       camera: FisheyeCamera | None = None) -> VisionConfig:
    """Load a vision configuration file (None: the library default). UserError names the file."""
    p = Path(path) if path is not None else DEFAULT_VISION_FILE
    try:
        with open(p, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise UserError(f"{p}: vision config file not found") from None
    except OSError as exc:
        raise UserError(f"{p}: cannot read vision config ({exc.strerror})") from None
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"{p}: not valid TOML ({exc})") from None
    return vision_config_from_dict(doc, camera, str(p))
