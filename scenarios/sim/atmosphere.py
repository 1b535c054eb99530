"""U.S. Standard Atmosphere 1976: temperature, pressure and density from 0 to 1000 km (for drag).

Below 86 km geometric height the seven layers of the standard are evaluated in closed form
(hydrostatic equation with linear molecular-temperature profiles in geopotential height;
U.S. Standard Atmosphere 1976, NOAA-S/T 76-1562, eqs. (18), (23), (33a), (33b), (42)). Above 86 km the
standard integrates diffusion equations for each species; here the density is the standard's own
tabulated values (Table I of the same report, at the heights of :data:`_RHO_TABLE`) interpolated
linearly in log density (the scale height changes slowly, so the interpolation error stays below about
3 % between nodes, far below the day-to-day variability of the thermosphere that a real flight sees).

Heights are geometric heights above the ellipsoid [m] (the standard is defined above mean sea level;
the geoid difference of some tens of metres is irrelevant for drag). Vectorised over arrays.
"""
from __future__ import annotations

import numpy as np

from nav.checks import as_finite

#: Gas constant of the standard [J/(kmol K)], mean molar mass of air [kg/kmol], g0 [m/s^2], r0 [m].
R_STAR = 8314.32
M0 = 28.9644
G0 = 9.80665
R0 = 6_356_766.0
#: Layer bases in geopotential height [m'] and molecular-temperature lapse rates [K/m'].
_HB = np.array([0.0, 11_000.0, 20_000.0, 32_000.0, 47_000.0, 51_000.0, 71_000.0, 84_852.0])
_LB = np.array([-6.5e-3, 0.0, 1.0e-3, 2.8e-3, 0.0, -2.8e-3, -2.0e-3])
T0 = 288.15
P0 = 101_325.0
#: Top of the closed-form part: 86 km geometric = 84.852 km geopotential.
Z_86 = 86_000.0
H_MAX = 1_000_000.0


def _layer_bases():
    tb = [T0]
    pb = [P0]
    for i in range(len(_LB)):
        dh = _HB[i + 1] - _HB[i]
        t1 = tb[i] + _LB[i] * dh
        if _LB[i] == 0.0:
            p1 = pb[i] * np.exp(-G0 * M0 * dh / (R_STAR * tb[i]))
        else:
            p1 = pb[i] * (tb[i] / t1) ** (G0 * M0 / (R_STAR * _LB[i]))
        tb.append(t1)
        pb.append(p1)
    return np.array(tb), np.array(pb)


_TB, _PB = _layer_bases()

# US-1976 Table I densities [kg/m^3] above 86 km (geometric height [km], density).
_RHO_TABLE = np.array([
    (86, 6.958e-6), (90, 3.416e-6), (95, 1.393e-6), (100, 5.604e-7), (105, 2.325e-7),
    (110, 9.708e-8), (115, 4.289e-8), (120, 2.222e-8), (130, 8.152e-9), (140, 3.831e-9),
    (150, 2.076e-9), (160, 1.233e-9), (170, 7.815e-10), (180, 5.194e-10), (190, 3.581e-10),
    (200, 2.541e-10), (220, 1.367e-10), (250, 6.073e-11), (300, 1.916e-11), (350, 7.014e-12),
    (400, 2.803e-12), (450, 1.184e-12), (500, 5.215e-13), (600, 1.137e-13), (700, 3.070e-14),
    (800, 1.136e-14), (900, 5.759e-15), (1000, 3.561e-15)])


def geopotential_height(z) -> np.ndarray:
    """Geopotential height H = r0 z / (r0 + z) [m'] of geometric height z [m] (US-1976 eq. (18))."""
    z = as_finite(z, "h")
    return R0 * z / (R0 + z)


def _lower(z):
    """Molecular temperature and pressure below 86 km (clipped to the closed-form range)."""
    h = geopotential_height(np.clip(z, -5000.0, Z_86))
    i = np.clip(np.searchsorted(_HB, h, side="right") - 1, 0, len(_LB) - 1)
    lb, tb, pb, hb = _LB[i], _TB[i], _PB[i], _HB[i]
    t = tb + lb * (h - hb)
    with np.errstate(divide="ignore", invalid="ignore"):
        p_grad = pb * (tb / t) ** (G0 * M0 / (R_STAR * np.where(lb == 0, 1.0, lb)))
    p_iso = pb * np.exp(-G0 * M0 * (h - hb) / (R_STAR * tb))
    return t, np.where(lb == 0.0, p_iso, p_grad)


def _check(h):
    h = as_finite(h, "h")
    if np.any(h > H_MAX) or np.any(h < -5000.0):
        raise ValueError(f"h: the standard atmosphere is tabulated from -5 km to {H_MAX / 1e3:.0f} km; "
                         f"got {float(np.min(h)):.0f} .. {float(np.max(h)):.0f} m")
    return h


def temperature(h) -> np.ndarray:
    """Molecular-scale temperature [K] for heights up to 86 km (NaN above: not needed for drag)."""
    h = _check(h)
    t, _ = _lower(h)
    return np.where(h <= Z_86, t, np.nan)


def pressure(h) -> np.ndarray:
    """Pressure [Pa] for heights up to 86 km (NaN above)."""
    h = _check(h)
    _, p = _lower(h)
    return np.where(h <= Z_86, p, np.nan)


def density(h) -> np.ndarray:
    """Mass density [kg/m^3], -5 km to 1000 km (US-1976; log-linear in Table I above 86 km)."""
    h = _check(h)
    t, p = _lower(h)
    rho_low = p * M0 / (R_STAR * t)
    rho_high = np.exp(np.interp(h / 1e3, _RHO_TABLE[:, 0], np.log(_RHO_TABLE[:, 1])))
    return np.where(h <= Z_86, rho_low, rho_high)


def density_table(step_m: float = 100.0, h_max: float = H_MAX) -> tuple[float, np.ndarray]:
    """(step, log density at 0, step, 2 step, ... h_max) for the truth kernel's linear look-up.

    With 100 m nodes the log-linear interpolation error is below 1e-4 relative below 86 km
    (scale height >= 5.8 km: error <= (step / H)^2 / 8).
    """
    h = np.arange(0.0, h_max + step_m / 2, step_m)
    return float(step_m), np.log(density(h))
