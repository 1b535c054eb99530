"""Input checks shared by the pure-computation modules: clear ``ValueError`` naming the argument."""
from __future__ import annotations

import numpy as np


def as_finite(a, name: str) -> np.ndarray:
    """float64 array of ``a``; NaN or inf raises ``ValueError`` naming ``name``."""
    try:
        out = np.asarray(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number or numeric array, got {type(a).__name__}") from None
    if not np.all(np.isfinite(out)):
        raise ValueError(f"{name}: contains NaN or inf")
    return out


def as_vectors(a, name: str, dim: int = 3) -> np.ndarray:
    """float64 array of shape ``(..., dim)``, finite; otherwise ``ValueError`` naming ``name``."""
    out = as_finite(a, name)
    if out.ndim == 0 or out.shape[-1] != dim:
        raise ValueError(f"{name}: expected shape (..., {dim}), got {out.shape}")
    return out


def as_matrices(a, name: str, n: int = 3) -> np.ndarray:
    """float64 array of shape ``(..., n, n)``, finite; otherwise ``ValueError`` naming ``name``."""
    out = as_finite(a, name)
    if out.ndim < 2 or out.shape[-2:] != (n, n):
        raise ValueError(f"{name}: expected shape (..., {n}, {n}), got {out.shape}")
    return out


def unit(v: np.ndarray, name: str = "v") -> np.ndarray:
    """Normalise vectors along the last axis; a zero vector raises ``ValueError`` naming ``name``."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n == 0):
        raise ValueError(f"{name}: zero-length vector has no direction")
    return v / n
