"""Import real flight data (IMU / GPS tables, camera footage) into a horizon-nav MCAP log, and export
logs back to tables, image folders and videos.

Modules (one job each):

* :mod:`.mapping` -- the TOML mapping file: dataclasses and validation (docs/import.md);
* :mod:`.units` -- unit names and SI factors;
* :mod:`.tables` -- CSV / Parquet reading (pyarrow), time bases, units, axis mapping;
* :mod:`.footage` -- video files and image folders with a time stamp per frame;
* :mod:`.validate` -- the validation report (rates, gaps, saturation, unit plausibility);
* :mod:`.build` -- assembles the MCAP log (``import_flight``);
* :mod:`.export` -- a log back to CSV + image folders + videos + a mapping file (``export_log``).

The public names below are imported from their module on first use (:mod:`scenarios._lazy`).
"""
from typing import TYPE_CHECKING

from scenarios._lazy import lazy_exports

if TYPE_CHECKING:
    from .build import ImportResult, ValidationFailed, import_flight, prepare
    from .export import ExportResult, export_log
    from .mapping import Mapping, load_mapping

__all__ = ["load_mapping", "Mapping", "prepare", "import_flight", "ImportResult", "ValidationFailed",
           "export_log", "ExportResult"]
__getattr__ = lazy_exports(__name__, __file__)
