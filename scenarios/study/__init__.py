"""Filter-tuning studies: Monte Carlo runs and parameter sweeps described by a study file
(docs/studies.md). :mod:`.studyfile` reads and validates the study file (variants, replicates, run
settings); :mod:`.runner` does one run (simulate, vectors from truth plus the vision error model,
filter, smoother, metrics); :mod:`.metrics` computes its NEES, NIS, RMS and misalignment figures;
:mod:`.execute` runs a whole study resumably on local processes or a Dask cluster and assembles the
tables; :mod:`.report` writes the HTML report. The public names below are imported from their
module on first use (:mod:`scenarios._lazy`).
"""
from typing import TYPE_CHECKING

from scenarios._lazy import lazy_exports

if TYPE_CHECKING:
    from .execute import run_study
    from .report import write_report
    from .runner import run_one
    from .studyfile import Study, load_study, study_from_text

__all__ = ["Study", "load_study", "study_from_text", "run_study", "run_one", "write_report"]
__getattr__ = lazy_exports(__name__, __file__)
