"""First-order Gauss-Markov vector errors (003 §6.3, eqs. (41)-(45)).

``zeta_k = Phi zeta_{k-1} + Gamma eta_{k-1}`` with ``Phi = (1 - dt/T_c) I`` and
``Gamma = (dt/T_c) I`` (eq. (42), a first-order discretisation of ``exp(-dt/T_c)``). The driving
noise covariance Q keeps the process at the quasi-stationary covariance ``P_c`` of the vision
measurement (003 eq. (33)): the discrete Lyapunov equation (44) solved for Q (eq. (45)).

The filter needs the product ``Gamma Q Gamma^T = P_c - Phi P_c Phi^T``, which is also the
discrete process noise of the exact transition ``Phi = exp(-dt/T_c) I``; :func:`gm_transition`
offers both forms (``exact=True`` is the default of the filter because it stays valid for any
``dt``, while eq. (42) needs ``dt << T_c``).
"""
from __future__ import annotations

import numpy as np

from nav.checks import as_matrices


def gm_transition(dt: float, tc: float, *, exact: bool = True) -> float:
    """Scalar of ``Phi = phi I``: ``exp(-dt/T_c)`` or 003 eq. (42)'s ``1 - dt/T_c``."""
    if tc <= 0:
        raise ValueError(f"tc: correlation time must be > 0, got {tc}")
    return float(np.exp(-dt / tc)) if exact else 1.0 - dt / tc


def gm_input_noise(P_c, dt: float, tc: float) -> np.ndarray:
    """Q of 003 eq. (45): ``Gamma^-1 (P_c - Phi P_c Phi^T) Gamma^-T`` with eq. (42)'s matrices."""
    P = as_matrices(P_c, "P_c")
    phi = gm_transition(dt, tc, exact=False)
    gam = dt / tc
    if gam <= 0:
        raise ValueError(f"dt: must be > 0 for eq. (45), got {dt}")
    return (P - phi * phi * P) / (gam * gam)


def gm_process_noise(P_c, dt: float, tc: float, *, exact: bool = True) -> np.ndarray:
    """Discrete process noise ``Gamma Q Gamma^T = P_c - Phi P_c Phi^T`` (eqs. (43)-(44))."""
    P = as_matrices(P_c, "P_c")
    phi = gm_transition(dt, tc, exact=exact)
    return (1.0 - phi * phi) * P


def gm_propagate(P_prev, P_c, dt: float, tc: float, *, exact: bool = True) -> np.ndarray:
    """Covariance propagation of eq. (43): ``Phi P Phi^T + Gamma Q Gamma^T``."""
    phi = gm_transition(dt, tc, exact=exact)
    return phi * phi * as_matrices(P_prev, "P_prev") + gm_process_noise(P_c, dt, tc, exact=exact)
