"""Navigation filter tuning: the :class:`Tuning` dataclass and parsing of overrides from a dict or
a TOML string (no file I/O).

:class:`Tuning` holds every default: 003 table 3 (docs/conventions.md "The reference flight"). A
tuning file holds overrides only, in tables per part of the filter; a key left out keeps the
default, an unknown table or key is an error naming it::

    [imu]       accel_white_noise_mg_rthz, accel_white_noise_extra_mg_rthz,
                gyro_white_noise_deg_rth, gyro_white_noise_extra_deg_rth,
                gyro_range_deg_s, accel_range_g, max_gap_s
    [states.<group>]  mode = "E" | "C" | "off", sigma_<unit>  (groups and units: ``_GROUPS``;
                [states.edge_height] also takes correlation_time_s, 0 for a constant,
                and edge = "limb" | "threshold";
                [states.gyro_gm] takes correlation_time_s, > 0)
    [vectors]   targets, white_noise, gm_mode, correlation_time_s, gm_default_sigma_deg,
                white_noise_<target>, cov_scale_<target>  (target: hor, sun, moon),
                cov_scale_<target>_camera_<k>  (k: the log's camera number, /camera_<k>, 1-based),
                cov_scale_edge_state = "E" | "C" | "off"  (the edge-height state's mode the
                scales were estimated with; `horizon-nav tune` writes it)
    [gps]       noise_scale
    [initial]   attitude_sigma_deg, position_sigma_m, velocity_sigma_m_s
    [filter]    max_cov_interval_s, gate_probability, first_update_iterations,
                second_order_noise, misalignment_reset
    [recovery]  enabled, gap_s, gap_samples, gated_fixes, gated_vectors, velocity_sigma_m_s,
                attitude_sigma_gap_deg, attitude_sigma_divergence_deg

Every error group is ``"E"`` (estimated), ``"C"`` (considered only, Schmidt-Kalman, 003 §6.1 and
ref. [14]) or ``"off"`` (not modelled). Units in the TOML follow 003 table 3 and end in the unit
(``_mg``, ``_ppm``, ``_mrad``, ``_deg_h``, ``_deg``); the dataclasses hold SI values (m/s^2, rad,
rad/s, dimensionless).
"""
from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, replace

import numpy as np

G0 = 9.80665  #: standard gravity [m/s^2], converts mg
MODES = ("E", "C", "off")
#: the table 3 white noise of the IMU and its bracketed tuning extra, [mg/sqrt(Hz)], [deg/sqrt(h)]
#: (the defaults of :attr:`Tuning.accel_white`, :attr:`Tuning.gyro_white`: ``_white_noise``)
IMU_WHITE_NOISE = {"accel_white_noise_mg_rthz": 0.05, "accel_white_noise_extra_mg_rthz": 2.5,
                   "gyro_white_noise_deg_rth": 0.05, "gyro_white_noise_extra_deg_rth": 2.5}



