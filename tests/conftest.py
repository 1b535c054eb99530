"""Shared test settings: astropy works offline with its bundled Earth-orientation data."""
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


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


@pytest.fixture(scope="session")
def vlog(tmp_path_factory):
    """A short simulated log with truth-derived vectors and no images: atek, T+0..T+140 (the
    cameras run from T+60), written by the CLI as a user would."""
    p = tmp_path_factory.mktemp("replay") / "v.mcap"
    subprocess.run([sys.executable, "-m", "scenarios.cli", "simulate", "atek", "--no-images", "--vectors",
                    "--duration", "140", "-o", str(p), "--quiet"], check=True, cwd=ROOT, capture_output=True)
    return p


@pytest.fixture(scope="session")
def ilog(tmp_path_factory):
    """A short rendered log: atek T+0..T+64, both cameras at 1 Hz from T+60 (10 frames)."""
    p = tmp_path_factory.mktemp("img") / "i.mcap"
    subprocess.run([sys.executable, "-m", "scenarios.cli", "simulate", "atek", "--duration", "64", "-o", str(p),
                    "--quiet"], check=True, cwd=ROOT, capture_output=True)
    return p
