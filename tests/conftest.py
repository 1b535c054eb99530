"""Shared test settings: astropy works offline with its bundled Earth-orientation data."""
import warnings

import pytest


@pytest.fixture(scope="session")
def astropy_offline():
    """astropy configured to never download (CI has no network); returns the modules used."""
    from astropy.utils import iers

    iers.conf.auto_download = False
    iers.conf.auto_max_age = None
    iers.conf.iers_degraded_accuracy = "warn"
    warnings.filterwarnings("ignore", module="astropy")
    warnings.filterwarnings("ignore", message=".*dubious year.*")
    return iers