def _white_noise(v: dict) -> tuple:
    """(accel_white, gyro_white) from the table 3 value and the tuning extra added in quadrature:
    mg/sqrt(Hz) -> m/s^2/sqrt(Hz); deg/sqrt(h) -> rad/s/sqrt(Hz) = rad/sqrt(s)."""
    return (math.hypot(v["accel_white_noise_mg_rthz"], v["accel_white_noise_extra_mg_rthz"]) * 1e-3 * G0,
            math.radians(math.hypot(v["gyro_white_noise_deg_rth"], v["gyro_white_noise_extra_deg_rth"])) / 60.0)


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
    gyro_nonorthogonality : StateGroupTuning
        The gyro triad's non-orthogonality ``n_w`` (:mod:`nav.imu_errors`): the three symmetric
        off-diagonal terms of its axis misalignment that the rotation ``gyro_misalignment`` does
        not hold. Off by default (table 3 has the three-state misalignment only); TOML
        ``[states.gyro_nonorthogonality]`` with ``sigma_mrad``.
    camera_clock_offset : StateGroupTuning
        Time offset of each camera's clock against the IMU time base [s] (003 §7.3), one
        constant state per camera (:mod:`nav.clock_offset` gives the initial value and sigma).
        Off by default (not in table 3); TOML ``[states.camera_clock_offset]`` with ``sigma_ms``.
    edge_height : StateGroupTuning
        Effective height of each camera's Earth edge above the ellipsoid [m] (003 eq. (5), ``d``;
        :mod:`vision.edge_height`): one state ``h_e`` per camera, entering the horizon vectors that
        carry their sensitivity (``VectorData.dedge_c``). Its initial value is the height the
        vectors were fitted at (``VectorData.edge_ref_m``), ``sigma`` its initial 1-sigma. Off by
        default; TOML ``[states.edge_height]`` with ``sigma_km`` and ``correlation_time_s``.
    edge_height_tau_s : float
        Correlation time of ``h_e`` as a first-order Gauss-Markov process about its initial value
        with the stationary sigma ``edge_height.sigma`` [s]; 0: a constant.
    edge_height_edge : str
        The edge ``h_e`` describes (the vision's ``[earth.edge] state_edge``): "limb" (the limb
        edge where the limb model is on, the default) or "threshold" (the threshold edge on every
        frame: for a camera whose arcs cannot check the limb model, docs/vision.md); TOML
        ``[states.edge_height] edge``.
    gyro_gm : StateGroupTuning
        First-order Gauss-Markov gyro error ``g_w`` [rad/s] per axis, beside the constant bias
        ``gyro_bias``: the correlated drift at time scales of ``gyro_gm_tau_s`` (the white gyro
        noise ``gyro_white`` covers the short ones). ``sigma`` is its stationary 1-sigma (also its
        initial one). Off by default; TOML ``[states.gyro_gm]`` with ``sigma_deg_h`` and
        ``correlation_time_s``.
    gyro_gm_tau_s : float
        Correlation time of ``g_w`` [s]: ``phi = exp(-dt/tau)``, driving noise PSD ``2 sigma^2 / tau``.
    gyro_gm_quantum : float
        Step ``q`` of a rate gyro's output [rad/s]; 0: none. When positive, ``g_w`` is that
        output's rounding (:mod:`nav.quantisation`): stationary sigma ``q / sqrt(12)`` per axis
        (in place of ``gyro_gm.sigma``) and a correlation time ``q / (c |d omega / dt|)`` from the
        measured rates (in place of ``gyro_gm_tau_s``). TOML ``[states.gyro_gm] quantum_dps``.
    gyro_gm_quantum_scale : float
        ``c`` of that correlation time; TOML ``[states.gyro_gm] quantum_scale``.
    gyro_gm_quantum_window_s : float
        Width of the one-sided windows of the rate's slope [s] (:func:`nav.quantisation.rate_slopes`);
        TOML ``[states.gyro_gm] quantum_window_s``.
    vector_white : float
        White noise (1 sigma, per axis, unit-vector units) added to eq. (49) as Q_tuning.
    vector_gm_mode : str
        Mode of the Gauss-Markov vector-error states zeta_hor / zeta_sun (003 eqs. (41)-(45)).
    correlation_time_s : float
        T_c of the Gauss-Markov process (003 §6.3: 20 s).
    gm_default_sigma : float
        Stationary sigma of zeta before a target's first measurement brings its P_c.
    vector_white_by_target : tuple of (str, float)
        Per target, a white noise that replaces ``vector_white`` for that target's vectors
        (e.g. ``(("hor", 0.003),)``; :meth:`vector_white_for`).
    vector_cov_scale_by_target : tuple of (str, float)
        Per target, a factor on the 1-sigma of the vision's covariance P_c (003 eq. (33)): P_c is
        multiplied by its square wherever it enters (the Gauss-Markov stationary covariance of
        eqs. (44)-(45), or R with the Gauss-Markov states off); default 1 (:meth:`vector_cov_scale_for`).
    vector_cov_scale_edge_mode : str
        The ``edge_height`` mode the P_c scales were estimated with (``[vectors]
        cov_scale_edge_state``, written by ``horizon-nav tune``; "" when not recorded). With the
        state on the vectors carry P_c given the edge height, without it the marginal P_c, so a
        scale estimated one way is wrong the other way (:func:`consistency_warnings`).
    vector_cov_scale_by_camera : tuple of ((int, str), float)
        Per camera and target, a factor that replaces the target's for that camera's vectors:
        ``((camera_index, target), value)`` with the filter's camera index (0-based; TOML
        ``cov_scale_<target>_camera_<k>`` with the log's camera number k = index + 1 when every
        camera is replayed, :meth:`for_cameras` otherwise).
    gps_noise_scale : float
        Factor on the 1-sigma of every GPS fix's position and velocity covariance (R multiplied
        by its square); default 1 (the receiver's covariances as logged).
    first_update_iterations : int
        Gauss-Newton relinearisations of the camera-vector updates (an iterated EKF) while the
        attitude is still uncertain: vector epochs whose prior attitude 1-sigma exceeds
        ``first_update_att_sigma`` are linearised again about the updated state this many times
        (0: the ordinary one-step update; :mod:`nav.updates` ``EpochStack.apply``).
    first_update_att_sigma : float
        Largest per-axis attitude 1-sigma [rad] (prior of the epoch) at which the iterated update is
        still used (beyond it the linearisation error is of second order in the attitude error).
    misalignment_reset : bool
        After every feedback, carry the estimated camera misalignments' covariance over to the
        corrected attitude (:meth:`nav.filter_state.FilterState.reset_rotations`), so that what
        the vectors told about the camera's attitude stays attached to it; the start with 003's
        2 deg attitude and 1 deg misalignments is then consistent (docs/tuning.md
        "A consistent start"). False: the first-order reset (P unchanged).
    second_order_noise : bool
        Add to every camera vector's noise the covariance of its terms quadratic in (psi, psi_c)
        (a Gaussian second-order filter, :func:`nav.measurements.second_order_noise`).
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
    recovery : bool
        Re-initialise the navigation state from GPS after a long IMU gap or a divergence
        (:mod:`nav.recovery` states the rules); False keeps the filter running on as it is.
    recovery_gap_s, recovery_gap_samples : float
        An IMU gap triggers a recovery when it is longer than both ``recovery_gap_s`` and
        ``recovery_gap_samples`` nominal sample intervals (the median interval of the run).
    recovery_gated_fixes : int
        Consecutive GPS fixes with a block rejected by the chi-square gate that mark a divergence
        (0: no divergence detection).
    recovery_gated_vectors : int
        Consecutive vectors of one camera (Earth, Sun, Moon) rejected by the chi-square gate after
        which its estimated misalignment is re-opened by its prior variance (0: never).
    recovery_vel_sigma : float
        1-sigma [m/s] added to the re-initialised velocity's covariance (the fix's own covariance,
        or that of the two fixes' difference).
    recovery_att_sigma_gap, recovery_att_sigma_divergence : float
        1-sigma [rad] added per axis to the kept attitude's covariance after a gap / a divergence.
    """
    accel_white: float = _white_noise(IMU_WHITE_NOISE)[0]
    gyro_white: float = _white_noise(IMU_WHITE_NOISE)[1]
    accel_bias: StateGroupTuning = StateGroupTuning("E", 2e-3 * G0)
    accel_scale: StateGroupTuning = StateGroupTuning("C", 300e-6)
    accel_misalignment: StateGroupTuning = StateGroupTuning("C", 2e-3)
    gyro_bias: StateGroupTuning = StateGroupTuning("C", math.radians(6.0) / 3600.0)
    gyro_scale: StateGroupTuning = StateGroupTuning("C", 2000e-6)
    gyro_misalignment: StateGroupTuning = StateGroupTuning("C", 2e-3)
    gyro_nonorthogonality: StateGroupTuning = StateGroupTuning("off", 2e-3)
    camera_misalignment: StateGroupTuning = StateGroupTuning("E", math.radians(1.0))
    camera_clock_offset: StateGroupTuning = StateGroupTuning("off", 0.05)
    edge_height: StateGroupTuning = StateGroupTuning("off", 20e3)
    edge_height_tau_s: float = 0.0
    edge_height_edge: str = "limb"
    gyro_gm: StateGroupTuning = StateGroupTuning("off", math.radians(5.0) / 3600.0)
    gyro_gm_tau_s: float = 100.0
    gyro_gm_quantum: float = 0.0
    gyro_gm_quantum_scale: float = 80.0
    gyro_gm_quantum_window_s: float = 5.0
    vector_white: float = 0.005
    vector_gm_mode: str = "C"
    correlation_time_s: float = 20.0
    gm_default_sigma: float = math.radians(0.1)
    vector_white_by_target: tuple = ()
    vector_cov_scale_by_target: tuple = ()
    vector_cov_scale_by_camera: tuple = ()
    vector_cov_scale_edge_mode: str = ""
    gps_noise_scale: float = 1.0
    first_update_iterations: int = 0
    first_update_att_sigma: float = math.radians(0.3)
    misalignment_reset: bool = False
    second_order_noise: bool = False
    targets: tuple = ("hor", "sun")
    init_att_sigma: float = math.radians(2.0)
    init_pos_sigma: float = 10.0
    init_vel_sigma: float = 0.1
    max_cov_interval_s: float = 0.1
    gate_probability: float = 0.99999
    gyro_range: float = math.radians(1000.0)
    accel_range: float = 50.0 * G0
    max_imu_gap_s: float = 0.5
    recovery: bool = True
    recovery_gap_s: float = 2.0
    recovery_gap_samples: float = 50.0
    recovery_gated_fixes: int = 10
    recovery_gated_vectors: int = 20
    recovery_vel_sigma: float = 0.5
    recovery_att_sigma_gap: float = math.radians(5.0)
    recovery_att_sigma_divergence: float = math.radians(10.0)

    def with_(self, **kw) -> "Tuning":
        """Copy with fields replaced (dataclasses.replace)."""
        return replace(self, **kw)

    def gyro_gm_sigmas(self) -> np.ndarray:
        """(3,) stationary 1-sigma of the Gauss-Markov gyro error per body axis [rad/s]
        (``gyro_gm.sigma``: one value or three; with ``gyro_gm_quantum`` the rounding's
        ``q / sqrt(12)``)."""
        if self.gyro_gm_quantum > 0:
            return np.full(3, self.gyro_gm_quantum / math.sqrt(12.0))
        return np.broadcast_to(np.asarray(self.gyro_gm.sigma, float), (3,)).copy()

    def vector_white_for(self, target: str) -> float:
        """White noise (1 sigma, unit-vector units) of ``target``'s vectors."""
        return dict(self.vector_white_by_target).get(target, self.vector_white)

    def vector_cov_scale_for(self, target: str, camera: int | None = None) -> float:
        """Factor on the 1-sigma of ``target``'s vision covariance P_c on camera index ``camera``:
        the camera's factor if the tuning has one, else the target's, else 1."""
        own = dict(self.vector_cov_scale_by_camera).get((camera, target)) if camera is not None else None
        return own if own is not None else dict(self.vector_cov_scale_by_target).get(target, 1.0)

    def for_cameras(self, numbers) -> "Tuning":
        """The tuning of a filter whose camera indices are the log's cameras ``numbers`` (1-based,
        in index order): the per-camera factors, keyed by ``number - 1``, re-keyed by the camera's
        position in ``numbers`` (those of cameras not in it dropped)."""
        numbers = [int(k) for k in numbers]
        if not self.vector_cov_scale_by_camera or numbers == list(range(1, len(numbers) + 1)):
            return self
        pairs = tuple(((numbers.index(c + 1), tg), v) for (c, tg), v in self.vector_cov_scale_by_camera
                      if c + 1 in numbers)
        return replace(self, vector_cov_scale_by_camera=tuple(sorted(pairs)))


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
    if sigma is not None:
        sigma = _scaled(_positive_axes(sigma, f"[states.{key}] {unit_key}") if key in _PER_AXIS
                        else _positive(sigma, f"[states.{key}] {unit_key}"), scale)
    unknown = set(g) - {"mode", unit_key}
    if unknown:
        raise ValueError(f"tuning [states.{key}]: unknown keys {sorted(unknown)}; expected 'mode', '{unit_key}'")
    return StateGroupTuning(mode, default.sigma if sigma is None else sigma)


def _positive_axes(v, name: str):
    """A non-negative number, or a list of three (body x, y, z) as a tuple."""
    if isinstance(v, list):
        if len(v) != 3:
            raise ValueError(f"tuning {name}: expected a number or three (body x, y, z), got {v!r}")
        return tuple(_positive(x, name) for x in v)
    return _positive(v, name)


def _scaled(v, factor: float):
    """``v`` (a number or a tuple) times ``factor``."""
    return tuple(x * factor for x in v) if isinstance(v, tuple) else v * factor


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
    "gyro_nonorthogonality": ("sigma_mrad", 1e-3),
    "camera_misalignment": ("sigma_deg", math.radians(1.0)),
    "camera_clock_offset": ("sigma_ms", 1e-3),
    "edge_height": ("sigma_km", 1e3),
    "gyro_gm": ("sigma_deg_h", math.radians(1.0) / 3600.0),
}
#: groups whose sigma and correlation time may be given per body axis (a list of three)
_PER_AXIS = {"gyro_gm"}


