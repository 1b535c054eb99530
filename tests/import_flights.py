"""Small simulated flights written as the CSV tables a user would import (tests of the import's
plausibility and cross-checks).

* :func:`rocket_tables`: the ATEK rocket (scenarios.sim, 120 s: boost, spin, coast), IMU at 20 Hz
  with Unix-millisecond stamps, GPS at 10 Hz with Unix-second stamps, geodetic position, NED
  velocity and sigma columns.
* :func:`plane_tables`: an aircraft-like flight built from kinematics: 20 s at rest on the ground,
  a 20 s take-off roll to 60 m/s, then S-turns at 30 deg of bank, 100 Hz IMU (exact specific force
  and rate from the trajectory, ``nav.earth`` gravity, Earth rate; white noise), GPS at 5 Hz with
  2 m / 0.05 m/s noise.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pcsv

from nav import earth
from nav.rotation import matrix_to_rotvec, quat_to_matrix

T0 = 1_560_392_460_000_000_000  # 2019-06-13T02:21:00Z
LIFTOFF = "2019-06-13T02:21:00Z"


def write_csv(path: Path, cols: dict) -> Path:
    pcsv.write_csv(pa.table(cols), path)
    return path


def gps_columns(t_ns, x_e, v_e, sig_p, sig_v) -> dict:
    lat, lon, h = earth.ecef_to_geodetic(x_e)
    vn = np.einsum("nji,nj->ni", earth.R_en(lat, lon), v_e)
    return {"t": t_ns / 1e9, "lat": np.degrees(lat), "lon": np.degrees(lon), "h": h, "vn": vn[:, 0],
            "ve": vn[:, 1], "vd": vn[:, 2], "sig_p": np.full(len(t_ns), sig_p), "sig_v": np.full(len(t_ns), sig_v)}


def imu_columns(t_ns, w, f) -> dict:
    return {"t_ms": t_ns // 1_000_000, "gx": w[:, 0], "gy": w[:, 1], "gz": w[:, 2],
            "ax": f[:, 0], "ay": f[:, 1], "az": f[:, 2]}


IMU_TOML = """
[imu]
file = "imu.csv"
time = {{ column = "t_ms", base = "unix", unit = "{imu_unit}" }}
gyro = {{ columns = ["gx", "gy", "gz"], unit = "{gyro_unit}" }}
accel = {{ columns = ["ax", "ay", "az"], unit = "m/s^2" }}
{imu_extra}"""

GPS_TOML = """
[gps]
file = "gps.csv"
time = {{ column = "t", base = "{gps_base}", unit = "s"{gps_week} }}
position = {{ frame = "geodetic", columns = [{latlon}, "h"], angle_unit = "deg", unit = "m" }}
{velocity}{sigmas}{gps_extra}"""

VEL = 'velocity = { frame = "%s", columns = ["vn", "ve", "vd"], unit = "m/s" }\n'
SIGMAS = ('position_sigma = { column = "sig_p", unit = "m" }\n'
          'velocity_sigma = { column = "sig_v", unit = "m/s" }\n')


def mapping(d: Path, name="m.toml", *, imu_unit="ms", gyro_unit="rad/s", imu_extra="", gps_base="unix",
            gps_week="", latlon='"lat", "lon"', vel_frame="ned", sigmas=True, gps_extra="", imu=True,
            gps=True) -> Path:
    text = f'liftoff_utc = "{LIFTOFF}"\n'
    if imu:
        text += IMU_TOML.format(imu_unit=imu_unit, gyro_unit=gyro_unit, imu_extra=imu_extra)
    if gps:
        has_v = vel_frame is not None
        sig = SIGMAS if sigmas else ""
        if sigmas and not has_v:
            sig = SIGMAS.splitlines()[0] + "\n"
        text += GPS_TOML.format(gps_base=gps_base, gps_week=gps_week, latlon=latlon,
                                velocity=VEL % vel_frame if has_v else "", sigmas=sig, gps_extra=gps_extra)
    p = d / name
    p.write_text(text)
    return p


def rocket_tables(d: Path, seed: int = 3, duration: float = 120.0):
    """The ATEK flight as imu.csv / gps.csv in ``d``; returns the FlightData."""
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight
    fl = simulate_flight(load_scenario("atek"), seed, duration)
    t_imu = T0 + np.round(fl.imu.t * 1e9).astype(np.int64)
    write_csv(d / "imu.csv", imu_columns(t_imu, fl.imu.gyro, fl.imu.accel))
    g = fl.gps
    t_gps = T0 + np.round(g.t * 1e9).astype(np.int64)
    write_csv(d / "gps.csv", gps_columns(t_gps, g.position, g.velocity, 3.0, 0.1))
    return fl


def R_nb_zyx(roll, pitch, yaw):
    """Body -> north-east-down rotation of z-y-x Euler angles [rad], written out element by element."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    R = np.empty(roll.shape + (3, 3))
    R[..., 0, 0] = cp * cy
    R[..., 0, 1] = sr * sp * cy - cr * sy
    R[..., 0, 2] = cr * sp * cy + sr * sy
    R[..., 1, 0] = cp * sy
    R[..., 1, 1] = sr * sp * sy + cr * cy
    R[..., 1, 2] = cr * sp * sy - sr * cy
    R[..., 2, 0] = -sp
    R[..., 2, 1] = sr * cp
    R[..., 2, 2] = cr * cp
    return R


