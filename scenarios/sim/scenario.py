"""Flight scenarios: dataclasses, TOML loading with validation, and the built-in library.

A scenario describes one simulated sounding-rocket flight (003 §7): the launch, the vehicle (stages,
masses, drag, spin, despin, RCS, disturbance torques), the IMU, the GPS receiver and the cameras.
Files live in ``scenarios/library/<name>.toml`` (``horizon-nav scenarios`` lists them); any other
path to a ``.toml`` file works too.

Units are SI unless the key says otherwise: keys end in their unit (``_deg``, ``_dps`` = deg/s,
``_hz``, ``_s`` = seconds after lift-off, ``_m``, ``_kg``, ``_kgm2``, ``_nm`` = N m, ``_mg`` =
milli-g, ``_ppm``, ``_mrad``). Every table and key is checked: an unknown key, a missing required
key, a wrong type or an out-of-range value raises :class:`scenarios.errors.UserError` naming the
file and the dotted key (``atek.toml: imu.rate_hz = -20: expected > 0``).

Body frame (docs/conventions.md "Frames"): x_b along the roll axis towards the nose; at lift-off y_b is
horizontal, pointing to the right of the launch azimuth (``y_b = unit(down x x_b)``; east for a launch
to the north), and ``z_b = x_b x y_b`` (for a near-vertical launch: horizontal, towards the launch
azimuth). ``launch.roll_deg`` rotates y_b and z_b about x_b. The cameras are placed by their azimuth
about x_b, measured from +y_b towards +z_b (see :mod:`scenarios.sim.camera_geometry`).
"""
from __future__ import annotations

import dataclasses
import math
from scenarios.config.toml_file import read_toml
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from scenarios.errors import UserError

LIBRARY_DIR = Path(__file__).resolve().parent.parent / "library"
G0 = 9.80665  # standard gravity [m/s^2], for the mg and Isp units


def _meta(doc: str, *, shape: tuple | None = None, minimum: float | None = None,
          maximum: float | None = None, exclusive_min: bool = False, choices: tuple | None = None):
    return {"doc": doc, "shape": shape, "min": minimum, "max": maximum, "xmin": exclusive_min,
            "choices": choices}


def _f(default, doc, **kw):
    """A dataclass field with validation metadata (``default`` may be a list: copied per instance)."""
    if isinstance(default, (list, tuple)):
        return field(default_factory=lambda d=default: _copy(d), metadata=_meta(doc, **kw))
    return field(default=default, metadata=_meta(doc, **kw))


def _copy(d):
    return [_copy(x) for x in d] if isinstance(d, (list, tuple)) else d


REQUIRED = dataclasses.MISSING


# ------------------------------------------------------------------------------------------------
# Configuration dataclasses
# ------------------------------------------------------------------------------------------------
@dataclass
class LaunchConfig:
    """Launcher and lift-off (003 §7.1, table 2)."""
    time_utc: str = _f("2019-06-13T02:21:00Z", "lift-off time, ISO-8601 UTC")
    lat_deg: float = _f(67.8932, "geodetic latitude of the launcher", minimum=-90, maximum=90)
    lon_deg: float = _f(21.1069, "longitude of the launcher", minimum=-180, maximum=360)
    height_m: float = _f(330.0, "launcher height above the WGS-84 ellipsoid", minimum=-500, maximum=9000)
    elevation_deg: float = _f(86.0, "launcher elevation above the local horizontal", minimum=45, maximum=90)
    azimuth_deg: float = _f(0.0, "launch azimuth from north, east positive", minimum=-360, maximum=360)
    roll_deg: float = _f(0.0, "rotation of y_b about x_b from 'horizontal, right of the azimuth'",
                         minimum=-360, maximum=360)