#: TOML key -> (Tuning field, factor to SI) of the scalar entries, per table; values must be
#: finite and non-negative, and those in _NONZERO positive
_SCALARS = {
    "imu": {"gyro_range_deg_s": ("gyro_range", math.radians(1.0)), "accel_range_g": ("accel_range", G0),
            "max_gap_s": ("max_imu_gap_s", 1.0)},
    "vectors": {"white_noise": ("vector_white", 1.0), "correlation_time_s": ("correlation_time_s", 1.0),
                "gm_default_sigma_deg": ("gm_default_sigma", math.radians(1.0))},
    "initial": {"attitude_sigma_deg": ("init_att_sigma", math.radians(1.0)),
                "position_sigma_m": ("init_pos_sigma", 1.0), "velocity_sigma_m_s": ("init_vel_sigma", 1.0)},
    "filter": {"max_cov_interval_s": ("max_cov_interval_s", 1.0), "gate_probability": ("gate_probability", 1.0),
               "first_update_att_sigma_deg": ("first_update_att_sigma", math.radians(1.0))},
    "gps": {"noise_scale": ("gps_noise_scale", 1.0)},
    "recovery": {"gap_s": ("recovery_gap_s", 1.0), "gap_samples": ("recovery_gap_samples", 1.0),
                 "velocity_sigma_m_s": ("recovery_vel_sigma", 1.0),
                 "attitude_sigma_gap_deg": ("recovery_att_sigma_gap", math.radians(1.0)),
                 "attitude_sigma_divergence_deg": ("recovery_att_sigma_divergence", math.radians(1.0))},
}
_NONZERO = {"correlation_time_s", "max_cov_interval_s", "noise_scale", "quantum_dps", "quantum_scale", "quantum_window_s"}
VECTOR_TARGETS = ("hor", "sun", "moon")
#: per-target keys of [vectors]: key prefix -> Tuning field of (target, value) pairs
_PER_TARGET = {"white_noise_": "vector_white_by_target", "cov_scale_": "vector_cov_scale_by_target"}
#: ``[vectors] cov_scale_<target>_camera_<k>``: the per-camera P_c scale (k checked by _per_camera)
_PER_CAMERA = re.compile(r"cov_scale_(" + "|".join(VECTOR_TARGETS) + r")_camera_(.*)")
_OTHER_KEYS = {"imu": set(IMU_WHITE_NOISE),
               "vectors": {"gm_mode", "targets", "cov_scale_edge_state"} | {p + t for p in _PER_TARGET for t in VECTOR_TARGETS},
               "initial": set(), "filter": {"first_update_iterations", "misalignment_reset", "second_order_noise"}, "gps": set(),
               "recovery": {"enabled", "gated_fixes", "gated_vectors"}}


