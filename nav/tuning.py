"""Navigation filter tuning: dataclasses and parsing from a dict or a TOML string (no file I/O).

The default values are 003 table 3 (CONVENTIONS.md "The reference flight"); the TOML file that
holds them lives in ``scenarios/library/tuning/table3.toml`` and is read by
``scenarios/tuning_file.py``. Every error group is ``"E"`` (estimated), ``"C"`` (considered only,
Schmidt-Kalman, 003 §6.1 and ref. [14]) or ``"off"`` (not modelled).

Units in the TOML follow 003 table 3 and end in the unit (``_mg``, ``_ppm``, ``_mrad``, ``_deg_h``,
``_deg``); the dataclasses hold SI values (m/s^2, rad, rad/s, dimensionless).
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, replace

G0 = 9.80665  #: standard gravity [m/s^2], converts mg
MODES = ("E", "C", "off")


@dataclass(frozen=True)
class StateGroupTuning:
    """One error group: ``mode`` in {"E", "C", "off"} and its initial 1-sigma in SI units."""
    mode: str
    sigma: float

    @property
    def on(self) -> bool:
        return self.mode != "off"

    @property
    def estimated(self) -> bool:
        return self.mode == "E"


@dataclass(frozen=True)
class Tuning:
    """Filter tuning (003 table 3 and §6).

    Attributes
    ----------
    accel_white, gyro_white : float
        Velocity / angular random walk PSD square roots used as process noise [m/s^2/sqrt(Hz)],
        [rad/s/sqrt(Hz)]: table 3 value plus the bracketed extra tuning noise, added in quadrature.
    accel_bias ... camera_misalignment : StateGroupTuning
        Error groups of 003 eq. (46), generalised (scale factor and misalignment of the IMU).
    camera_clock_offset : StateGroupTuning
        Time offset of each camera's clock against the IMU time base [s] (003 §7.3), one
        constant state per camera (:mod:`nav.clock_offset` gives the initial value and sigma).
        Off by default (not in table 3); TOML ``[states.camera_clock_offset]`` with ``sigma_ms``.
    vector_white : float
        White noise (1 sigma, per axis, unit-vector units) added to eq. (49) as Q_tuning.
    vector_gm_mode : str
        Mode of the Gauss-Markov vector-error states zeta_hor / zeta_sun (003 eqs. (41)-(45)).
    correlation_time_s : float
        T_c of the Gauss-Markov process (003 §6.3: 20 s).
    gm_default_sigma : float
        Stationary sigma of zeta before a target's first measurement brings its P_c.
    targets : tuple of str
        Vector targets modelled: subset of ("hor", "sun", "moon").
    init_att_sigma, init_pos_sigma, init_vel_sigma : float
        Initial 1-sigma of psi [rad] (003 §7.4: 2 deg), position [m], velocity [m/s].
    max_cov_interval_s : float
        Longest interval over which the covariance transition is accumulated (see
        :mod:`nav.navigator`).
    gate_probability : float
        Chi-square gate: a measurement whose NIS exceeds the quantile of this probability is
        rejected.
    gyro_range, accel_range : float
        Sensor ranges [rad/s], [m/s^2]; samples at or beyond are counted as saturated.
    max_imu_gap_s : float
        IMU time step above which a gap is counted (the INS still integrates across it).
    """
    accel_white: float = math.hypot(0.05, 2.5) * 1e-3 * G0
    gyro_white: float = math.radians(math.hypot(0.05, 2.5)) / 60.0
    accel_bias: StateGroupTuning = StateGroupTuning("E", 2e-3 * G0)
    accel_scale: StateGroupTuning = StateGroupTuning("C", 300e-6)
    accel_misalignment: StateGroupTuning = StateGroupTuning("C", 2e-3)
    gyro_bias: StateGroupTuning = StateGroupTuning("C", math.radians(6.0) / 3600.0)
    gyro_scale: StateGroupTuning = StateGroupTuning("C", 2000e-6)
    gyro_misalignment: StateGroupTuning = StateGroupTuning("C", 2e-3)
    camera_misalignment: StateGroupTuning = StateGroupTuning("E", math.radians(1.0))
    camera_clock_offset: StateGroupTuning = StateGroupTuning("off", 0.05)
    vector_white: float = 0.005
    vector_gm_mode: str = "C"
    correlation_time_s: float = 20.0
    gm_default_sigma: float = math.radians(0.1)
    targets: tuple = ("hor", "sun")
    init_att_sigma: float = math.radians(2.0)
    init_pos_sigma: float = 10.0
    init_vel_sigma: float = 0.1
    max_cov_interval_s: float = 0.1
    gate_probability: float = 0.99999
    gyro_range: float = math.radians(1000.0)
    accel_range: float = 50.0 * G0
    max_imu_gap_s: float = 0.5

    def with_(self, **kw) -> "Tuning":
        """Copy with fields replaced (dataclasses.replace)."""
        return replace(self, **kw)


def _group(d: dict, key: str, unit_key: str, scale: float, default: StateGroupTuning) -> StateGroupTuning:
    if key not in d:
        return default
    g = d[key]
    if not isinstance(g, dict):
        raise ValueError(f"tuning [states.{key}]: expected a table with 'mode' and '{unit_key}'")
    mode = g.get("mode", default.mode)
    if mode not in MODES:
        raise ValueError(f"tuning [states.{key}] mode: expected one of {MODES}, got {mode!r}")
    sigma = g.get(unit_key, None)
    sigma = default.sigma if sigma is None else _positive(sigma, f"[states.{key}] {unit_key}") * scale
    unknown = set(g) - {"mode", unit_key}
    if unknown:
        raise ValueError(f"tuning [states.{key}]: unknown keys {sorted(unknown)}; expected 'mode', '{unit_key}'")
    return StateGroupTuning(mode, float(sigma))


def _positive(v, name: str) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"tuning {name}: expected a number, got {v!r}") from None
    if not math.isfinite(x) or x < 0:
        raise ValueError(f"tuning {name}: expected a finite non-negative number, got {v!r}")
    return x


_GROUPS = {  # key: (unit key, factor to SI)
    "accel_bias": ("sigma_mg", 1e-3 * G0),
    "accel_scale": ("sigma_ppm", 1e-6),
    "accel_misalignment": ("sigma_mrad", 1e-3),
    "gyro_bias": ("sigma_deg_h", math.radians(1.0) / 3600.0),
    "gyro_scale": ("sigma_ppm", 1e-6),
    "gyro_misalignment": ("sigma_mrad", 1e-3),
    "camera_misalignment": ("sigma_deg", math.radians(1.0)),
    "camera_clock_offset": ("sigma_ms", 1e-3),
}


def tuning_from_dict(d: dict) -> Tuning:
    """Build a :class:`Tuning` from a dict shaped like ``table3.toml`` (missing keys = table 3).

    Raises ``ValueError`` naming the offending key for unknown sections or bad values.
    """
    if not isinstance(d, dict):
        raise ValueError("tuning: expected a table (dict)")
    known = {"imu", "states", "vectors", "initial", "filter"}
    unknown = set(d) - known
    if unknown:
        raise ValueError(f"tuning: unknown sections {sorted(unknown)}; expected {sorted(known)}")
    base = Tuning()
    kw = {}
    imu = d.get("imu", {})
    aw = _positive(imu.get("accel_white_noise_mg_rthz", 0.05), "[imu] accel_white_noise_mg_rthz")
    ax = _positive(imu.get("accel_white_noise_extra_mg_rthz", 2.5), "[imu] accel_white_noise_extra_mg_rthz")
    gw = _positive(imu.get("gyro_white_noise_deg_rth", 0.05), "[imu] gyro_white_noise_deg_rth")
    gx = _positive(imu.get("gyro_white_noise_extra_deg_rth", 2.5), "[imu] gyro_white_noise_extra_deg_rth")
    # mg/sqrt(Hz) -> m/s^2/sqrt(Hz); deg/sqrt(h) -> rad/s/sqrt(Hz) = rad/sqrt(s)
    kw["accel_white"] = math.hypot(aw, ax) * 1e-3 * G0
    kw["gyro_white"] = math.radians(math.hypot(gw, gx)) / 60.0
    if "gyro_range_deg_s" in imu:
        kw["gyro_range"] = math.radians(_positive(imu["gyro_range_deg_s"], "[imu] gyro_range_deg_s"))
    if "accel_range_g" in imu:
        kw["accel_range"] = _positive(imu["accel_range_g"], "[imu] accel_range_g") * G0
    if "max_gap_s" in imu:
        kw["max_imu_gap_s"] = _positive(imu["max_gap_s"], "[imu] max_gap_s")
    states = d.get("states", {})
    unknown = set(states) - set(_GROUPS)
    if unknown:
        raise ValueError(f"tuning [states]: unknown groups {sorted(unknown)}; expected {sorted(_GROUPS)}")
    for key, (unit_key, scale) in _GROUPS.items():
        kw[key] = _group(states, key, unit_key, scale, getattr(base, key))
    vec = d.get("vectors", {})
    if "white_noise" in vec:
        kw["vector_white"] = _positive(vec["white_noise"], "[vectors] white_noise")
    if "gm_mode" in vec:
        if vec["gm_mode"] not in MODES:
            raise ValueError(f"tuning [vectors] gm_mode: expected one of {MODES}, got {vec['gm_mode']!r}")
        kw["vector_gm_mode"] = vec["gm_mode"]
    if "correlation_time_s" in vec:
        tc = _positive(vec["correlation_time_s"], "[vectors] correlation_time_s")
        if tc == 0:
            raise ValueError("tuning [vectors] correlation_time_s: must be > 0")
        kw["correlation_time_s"] = tc
    if "gm_default_sigma_deg" in vec:
        kw["gm_default_sigma"] = math.radians(_positive(vec["gm_default_sigma_deg"], "[vectors] gm_default_sigma_deg"))
    if "targets" in vec:
        t = tuple(vec["targets"])
        if not t or any(x not in ("hor", "sun", "moon") for x in t):
            raise ValueError(f"tuning [vectors] targets: expected a non-empty subset of hor, sun, moon; got {t}")
        kw["targets"] = t
    ini = d.get("initial", {})
    if "attitude_sigma_deg" in ini:
        kw["init_att_sigma"] = math.radians(_positive(ini["attitude_sigma_deg"], "[initial] attitude_sigma_deg"))
    if "position_sigma_m" in ini:
        kw["init_pos_sigma"] = _positive(ini["position_sigma_m"], "[initial] position_sigma_m")
    if "velocity_sigma_m_s" in ini:
        kw["init_vel_sigma"] = _positive(ini["velocity_sigma_m_s"], "[initial] velocity_sigma_m_s")
    flt = d.get("filter", {})
    if "max_cov_interval_s" in flt:
        v = _positive(flt["max_cov_interval_s"], "[filter] max_cov_interval_s")
        if v == 0:
            raise ValueError("tuning [filter] max_cov_interval_s: must be > 0")
        kw["max_cov_interval_s"] = v
    if "gate_probability" in flt:
        p = _positive(flt["gate_probability"], "[filter] gate_probability")
        if not 0 < p < 1:
            raise ValueError(f"tuning [filter] gate_probability: expected 0 < p < 1, got {p}")
        kw["gate_probability"] = p
    return replace(base, **kw)


def tuning_from_toml(text: str) -> Tuning:
    """Parse a TOML string (the content of a tuning file) into a :class:`Tuning`."""
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"tuning: not valid TOML: {e}") from None
    return tuning_from_dict(d)


def table3() -> Tuning:
    """003 table 3 (white noise with the bracketed tuning extra)."""
    return tuning_from_dict({})