@dataclass
class StageConfig:
    """One solid motor: trapezoidal thrust with total impulse = propellant * Isp * g0."""
    name: str = _f("stage", "label")
    ignition_s: float = _f(0.0, "ignition time after lift-off", minimum=0)
    burn_time_s: float = _f(10.0, "burn time (from ignition to end of tail-off)", minimum=0, exclusive_min=True)
    propellant_kg: float = _f(500.0, "propellant mass", minimum=0)
    dry_mass_kg: float = _f(200.0, "inert mass of the stage, dropped at separation", minimum=0)
    isp_s: float = _f(260.0, "vacuum specific impulse", minimum=0, exclusive_min=True)
    rise_s: float = _f(0.3, "thrust rise time", minimum=0)
    tail_off_s: float = _f(1.5, "thrust tail-off time", minimum=0)
    separation_s: float = _f(20.0, "separation time (the stage's dry mass is dropped)", minimum=0)


@dataclass
class VehicleConfig:
    """Masses, inertia and aerodynamics (a point-mass drag model, 003 §7.1 events)."""
    payload_mass_kg: float = _f(380.0, "payload mass after nose-cone separation", minimum=0, exclusive_min=True)
    nose_cone_mass_kg: float = _f(20.0, "nose-cone mass, dropped at nose_cone_separation_s", minimum=0)
    nose_cone_separation_s: float = _f(56.0, "nose-cone separation", minimum=0)
    stages: list = field(default_factory=list, metadata=_meta("motors, first to last"))
    inertia_ascent_kgm2: list = _f([30.0, 2500.0, 2500.0], "principal inertia of the stack [Ixx, Iyy, Izz]",
                                   shape=(3,), minimum=0, exclusive_min=True)
    inertia_payload_kgm2: list = _f([12.0, 150.0, 155.0], "payload principal inertia after motor separation",
                                    shape=(3,), minimum=0, exclusive_min=True)
    inertia_payload_products_kgm2: list = _f([0.0, 0.0, 0.0], "payload products of inertia [Ixy, Ixz, Iyz]",
                                             shape=(3,))
    cd_area_ascent_m2: float = _f(0.12, "drag coefficient times reference area of the stack", minimum=0)
    cd_area_payload_m2: float = _f(0.10, "drag area of the payload (after motor separation)", minimum=0)
    reentry_s: float = _f(430.0, "begin of the re-entry: the payload tumbles, drag area cd_area_reentry_m2",
                          minimum=0)
    cd_area_reentry_m2: float = _f(0.5, "drag area of the tumbling payload during the re-entry", minimum=0)
    weathercock_frequency_rad_s: float = _f(3.0, "natural frequency with which the finned stack aligns "
                                            "x_b with the air-relative velocity (critically damped)", minimum=0)
    weathercock_min_speed_mps: float = _f(30.0, "below this speed the stack keeps its attitude", minimum=0)
    weathercock_end_s: float = _f(56.0, "fin stabilisation ends (nose-cone separation)", minimum=0)
    chute_s: float = _f(579.0, "parachute deployment", minimum=0)
    chute_cd_area_m2: float = _f(25.0, "drag area of the open parachute", minimum=0)
    chute_inflation_s: float = _f(8.0, "time for the drag area to grow to chute_cd_area_m2", minimum=0,
                                  exclusive_min=True)


@dataclass
class SpinConfig:
    """Spin-up about x_b during the ascent and yo-yo despin (003 §7.1)."""
    profile_hz: list = _f([[0.0, 0.0], [2.0, 0.5], [12.0, 2.5], [30.0, 3.5], [56.0, 3.6]],
                          "spin-rate target [[t_s, rate_hz], ...] (fins, spin-up motors), linear between",
                          shape=(None, 2))
    gain_per_s: float = _f(1.5, "how fast the roll rate follows the target (fin roll damping)", minimum=0)
    despin_s: float = _f(57.0, "yo-yo release", minimum=0)
    despin_time_constant_s: float = _f(0.08, "time constant of the yo-yo rate decay", minimum=0,
                                       exclusive_min=True)
    despin_duration_s: float = _f(0.6, "duration of the yo-yo despin", minimum=0, exclusive_min=True)
    motor_separation_s: float = _f(60.0, "motor separation (2nd-stage dry mass dropped, payload inertia)",
                                   minimum=0)
    tipoff_dps: list = _f([0.3, 1.4, -1.2], "body-rate change given by the separation (tip-off)", shape=(3,))
    tipoff_duration_s: float = _f(0.1, "duration of the tip-off torque", minimum=0, exclusive_min=True)