def _table(d: dict, name: str) -> dict:
    """Table ``[name]`` of ``d`` (empty if absent); an unknown key raises naming it."""
    t = d.get(name, {})
    if not isinstance(t, dict):
        raise ValueError(f"tuning [{name}]: expected a table")
    unknown = set(t) - set(_SCALARS[name]) - _OTHER_KEYS[name]
    if name == "vectors":
        unknown = {k for k in unknown if not _PER_CAMERA.fullmatch(k)}
    if unknown:
        extra = ["cov_scale_<target>_camera_<k>"] if name == "vectors" else []
        raise ValueError(f"tuning [{name}]: unknown key {sorted(unknown)[0]!r}; expected one of "
                         f"{sorted(set(_SCALARS[name]) | _OTHER_KEYS[name]) + extra}")
    return t


def _scalar(table: str, key: str, v, scale: float) -> float:
    x = _positive(v, f"[{table}] {key}")
    if key in _NONZERO and x == 0:
        raise ValueError(f"tuning [{table}] {key}: must be > 0")
    if key == "gate_probability" and not 0 < x < 1:
        raise ValueError(f"tuning [filter] gate_probability: expected 0 < p < 1, got {x}")
    return x * scale


def _imu_white(imu: dict, kw: dict) -> None:
    """The white-noise overrides of ``[imu]`` (a component left out keeps its table 3 value)."""
    if set(imu) & set(IMU_WHITE_NOISE):
        v = {k: _positive(imu.get(k, d), f"[imu] {k}") for k, d in IMU_WHITE_NOISE.items()}
        kw["accel_white"], kw["gyro_white"] = _white_noise(v)


