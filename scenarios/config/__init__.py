"""Configuration loaders: TOML files a user copies and edits, read into the dataclasses of ``nav``
and ``vision`` with every key checked. :mod:`.camera`: camera files (intrinsics from
``horizon-nav calibrate``) and payload masks; :mod:`.tuning`: the filter tuning (003 table 3);
:mod:`.vision`: the vision front end's settings. The defaults live in ``scenarios/library/``. The
public names below are imported from their module on first use (:mod:`scenarios._lazy`).
"""
from typing import TYPE_CHECKING

from scenarios._lazy import lazy_exports

if TYPE_CHECKING:
    from .camera import load_camera, read_payload_mask, save_camera
    from .tuning import load_tuning
    from .vision import load_vision_config

__all__ = ["load_camera", "save_camera", "read_payload_mask", "load_tuning", "load_vision_config"]
__getattr__ = lazy_exports(__name__, __file__)