@dataclass
class RcsConfig:
    """Bang-bang cold-gas rate control (003 §7.1, figs. 34, 35)."""
    enabled: bool = _f(True, "RCS present")
    start_s: float = _f(61.0, "RCS activation", minimum=0)
    end_s: float = _f(430.0, "RCS switched off (re-entry)", minimum=0)
    threshold_dps: float = _f(0.9, "a thruster pair fires when |body rate| exceeds this", minimum=0,
                              exclusive_min=True)
    release_dps: float = _f(0.3, "it stops when |body rate| falls below this (hysteresis)", minimum=0)
    torque_nm: list = _f([1.0, 4.0, 4.0], "torque of each axis' thruster pair", shape=(3,), minimum=0)
    specific_force_mg: list = _f([[1.0, 0.3, 0.2], [0.4, 2.5, 0.3], [0.4, 0.3, 2.5]],
                                 "specific force [x, y, z] in b while the roll, pitch or yaw pair fires "
                                 "with positive torque (misaligned thrusters)", shape=(3, 3))


@dataclass
class DisturbanceConfig:
    """Slow disturbance torques from the payload experiments during the coast."""
    start_s: float = _f(60.0, "disturbances start", minimum=0)
    torque_nm: list = _f([0.002, 0.02, -0.015], "constant part [x, y, z]", shape=(3,))
    amplitude_nm: list = _f([0.002, 0.015, 0.012], "amplitude of the periodic part", shape=(3,))
    period_s: list = _f([97.0, 61.0, 43.0], "period of the periodic part", shape=(3,), minimum=0,
                        exclusive_min=True)


@dataclass
class ImuConfig:
    """Strapdown IMU: 3 accelerometers + 3 gyros (003 §7.1, table 3)."""
    rate_hz: float = _f(20.0, "output rate", minimum=0, exclusive_min=True)
    output: str = _f("rate", "'rate' (rad/s, m/s^2) or 'increment' (rad, m/s per sample)",
                     choices=("rate", "increment"))
    sample: str = _f("average", "rate output: 'average' over the sample interval or 'point' value",
                     choices=("average", "point"))
    gyro_range_dps: float = _f(1000.0, "gyro saturation", minimum=0, exclusive_min=True)
    accel_range_g: float = _f(30.0, "accelerometer saturation", minimum=0, exclusive_min=True)
    gyro_resolution_dps: float = _f(0.03, "gyro quantum (rate output; increments: quantum * dt)", minimum=0)
    accel_resolution_mg: float = _f(0.0, "accelerometer quantum (0: none)", minimum=0)
    gyro_noise_deg_rt_h: float = _f(0.05, "angular random walk [deg/sqrt(h)]", minimum=0)
    gyro_bias_deg_h: float = _f(6.0, "turn-on bias, 1 sigma per axis [deg/h]", minimum=0)
    gyro_scale_ppm: float = _f(2000.0, "scale-factor error, 1 sigma per axis", minimum=0)
    gyro_misalignment_mrad: float = _f(2.0, "axis misalignment, 1 sigma per off-diagonal element", minimum=0)
    gyro_gm_deg_h: float = _f(0.0, "first-order Gauss-Markov gyro drift, stationary 1 sigma per axis [deg/h] "
                              "(0: none)", minimum=0)
    gyro_gm_tau_s: float = _f(100.0, "correlation time of the Gauss-Markov gyro drift", minimum=0,
                              exclusive_min=True)
    accel_noise_mg_rt_hz: float = _f(0.05, "velocity random walk [mg/sqrt(Hz)]", minimum=0)
    accel_bias_mg: float = _f(2.0, "turn-on bias, 1 sigma per axis", minimum=0)
    accel_scale_ppm: float = _f(300.0, "scale-factor error, 1 sigma per axis", minimum=0)
    accel_misalignment_mrad: float = _f(2.0, "axis misalignment, 1 sigma per off-diagonal element", minimum=0)