def _vector_choices(vec: dict, kw: dict) -> None:
    if "gm_mode" in vec:
        if vec["gm_mode"] not in MODES:
            raise ValueError(f"tuning [vectors] gm_mode: expected one of {MODES}, got {vec['gm_mode']!r}")
        kw["vector_gm_mode"] = vec["gm_mode"]
    if "cov_scale_edge_state" in vec:
        if vec["cov_scale_edge_state"] not in MODES:
            raise ValueError(f"tuning [vectors] cov_scale_edge_state: expected one of {MODES}, "
                             f"got {vec['cov_scale_edge_state']!r}")
        kw["vector_cov_scale_edge_mode"] = vec["cov_scale_edge_state"]
    if "targets" in vec:
        t = tuple(vec["targets"])
        if not t or any(x not in ("hor", "sun", "moon") for x in t):
            raise ValueError(f"tuning [vectors] targets: expected a non-empty subset of hor, sun, moon; got {t}")
        kw["targets"] = t


def _per_target(vec: dict, kw: dict) -> None:
    """``[vectors] white_noise_<target>``, ``cov_scale_<target>`` (a scale must be > 0)."""
    for prefix, field_ in _PER_TARGET.items():
        pairs = []
        for t in VECTOR_TARGETS:
            if prefix + t in vec:
                x = _positive(vec[prefix + t], f"[vectors] {prefix + t}")
                if prefix == "cov_scale_" and x == 0:
                    raise ValueError(f"tuning [vectors] {prefix + t}: must be > 0")
                pairs.append((t, x))
        if pairs:
            kw[field_] = tuple(pairs)