def plane_truth(duration=180.0, rate=100.0):
    """Kinematic truth of the aircraft-like flight (module docstring): t [s], x_e, v_e, R_eb, f_b, w_b."""
    h = 1.0 / rate
    t = np.arange(int(round(duration * rate)) + 1) * h
    s = np.clip((t - 20.0) / 20.0, 0.0, 1.0)
    V = 60.0 * s * s * (3 - 2 * s)                       # smooth take-off roll, then 60 m/s
    turn = np.clip((t - 45.0) / 5.0, 0.0, 1.0)           # S-turns from T+45
    psi_rate = turn * np.radians(9.0) * np.sin(2 * np.pi * (t - 45.0) / 40.0)
    yaw = np.cumsum(psi_rate) * h
    roll = np.arctan(V * psi_rate / 9.81)               # coordinated turn
    pitch = np.zeros_like(t)
    lat0, lon0, h0 = np.radians(48.0), np.radians(11.0), 500.0
    vn = np.stack([V * np.cos(yaw), V * np.sin(yaw), 0 * V], 1)
    dn = np.cumsum(vn, axis=0) * h
    lat = lat0 + dn[:, 0] / earth.meridian_radius(lat0)
    lon = lon0 + dn[:, 1] / (earth.prime_vertical_radius(lat0) * np.cos(lat0))
    x = earth.geodetic_to_ecef(lat, lon, h0 - dn[:, 2])
    v = np.gradient(x, h, axis=0)
    a = np.gradient(v, h, axis=0)
    R_eb = earth.R_en(lat, lon) @ R_nb_zyx(roll, pitch, yaw)
    f_e = a - earth.gravity_e(x) + 2.0 * np.cross(earth.OMEGA_IE_E, v)
    f_b = np.einsum("nji,nj->ni", R_eb, f_e)
    dR = np.einsum("nji,njk->nik", R_eb[:-2], R_eb[2:])      # R_b(t-h) b(t+h)
    w_eb = np.vstack([np.zeros((1, 3)), matrix_to_rotvec(dR) / (2 * h), np.zeros((1, 3))])
    w_eb[-1] = w_eb[-2]
    w_b = w_eb + np.einsum("nji,j->ni", R_eb, earth.OMEGA_IE_E)
    return t, x, v, R_eb, f_b, w_b


def plane_tables(d: Path, seed: int = 1, duration: float = 180.0, sensor_R=None):
    """The aircraft-like flight as imu.csv / gps.csv in ``d`` (``sensor_R``: R_bs of a sensor
    mounted with other axes; the columns then hold v_s = R_bs^T v_b)."""
    rng = np.random.default_rng(seed)
    t, x, v, R_eb, f_b, w_b = plane_truth(duration)
    w = w_b + rng.normal(0, 2e-4, w_b.shape)
    f = f_b + rng.normal(0, 5e-3, f_b.shape)
    if sensor_R is not None:
        w, f = w @ sensor_R, f @ sensor_R
    t_ns = T0 + np.round(t * 1e9).astype(np.int64)
    write_csv(d / "imu.csv", imu_columns(t_ns, w, f))
    k = np.arange(0, len(t), 20)  # 5 Hz
    write_csv(d / "gps.csv", gps_columns(t_ns[k], x[k] + rng.normal(0, 2.0, (k.size, 3)),
                                         v[k] + rng.normal(0, 0.05, (k.size, 3)), 2.0, 0.05))
    return t, x, v, R_eb