@dataclass
class GpsConfig:
    """GNSS receiver: ECEF position and velocity fixes."""
    enabled: bool = _f(True, "receiver present")
    rate_hz: float = _f(10.0, "fix rate", minimum=0, exclusive_min=True)
    position_sigma_m: float = _f(3.0, "white position noise, 1 sigma per ECEF axis", minimum=0)
    velocity_sigma_mps: float = _f(0.1, "white velocity noise, 1 sigma per ECEF axis", minimum=0)
    latency_s: float = _f(0.0, "fix stamped at t holds the state at t - latency (uncompensated)", minimum=0)
    outages_s: list = _f([], "windows [[start_s, end_s], ...] without fixes", shape=(None, 2))
    num_satellites: int = _f(8, "reported satellite count", minimum=0)


@dataclass
class CameraConfig:
    """One camera: intrinsics, mounting on the payload and frame timing (003 §7.1)."""
    intrinsics: str = _f("atek_gopro", "camera file in scenarios/library/cameras (without .toml) or a path")
    fov_deg: float = _f(0.0, "if > 0: an equidistant fisheye (r_d = theta) with this horizontal FOV, "
                        "width x height, instead of the intrinsics file", minimum=0, maximum=350)
    width: int = _f(1920, "image width for fov_deg", minimum=16)
    height: int = _f(1080, "image height for fov_deg", minimum=16)
    azimuth_deg: float = _f(0.0, "mounting azimuth about x_b, from +y_b towards +z_b", minimum=-360, maximum=360)
    depression_deg: float = _f(20.0, "optical axis tilt from the radial direction towards -x_b (aft)",
                               minimum=-90, maximum=90)
    roll_deg: float = _f(0.0, "rotation of the camera about its optical axis", minimum=-360, maximum=360)
    misalignment_sigma_deg: float = _f(1.0, "true mount misalignment drawn per axis, 1 sigma (003 eq. (50))",
                                       minimum=0)
    rate_hz: float = _f(1.0, "frame rate", minimum=0, exclusive_min=True)
    start_s: float = _f(0.0, "first frame", minimum=0)
    end_s: float = _f(0.0, "last frame at or before this time (0: to the end of the flight)", minimum=0)
    clock_offset_s: float = _f(0.0, "camera clock minus true time: frames taken at t are stamped t + offset")
    mask_deg: float = _f(0.0, "payload mask: rays less than this above the payload's tangent plane "
                         "at the camera are hidden by the structure", minimum=-90, maximum=90)


@dataclass
class OrbitConfig:
    """A spacecraft already in orbit (``[orbit]``; its presence replaces the launch): the state at
    ``epoch_utc`` (t = 0) from a geodetic point, the heading of the inertial velocity and its speed,
    no motors and no drag, and an attitude that follows a pointing law (scenarios/sim/orbit.py):
    x_b along the geocentric zenith, y_b the along-track direction turned by ``yaw_deg`` about x_b,
    the body turning with the orbit about its normal and by ``yaw_rate_dps`` about x_b."""
    epoch_utc: str = _f("2023-11-20T22:13:20Z", "time of the initial state (t = 0), ISO-8601 UTC")
    lat_deg: float = _f(0.0, "geodetic latitude of the initial position", minimum=-90, maximum=90)
    lon_deg: float = _f(0.0, "longitude of the initial position", minimum=-180, maximum=360)
    height_m: float = _f(500e3, "height above the WGS-84 ellipsoid", minimum=100e3, maximum=5000e3)
    heading_deg: float = _f(0.0, "azimuth of the inertial velocity from north, east positive",
                            minimum=-360, maximum=360)
    flight_path_deg: float = _f(0.0, "elevation of the inertial velocity above the local horizontal",
                                minimum=-45, maximum=45)
    speed_mps: float = _f(0.0, "inertial speed (0: the circular speed sqrt(GM / r))", minimum=0)
    yaw_deg: float = _f(0.0, "initial turn of y_b about x_b from the along-track direction towards "
                        "the orbit normal", minimum=-360, maximum=360)
    yaw_rate_dps: float = _f(0.0, "rate of the pointing law's turn about x_b (the zenith axis)",
                             minimum=-10, maximum=10)