def _per_camera(vec: dict, kw: dict) -> None:
    """``[vectors] cov_scale_<target>_camera_<k>`` (k an integer >= 1, the scale > 0) into
    ``vector_cov_scale_by_camera`` keyed by camera index k - 1."""
    pairs = []
    for key, v in vec.items():
        m = _PER_CAMERA.fullmatch(key)
        if not m:
            continue
        k = m.group(2)
        if not (k.isascii() and k.isdigit()) or int(k) < 1:
            raise ValueError(f"tuning [vectors] {key}: expected a camera number >= 1 after '_camera_', got {k!r}")
        x = _positive(v, f"[vectors] {key}")
        if x == 0:
            raise ValueError(f"tuning [vectors] {key}: must be > 0")
        pairs.append(((int(k) - 1, m.group(1)), x))
    if pairs:
        kw["vector_cov_scale_by_camera"] = tuple(sorted(pairs))


def _count(table: str, key: str, n) -> int:
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ValueError(f"tuning [{table}] {key}: expected a non-negative integer, got {n!r}")
    return n


def _recovery_choices(rec: dict, kw: dict) -> None:
    """``[recovery]`` enabled (a boolean), gated_fixes and gated_vectors (non-negative integers)."""
    if "enabled" in rec:
        if not isinstance(rec["enabled"], bool):
            raise ValueError(f"tuning [recovery] enabled: expected true or false, got {rec['enabled']!r}")
        kw["recovery"] = rec["enabled"]
    if "gated_fixes" in rec:
        kw["recovery_gated_fixes"] = _count("recovery", "gated_fixes", rec["gated_fixes"])
    if "gated_vectors" in rec:
        kw["recovery_gated_vectors"] = _count("recovery", "gated_vectors", rec["gated_vectors"])