__all__ = ["T0", "LIFTOFF", "mapping", "rocket_tables", "plane_tables", "plane_truth", "write_csv",
           "gps_columns", "imu_columns", "quat_to_matrix", "R_nb_zyx", "sample_tables"]


#: the sample of scenarios/library/import/sample/ (README "What a user runs"): its start (GPS week
#: and seconds of week of 2024-05-14T09:30:00Z) and the body axes in the IMU's sensor axes
SAMPLE_START_UTC = "2024-05-14T09:30:00Z"
SAMPLE_AXES = ("+y", "+x", "-z")     # body x = sensor +y, body y = sensor +x, body z = sensor -z


def sample_tables(d: Path, duration: float = 80.0, rate: float = 40.0, seed: int = 7) -> None:
    """The import sample: the aircraft-like flight of :func:`plane_truth` (20 s at rest, take-off
    roll, S-turns) as a receiver and an IMU would log it: both stamped in GPS week and seconds of
    week, the IMU at ``rate`` in deg/s and g in its own axes (``SAMPLE_AXES``) with white noise
    (0.0115 deg/s, 0.5 mg) and the output resolution of a MEMS unit (1e-4 deg/s, 1e-5 g), the
    receiver at 5 Hz with geodetic position (noise 1.5 m north/east, 3 m down), NED velocity
    (0.05 m/s) and the sigma columns it reports."""
    from nav.timescales import parse_utc, utc_to_gps_ns
    rng = np.random.default_rng(seed)
    t, x, v, R_eb, f_b, w_b = plane_truth(duration, rate)
    R_bs = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])   # rows: body axes in sensor axes
    w_s = (w_b + rng.normal(0, 2e-4, w_b.shape)) @ R_bs
    f_s = (f_b + rng.normal(0, 5e-3, f_b.shape)) @ R_bs
    gps0 = int(utc_to_gps_ns(parse_utc(SAMPLE_START_UTC)))
    week, sow0 = divmod(gps0, 604800 * 10 ** 9)

    def stamps(tt):
        return {"gps_week": np.full(tt.size, week, np.int64), "tow_s": np.round(sow0 / 1e9 + tt, 3)}
    imu = stamps(t)
    imu.update({f"gyro_{a}_dps": np.round(np.degrees(w_s[:, i]), 4) for i, a in enumerate("xyz")})
    imu.update({f"acc_{a}_g": np.round(f_s[:, i] / 9.80665, 5) for i, a in enumerate("xyz")})
    write_csv(d / "imu.csv", imu)
    k = np.arange(0, len(t), int(round(rate / 5.0)))
    lat, lon, h = earth.ecef_to_geodetic(x[k])
    sig = np.array([1.5, 1.5, 3.0])
    dn = rng.normal(0, 1, (k.size, 3)) * sig
    lat = lat + dn[:, 0] / earth.meridian_radius(lat)
    lon = lon + dn[:, 1] / (earth.prime_vertical_radius(lat) * np.cos(lat))
    vn = np.einsum("nji,nj->ni", earth.R_en(lat, lon), v[k]) + rng.normal(0, 0.05, (k.size, 3))
    gps = stamps(t[k])
    gps.update({"lat_deg": np.round(np.degrees(lat), 8), "lon_deg": np.round(np.degrees(lon), 8),
                "height_m": np.round(h - dn[:, 2], 3), "vel_n": np.round(vn[:, 0], 3), "vel_e": np.round(vn[:, 1], 3),
                "vel_d": np.round(vn[:, 2], 3), "sigma_n": np.full(k.size, sig[0]),
                "sigma_e": np.full(k.size, sig[1]), "sigma_d": np.full(k.size, sig[2]),
                "sigma_vel": np.full(k.size, 0.05), "sats": np.full(k.size, 11, np.int64)})
    write_csv(d / "gps.csv", gps)