@dataclass
class RenderConfig:
    """What the renderer draws for this flight's images (``horizon-nav simulate``)."""
    payload: bool = _f(True, "draw the launcher's payload structure into the images (an orbital "
                       "camera sees none)")
    limb_shift_m: float = _f(0.0, "lift of the rendered limb air (RenderOptions.limb_shift_m): the "
                             "threshold edge sits this much above the default's 45 km",
                             minimum=-100e3, maximum=100e3)


@dataclass
class SimulationConfig:
    duration_s: float = _f(600.0, "simulated flight time", minimum=0, exclusive_min=True)
    truth_rate_hz: float = _f(400.0, "rate of the stored truth; every sensor rate must divide it", minimum=0,
                              exclusive_min=True)
    substeps: int = _f(5, "RK4 steps per truth sample (integration rate = truth_rate_hz * substeps)", minimum=1)
    horizon_atmosphere_m: float = _f(0.0, "effective atmosphere thickness d of 003 eq. (5)", minimum=0)


@dataclass
class Scenario:
    """A complete flight scenario (see the module docstring)."""
    name: str
    description: str = ""
    launch: LaunchConfig = field(default_factory=LaunchConfig)
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    spin: SpinConfig = field(default_factory=SpinConfig)
    rcs: RcsConfig = field(default_factory=RcsConfig)
    disturbance: DisturbanceConfig = field(default_factory=DisturbanceConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    gps: GpsConfig = field(default_factory=GpsConfig)
    cameras: list = field(default_factory=list)
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    orbit: OrbitConfig | None = None   # None: a launch ([launch], [vehicle] stages)
    render: RenderConfig = field(default_factory=RenderConfig)
    source: str = ""      # path of the file it was read from ("" when built in code)
    toml_text: str = ""   # the file's text (written into logs as metadata)


_TABLES = {"launch": LaunchConfig, "vehicle": VehicleConfig, "spin": SpinConfig, "rcs": RcsConfig,
           "disturbance": DisturbanceConfig, "imu": ImuConfig, "gps": GpsConfig,
           "simulation": SimulationConfig, "orbit": OrbitConfig, "render": RenderConfig}
_LISTS = {"cameras": CameraConfig, "vehicle.stages": StageConfig}


# ------------------------------------------------------------------------------------------------
# Validation
# ------------------------------------------------------------------------------------------------
def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_range(v: float, md: dict, where: str) -> None:
    if not math.isfinite(v):
        raise UserError(f"{where} = {v!r}: expected a finite number")
    lo, hi = md.get("min"), md.get("max")
    if lo is not None and (v < lo or (md.get("xmin") and v <= lo)):
        raise UserError(f"{where} = {v!r}: expected {'>' if md.get('xmin') else '>='} {lo}")
    if hi is not None and v > hi:
        raise UserError(f"{where} = {v!r}: expected <= {hi}")


def _check_array(v, shape: tuple, md: dict, where: str):
    if not isinstance(v, list):
        raise UserError(f"{where} = {v!r}: expected an array of shape {_shape_text(shape)}")
    if shape[0] is not None and len(v) != shape[0]:
        raise UserError(f"{where}: expected {shape[0]} entries ({_shape_text(shape)}), got {len(v)}")
    out = []
    for i, x in enumerate(v):
        if len(shape) > 1:
            out.append(_check_array(x, shape[1:], md, f"{where}[{i}]"))
        else:
            if not _is_num(x):
                raise UserError(f"{where}[{i}] = {x!r}: expected a number")
            _check_range(float(x), md, f"{where}[{i}]")
            out.append(float(x))
    return out


def _shape_text(shape) -> str:
    return "[" + ", ".join("n" if s is None else str(s) for s in shape) + "]"


def _build(cls, table: Any, where: str, prefix: str):
    """Instance of dataclass ``cls`` from a TOML table; UserError naming ``where`` and the key."""
    if not isinstance(table, dict):
        raise UserError(f"{where}: [{prefix}] must be a table, got {type(table).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise UserError(f"{where}: unknown key {prefix}.{unknown[0]}; expected one of "
                        f"{sorted(fields)}")
    kwargs = {}
    for name, v in table.items():
        f = fields[name]
        key = f"{where}: {prefix}.{name}"
        if cls is VehicleConfig and name == "stages":
            if not isinstance(v, list) or not all(isinstance(s, dict) for s in v):
                raise UserError(f"{key}: expected an array of tables [[vehicle.stages]]")
            kwargs[name] = [_build(StageConfig, s, where, f"vehicle.stages[{i}]") for i, s in enumerate(v)]
            continue
        typ, md = hints[name], f.metadata
        if md.get("shape") is not None:
            kwargs[name] = _check_array(v, md["shape"], md, key)
        elif typ is bool:
            if not isinstance(v, bool):
                raise UserError(f"{key} = {v!r}: expected true or false")
            kwargs[name] = v
        elif typ is int:
            if isinstance(v, bool) or not isinstance(v, int):
                raise UserError(f"{key} = {v!r}: expected an integer")
            _check_range(v, md, key)
            kwargs[name] = v
        elif typ is float:
            if not _is_num(v):
                raise UserError(f"{key} = {v!r}: expected a number ({md.get('doc', '')})")
            _check_range(float(v), md, key)
            kwargs[name] = float(v)
        elif typ is str:
            if not isinstance(v, str):
                raise UserError(f"{key} = {v!r}: expected a string")
            if md.get("choices") and v not in md["choices"]:
                raise UserError(f"{key} = {v!r}: expected one of {list(md['choices'])}")
            kwargs[name] = v
        else:  # pragma: no cover - all field types are covered above
            raise TypeError(f"unsupported field type {typ} for {prefix}.{name}")
    return cls(**kwargs)


def scenario_from_dict(doc: dict, where: str = "<scenario>", toml_text: str = "") -> Scenario:
    """Build and validate a :class:`Scenario` from a parsed TOML document."""
    known = {"name", "description", "cameras"} | set(_TABLES)
    unknown = sorted(set(doc) - known)
    if unknown:
        raise UserError(f"{where}: unknown key or table {unknown[0]!r}; expected {sorted(known)}")
    name = doc.get("name")
    if not isinstance(name, str) or not name:
        raise UserError(f"{where}: key 'name' must be a non-empty string")
    desc = doc.get("description", "")
    if not isinstance(desc, str):
        raise UserError(f"{where}: key 'description' must be a string")
    kw: dict[str, Any] = {"name": name, "description": desc}
    for tname, cls in _TABLES.items():
        if tname in doc:
            kw[tname] = _build(cls, doc[tname], where, tname)
    cams = doc.get("cameras", [])
    if not isinstance(cams, list) or not all(isinstance(c, dict) for c in cams):
        raise UserError(f"{where}: 'cameras' must be an array of tables [[cameras]]")
    kw["cameras"] = [_build(CameraConfig, c, where, f"cameras[{i}]") for i, c in enumerate(cams)]
    sc = Scenario(**kw, source=where, toml_text=toml_text)
    check_consistency(sc, where)
    return sc


def check_consistency(sc: Scenario, where: str) -> None:
    """Cross-key checks: event order, sensor rates dividing the truth rate, camera files."""
    sim = sc.simulation
    rates = [("imu.rate_hz", sc.imu.rate_hz), ("gps.rate_hz", sc.gps.rate_hz)]
    rates += [(f"cameras[{i}].rate_hz", c.rate_hz) for i, c in enumerate(sc.cameras)]
    for key, r in rates:
        ratio = sim.truth_rate_hz / r
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise UserError(f"{where}: {key} = {r}: must divide simulation.truth_rate_hz = "
                            f"{sim.truth_rate_hz} (sensors sample the stored truth)")
    if not sc.vehicle.stages and sc.orbit is None:
        raise UserError(f"{where}: vehicle.stages: at least one [[vehicle.stages]] table is required")
    for i, s in enumerate(sc.vehicle.stages):
        if s.rise_s + s.tail_off_s > s.burn_time_s:
            raise UserError(f"{where}: vehicle.stages[{i}]: rise_s + tail_off_s = {s.rise_s + s.tail_off_s} "
                            f"exceeds burn_time_s = {s.burn_time_s}")
        if s.separation_s < s.ignition_s + s.burn_time_s:
            raise UserError(f"{where}: vehicle.stages[{i}].separation_s = {s.separation_s}: expected >= "
                            f"ignition_s + burn_time_s = {s.ignition_s + s.burn_time_s}")
    if sc.rcs.release_dps >= sc.rcs.threshold_dps:
        raise UserError(f"{where}: rcs.release_dps = {sc.rcs.release_dps}: expected < rcs.threshold_dps "
                        f"= {sc.rcs.threshold_dps}")
    t_prev = -1.0
    for i, (t, _) in enumerate(sc.spin.profile_hz):
        if t < t_prev:
            raise UserError(f"{where}: spin.profile_hz[{i}]: times must increase")
        t_prev = t
    for i, (a, b) in enumerate(sc.gps.outages_s):
        if b <= a:
            raise UserError(f"{where}: gps.outages_s[{i}] = [{a}, {b}]: expected start < end")
    from nav import timescales
    key, stamp = ("launch.time_utc", sc.launch.time_utc) if sc.orbit is None else ("orbit.epoch_utc",
                                                                                    sc.orbit.epoch_utc)
    try:
        timescales.parse_utc(stamp)
    except ValueError as exc:
        raise UserError(f"{where}: {key} = {stamp!r}: {exc}") from None
    for i, c in enumerate(sc.cameras):
        if c.fov_deg > 0:
            try:
                load_camera_for(c)
            except ValueError as exc:
                raise UserError(f"{where}: cameras[{i}].fov_deg = {c.fov_deg}: {exc}") from None
        else:
            resolve_camera_path(c.intrinsics, where, f"cameras[{i}].intrinsics", sc.source)


def resolve_camera_path(intrinsics: str, where: str = "", key: str = "intrinsics", source: str = "") -> Path:
    """Camera file for an ``intrinsics`` value: a library name or a path (relative to the scenario)."""
    cand = [LIBRARY_DIR / "cameras" / f"{intrinsics}.toml", Path(intrinsics)]
    if source:
        cand.append(Path(source).parent / intrinsics)
    for p in cand:
        if p.is_file():
            return p
    names = sorted(p.stem for p in (LIBRARY_DIR / "cameras").glob("*.toml"))
    raise UserError(f"{where}: {key} = {intrinsics!r}: no such camera file (library cameras: {names})")


def load_camera_for(cam: CameraConfig, source: str = ""):
    """The camera model (`vision.camera`) of a camera config: its camera file (any format of
    scenarios/config/camera.py), or the equidistant fisheye of ``fov_deg``."""
    from scenarios.config.camera import load_camera
    from vision.camera import from_fov

    if cam.fov_deg > 0:
        return from_fov(cam.width, cam.height, cam.fov_deg, (1.0,), axis="horizontal", name=f"fov{cam.fov_deg:g}")
    return load_camera(resolve_camera_path(cam.intrinsics, source or "<scenario>", "intrinsics", source))


# ------------------------------------------------------------------------------------------------
# Files and the library
# ------------------------------------------------------------------------------------------------
def load_scenario_file(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file (UserError naming the file and key on problems)."""
    doc, text = read_toml(path, "scenario file")
    return scenario_from_dict(doc, str(Path(path)), text)


def library_names() -> list[str]:
    """Names of the built-in scenarios (``scenarios/library/*.toml``)."""
    return sorted(p.stem for p in LIBRARY_DIR.glob("*.toml"))


def load_scenario(name_or_path: str | Path) -> Scenario:
    """A library scenario by name (``"atek"``) or any scenario file by path."""
    s = str(name_or_path)
    p = Path(s)
    if s.endswith(".toml") or p.is_file():
        return load_scenario_file(p)
    lib = LIBRARY_DIR / f"{s}.toml"
    if lib.is_file():
        return load_scenario_file(lib)
    raise UserError(f"scenario {s!r}: not a library scenario (available: {', '.join(library_names())}) "
                    f"and not a .toml file")


def library() -> list[tuple[str, str]]:
    """(name, one-line description) of every library scenario."""
    out = []
    for name in library_names():
        sc = load_scenario(name)
        out.append((name, sc.description.strip().splitlines()[0] if sc.description.strip() else ""))
    return out