def _group_tau(states: dict, kw: dict, group: str, field_: str, nonzero: bool = False) -> dict:
    """``[states.<group>] correlation_time_s`` into ``kw[field_]`` (``nonzero``: it must be
    positive); the states without that key."""
    g = states.get(group)
    if not isinstance(g, dict) or "correlation_time_s" not in g:
        return states
    name = f"[states.{group}] correlation_time_s"
    kw[field_] = (_positive_axes if group in _PER_AXIS else _positive)(g["correlation_time_s"], name)
    if nonzero and not min(np.atleast_1d(kw[field_])) > 0:
        raise ValueError(f"tuning {name}: expected a positive number, got {g['correlation_time_s']!r}")
    return {**states, group: {k: v for k, v in g.items() if k != "correlation_time_s"}}


def _edge_choice(states: dict, kw: dict) -> dict:
    """``[states.edge_height] edge`` ("limb" or "threshold") into ``kw["edge_height_edge"]``; the
    states without that key."""
    g = states.get("edge_height")
    if not isinstance(g, dict) or "edge" not in g:
        return states
    if g["edge"] not in ("limb", "threshold"):
        raise ValueError(f'tuning [states.edge_height] edge: expected "limb" or "threshold", got {g["edge"]!r}')
    kw["edge_height_edge"] = g["edge"]
    return {**states, "edge_height": {k: v for k, v in g.items() if k != "edge"}}


#: ``[states.gyro_gm]`` keys of the rate-quantisation form -> (Tuning field, factor to SI)
_QUANTUM_KEYS = {"quantum_dps": ("gyro_gm_quantum", math.radians(1.0)),
                 "quantum_scale": ("gyro_gm_quantum_scale", 1.0),
                 "quantum_window_s": ("gyro_gm_quantum_window_s", 1.0)}


def _gyro_quantum(states: dict, kw: dict) -> dict:
    """The rate-quantisation form of ``[states.gyro_gm]`` (``quantum_dps``, optionally
    ``quantum_scale``, ``quantum_window_s``; each positive) into ``kw``; the states without those
    keys. With ``quantum_dps`` the sigma and the correlation time follow from it and the rates, so
    ``sigma_deg_h`` and ``correlation_time_s`` are refused beside it."""
    g = states.get("gyro_gm")
    if not isinstance(g, dict) or not set(g) & set(_QUANTUM_KEYS):
        return states
    if "quantum_dps" not in g:
        raise ValueError(f"tuning [states.gyro_gm] {sorted(set(g) & set(_QUANTUM_KEYS))[0]}: "
                         "needs quantum_dps (the gyro's rate step)")
    both = sorted({"sigma_deg_h", "correlation_time_s"} & set(g))
    if both:
        raise ValueError(f"tuning [states.gyro_gm] {both[0]}: not with quantum_dps, which sets the sigma "
                         "(q / sqrt(12)) and the correlation time (from the rates)")
    for key, (field_, factor) in _QUANTUM_KEYS.items():
        if key in g:
            kw[field_] = _scalar("states.gyro_gm", key, g[key], factor)
    sigma_deg_h = math.degrees(kw["gyro_gm_quantum"]) * 3600.0 / math.sqrt(12.0)
    return {**states, "gyro_gm": {**{k: v for k, v in g.items() if k not in _QUANTUM_KEYS}, "sigma_deg_h": sigma_deg_h}}


