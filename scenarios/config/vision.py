"""Vision configuration files (TOML) -> `vision.config.VisionConfig`.

A file holds overrides of the defaults, which live in the dataclasses of `vision.config` (see
scenarios/library/vision/default.toml for a commented example): a ``[vision]`` table
(``sphere_radius_m``) and one table per target (``[earth]``, ``[sun]``, ``[moon]``) whose keys are
the `TargetConfig` fields, with one nested table per stage named as the field holding its options
(``[earth.ransac]``, ``[earth.limb]``, ``[earth.limb.flank]``, ``[sun.detection.binarize]``, ...).
A key that is not given keeps its default: ``[moon]`` with ``enabled = true`` alone enables the
Moon with its default settings.

A key of a nested table may also be given flat in the target's table, under an unambiguous tail
of its path joined with "_" (``ransac_threshold_px``, ``limb_flank_profiles``,
``search_alpha_min_deg``; in the stages of `_BARE_STAGES` the bare name too: ``score_rays``,
``threshold``), or under a name of `_FLAT_NAMES`: with these, files in the flat format keep
working.

The accepted keys and their types come from the dataclasses' fields. Errors name the file, the
table and the key (`scenarios.errors.UserError`).
"""
from __future__ import annotations

import dataclasses
import os
from scenarios.config.toml_file import read_toml
from pathlib import Path
from typing import Any

from scenarios.errors import UserError
from vision.camera import FisheyeCamera
from vision.config import TARGETS, TargetConfig, VisionConfig, resolve_search_lines

__all__ = ["DEFAULT_VISION_FILE", "load_vision_config", "vision_config_from_dict"]

#: a commented example of a vision configuration file; loading it gives the defaults
DEFAULT_VISION_FILE = Path(__file__).parent.parent / "library" / "vision" / "default.toml"

#: flat names of the flat (un-nested) file format that are not a tail of their field's path
_FLAT_NAMES = {"threshold_method": ("detection", "binarize", "method"),
               "threshold_factor": ("detection", "binarize", "factor"),
               "min_length_px": ("detection", "min_length"),
               "max_residual_rad2": ("max_residual",),
               "side_check_px": ("side_check", "step_px"),
               "side_check_min": ("side_check", "min_agree")}


#: stages whose fields may be given flat under their bare names (as the flat format named them)
_BARE_STAGES = ("detection", "scoring", "ransac", "fit")


def _leaves(cls, prefix=()):
    """Paths of the non-dataclass fields of dataclass ``cls`` (nested through dataclass defaults),
    with the field's type annotation: {path: type string}."""
    out = {}
    for f in dataclasses.fields(cls):
        if dataclasses.is_dataclass(f.default):
            out.update(_leaves(type(f.default), prefix + (f.name,)))
        else:
            out[prefix + (f.name,)] = str(f.type)
    return out


def _flat_aliases(leaves) -> dict[str, tuple]:
    """{flat key: path} for the target table: every unambiguous tail of a nested path joined with
    "_" (the bare field name only in the stages of `_BARE_STAGES`) that is not a field of
    `TargetConfig` itself, and `_FLAT_NAMES`."""
    top = {p[0] for p in leaves if len(p) == 1}
    seen: dict[str, list] = {}
    for p in leaves:
        last = len(p) if p[0] in _BARE_STAGES else len(p) - 1
        for i in range(last):
            seen.setdefault("_".join(p[i:]), []).append(p)
    out = {k: v[0] for k, v in seen.items() if len(v) == 1 and k not in top}
    out.update(_FLAT_NAMES)
    return out


_LEAVES = _leaves(TargetConfig)
_FLAT = _flat_aliases(_LEAVES)
_TABLES = {p[:i] for p in _LEAVES for i in range(1, len(p))}


def _value(key: str, v, typ: str):
    """The TOML value ``v`` of a field of type ``typ`` (annotation string), checked and converted
    (integers for float fields to float, lists for tuple fields to tuples of floats)."""
    if typ == "bool":
        if not isinstance(v, bool):
            raise ValueError(f"{key} = {v!r}; expected true or false")
        return v
    if typ == "int":
        if isinstance(v, bool) or not isinstance(v, int):
            raise ValueError(f"{key} = {v!r}; expected an integer")
        return v
    if typ == "str":
        if not isinstance(v, str):
            raise ValueError(f"{key} = {v!r}; expected a string")
        return v
    if typ.startswith("tuple"):
        if not isinstance(v, list) or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in v):
            raise ValueError(f"{key} = {v!r}; expected a list of numbers")
        return tuple(float(x) for x in v)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ValueError(f"{key} = {v!r}; expected a number")
    return float(v)


