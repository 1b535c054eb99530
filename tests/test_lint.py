"""Static check: pyflakes finds no unused imports, undefined names or shadowed definitions."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_pyflakes_clean():
    r = subprocess.run([sys.executable, "-m", "pyflakes", "nav", "vision", "scenarios", "tests"],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