def tuning_from_dict(d: dict) -> Tuning:
    """Build a :class:`Tuning` from a dict of overrides shaped like a tuning TOML file (tables
    ``[imu]``, ``[states.<group>]``, ``[vectors]``, ``[initial]``, ``[filter]``, ``[recovery]``, ``[gps]``; units in the key
    names): every key absent keeps the :class:`Tuning` default (003 table 3).

    Raises ``ValueError`` naming the offending table and key for unknown tables or keys and bad
    values.
    """
    if not isinstance(d, dict):
        raise ValueError("tuning: expected a table (dict)")
    known = {"imu", "states", "vectors", "initial", "filter", "recovery", "gps"}
    unknown = set(d) - known
    if unknown:
        raise ValueError(f"tuning: unknown sections {sorted(unknown)}; expected {sorted(known)}")
    base = Tuning()
    kw = {}
    for name, keys in _SCALARS.items():
        table = _table(d, name)
        for key, (field_, scale) in keys.items():
            if key in table:
                kw[field_] = _scalar(name, key, table[key], scale)
    _imu_white(d.get("imu", {}), kw)
    _vector_choices(d.get("vectors", {}), kw)
    _per_target(d.get("vectors", {}), kw)
    _per_camera(d.get("vectors", {}), kw)
    if "first_update_iterations" in d.get("filter", {}):
        kw["first_update_iterations"] = _count("filter", "first_update_iterations",
                                               d["filter"]["first_update_iterations"])
    for key in ("misalignment_reset", "second_order_noise"):
        if key in d.get("filter", {}):
            v = d["filter"][key]
            if not isinstance(v, bool):
                raise ValueError(f"tuning [filter] {key}: expected true or false, got {v!r}")
            kw[key] = v
    _recovery_choices(d.get("recovery", {}), kw)
    states = d.get("states", {})
    unknown = set(states) - set(_GROUPS)
    if unknown:
        raise ValueError(f"tuning [states]: unknown groups {sorted(unknown)}; expected {sorted(_GROUPS)}")
    states = _group_tau(states, kw, "edge_height", "edge_height_tau_s")
    states = _edge_choice(states, kw)
    states = _gyro_quantum(states, kw)
    states = _group_tau(states, kw, "gyro_gm", "gyro_gm_tau_s", nonzero=True)
    for key, (unit_key, scale) in _GROUPS.items():
        kw[key] = _group(states, key, unit_key, scale, getattr(base, key))
    return replace(base, **kw)


def consistency_warnings(t: Tuning) -> list[str]:
    """What in ``t`` contradicts itself, one sentence each: P_c scales estimated with the
    edge-height state off and used with it on, or the other way round
    (:attr:`Tuning.vector_cov_scale_edge_mode`). Empty when nothing does.

    Examples
    --------
    >>> t = tuning_from_toml('[vectors]\\ncov_scale_hor = 0.2\\ncov_scale_edge_state = "off"\\n'
    ...                      '[states.edge_height]\\nmode = "E"\\n')
    >>> "optimistic" in consistency_warnings(t)[0]
    True
    >>> consistency_warnings(t.with_(edge_height=StateGroupTuning("off", 20e3)))
    []
    """
    was = t.vector_cov_scale_edge_mode
    scaled = bool(t.vector_cov_scale_by_target or t.vector_cov_scale_by_camera)
    if not was or not scaled or (was != "off") == t.edge_height.on:
        return []
    how = ("with the edge-height state off, for the vectors' covariance with the height's uncertainty in it; "
           "with the state on the vectors carry the covariance given the height, which these scales make optimistic"
           if was == "off" else
           "with the edge-height state on, for the vectors' covariance given the height; with the state off the "
           "vectors carry the height's uncertainty as well, which these scales were not estimated for")
    return [f"tuning: the [vectors] cov_scale_* keys were estimated {how}; "
            f"estimate them again with `horizon-nav tune` and [states.edge_height] mode = {t.edge_height.mode!r}"]


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