def _collect(table: dict, path: tuple, name: str, where: str, out: dict) -> None:
    """Overrides {leaf path: value} of the table at ``path`` of target ``name`` into ``out``."""
    label = ".".join((name,) + path)
    keys = {p[len(path)] for p in _LEAVES if p[:len(path)] == path}
    flat = _FLAT if not path else {}
    unknown = set(table) - keys - set(flat)
    if unknown:
        raise UserError(f"{where}: [{label}] unknown key(s) {sorted(unknown)}; expected some of "
                        f"{sorted(keys | set(flat))}")
    for k, v in table.items():
        p = path + (k,) if k in keys else flat[k]
        if p in _TABLES:
            if not isinstance(v, dict):
                raise UserError(f"{where}: [{label}] {k} must be a table ([{label}.{k}])")
            _collect(v, p, name, where, out)
            continue
        if p in out:
            raise UserError(f"{where}: [{label}] {k}: {'.'.join(p)} is given twice")
        try:
            out[p] = _value(k, v, _LEAVES[p])
        except ValueError as exc:
            raise UserError(f"{where}: [{label}] {exc}") from None


def _replace(obj, overrides: dict):
    """``obj`` (a dataclass) with the leaf values of ``overrides`` {path: value} set."""
    kw: dict[str, Any] = {}
    nested: dict[str, dict] = {}
    for p, v in overrides.items():
        if len(p) == 1:
            kw[p[0]] = v
        else:
            nested.setdefault(p[0], {})[p[1:]] = v
    for k, sub in nested.items():
        kw[k] = _replace(getattr(obj, k), sub)
    return dataclasses.replace(obj, **kw)


def _target(name: str, d: dict[str, Any], default: TargetConfig, where: str) -> TargetConfig:
    overrides: dict[tuple, Any] = {}
    _collect(d, (), name, where, overrides)
    try:
        return _replace(default, overrides)
    except (ValueError, TypeError) as exc:
        raise UserError(f"{where}: [{name}] {exc}") from None


def vision_config_from_dict(doc: dict[str, Any], camera: FisheyeCamera | None = None,
                            where: str = "vision config") -> VisionConfig:
    """The default `VisionConfig` with the overrides of a parsed TOML document. ``camera`` sets the
    focal length of the Sun/Moon search-line spacing (`vision.config.resolve_search_lines`;
    default: the ATEK lens, 1110 px)."""
    focal = float(min(camera.fx, camera.fy)) if camera is not None else 1110.0
    unknown = set(doc) - set(TARGETS) - {"vision"}
    if unknown:
        raise UserError(f"{where}: unknown table(s) {sorted(unknown)}; expected [vision], "
                        f"[earth], [sun], [moon]")
    defaults = VisionConfig()
    kw: dict[str, Any] = {}
    for name in TARGETS:
        if name in doc:
            if not isinstance(doc[name], dict):
                raise UserError(f"{where}: [{name}] must be a table")
            kw[name] = _target(name, doc[name], getattr(defaults, name), where)
    v = doc.get("vision", {})
    extra = set(v) - {"sphere_radius_m"}
    if extra:
        raise UserError(f"{where}: [vision] unknown key(s) {sorted(extra)}; expected sphere_radius_m")
    if "sphere_radius_m" in v:
        r = v["sphere_radius_m"]
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not 6.3e6 < r < 6.4e6:
            raise UserError(f"{where}: [vision] sphere_radius_m = {r!r}; expected an Earth radius in m")
        kw["sphere_radius_m"] = float(r)
    return resolve_search_lines(dataclasses.replace(defaults, **kw), focal)


def load_vision_config(path: str | os.PathLike | None = None,
                       camera: FisheyeCamera | None = None) -> VisionConfig:
    """Load a vision configuration file of overrides (None: the defaults, no file read).
    UserError names the file."""
    if path is None:
        return vision_config_from_dict({}, camera, "defaults")
    doc, _ = read_toml(path, "vision config file")
    return vision_config_from_dict(doc, camera, str(Path(path)))
