"""6-DOF truth of a sounding-rocket flight in the Earth-fixed frame e.

Model (all in e, docs/conventions.md "Frames"; the navigation frame of 003 §6):

* translation: ``dx/dt = v``, ``dv/dt = R_eb f_b + g_e(x) - 2 Omega_ie x v`` with ``g_e`` the J2
  gravitation plus centrifugal acceleration (:func:`nav.earth.gravity_e`) and the specific force
  ``f_b = (thrust x_b + drag + RCS force) / m`` (what an accelerometer at the centre of mass measures);
* drag: point-mass drag ``-1/2 rho |v| v CdA`` against the e-frame velocity (the atmosphere rotates
  with the Earth, no wind), rho from the U.S. Standard Atmosphere 1976 (:mod:`scenarios.sim.atmosphere`);
* thrust: trapezoidal profile per stage with total impulse = propellant * Isp * g0; the mass falls with
  the burnt propellant and drops at each separation (first stage, nose cone, motor; 003 table 2);
* rotation: ``I domega_ib/dt = tau - omega_ib x I omega_ib`` (Euler's equations, body frame, full
  inertia tensor) with the torques:
  - spin-up: ``tau_x = Ixx k (omega_target(t) - omega_x)`` (canted fins and spin-up motors);
  - fin stability (weathercock) until nose-cone separation: a critically damped restoring torque
    that turns x_b towards the air-relative velocity, natural frequency ``weathercock_frequency``;
    it also cancels the gyroscopic term about y_b, z_b, so the spinning stack follows its flight path;
  - yo-yo despin: ``tau_x = -Ixx omega_x / T`` during ``despin_duration_s``;
  - motor-separation tip-off: a constant torque for ``tipoff_duration_s`` giving ``tipoff_dps``;
  - RCS (003 §7.1): per axis a bang-bang thruster pair fires when ``|omega_i| > threshold`` and stops
    when ``|omega_i| < release`` (hysteresis), decided at each integration step; each firing also
    gives a small specific force (misaligned thrusters, 003 §7.2, fig. 34);
  - disturbance torques from the payload experiments: constant + sinusoid per axis;
* attitude: ``dq_eb/dt = 1/2 q_eb (x) [omega_eb_b, 0]``, ``omega_eb_b = omega_ib_b - R_be Omega_ie``.

Integration: classical RK4 with a fixed step (``1 / (truth_rate_hz * substeps)``, 2 kHz by default),
quaternion renormalised after each step, in a numba kernel (:mod:`scenarios.sim._truth_kernel`). The state
also integrates ``omega_ib_b`` and ``f_b`` so that interval-averaged IMU samples and increments are
exact integrals of the truth (:mod:`scenarios.sim.imu`). With a 0.5 ms step the RK4 error of the
spinning ascent (omega dt = 0.011 rad) is about (omega dt)^5 / 120 per step: < 1e-6 rad over 60 s.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nav import earth, timescales
from nav.rotation import matrix_to_quat
from scenarios.sim import _truth_kernel as kern
from scenarios.sim import atmosphere, orbit
from scenarios.sim.scenario import G0, Scenario


@dataclass
class Truth:
    """Truth samples at ``t`` [s after lift-off] (uniform, ``dt`` apart).

    ``x_e``, ``v_e`` (N, 3) [m, m/s]; ``q_eb`` (N, 4) scalar-last; ``omega_ib_b`` (N, 3) [rad/s];
    ``f_b`` (N, 3) specific force in b [m/s^2] (right limit: RCS switching happens at sample times);
    ``int_omega_b``, ``int_f_b`` (N, 3): integrals from lift-off of omega_ib_b and f_b;
    ``rcs`` (N, 3) int8: RCS thruster state per axis (-1, 0, +1 = sign of the torque);
    ``liftoff_ns``: UTC lift-off [ns].
    """
    t: np.ndarray
    x_e: np.ndarray
    v_e: np.ndarray
    q_eb: np.ndarray
    omega_ib_b: np.ndarray
    f_b: np.ndarray
    int_omega_b: np.ndarray
    int_f_b: np.ndarray
    rcs: np.ndarray
    liftoff_ns: int
    dt: float
    events: dict = field(default_factory=dict)

    @property
    def t_ns(self) -> np.ndarray:
        """UTC time stamps [ns] (rounded to the ns)."""
        return self.liftoff_ns + np.round(self.t * 1e9).astype(np.int64)

    def geodetic(self):
        """(lat, lon, h) [rad, rad, m] of every sample."""
        return earth.ecef_to_geodetic(self.x_e)


# ------------------------------------------------------------------------------------------------
# vehicle schedule
# ------------------------------------------------------------------------------------------------
def _thrust_profile(stage, t):
    """Trapezoidal thrust [N] of one stage at times t: area = propellant * Isp * g0."""
    impulse = stage.propellant_kg * stage.isp_s * G0
    flat = stage.burn_time_s - 0.5 * (stage.rise_s + stage.tail_off_s)
    f_max = impulse / flat if flat > 0 else 0.0
    tau = t - stage.ignition_s
    up = np.clip(tau / max(stage.rise_s, 1e-9), 0.0, 1.0)
    down = np.clip((stage.burn_time_s - tau) / max(stage.tail_off_s, 1e-9), 0.0, 1.0)
    on = (tau >= 0.0) & (tau <= stage.burn_time_s)
    return np.where(on, f_max * np.minimum(up, down), 0.0)


def build_schedule(sc: Scenario, duration: float, grid_s: float = 0.02):
    """Rows (times ``st``, values ``sv`` (n, N_COLS)) of the vehicle schedule, jumps as repeated times."""
    veh, spin, rcs, dis = sc.vehicle, sc.spin, sc.rcs, sc.disturbance
    t_end = duration + 1.0
    events = [0.0, t_end]
    for s in veh.stages:
        events += [s.ignition_s, s.ignition_s + s.rise_s, s.ignition_s + s.burn_time_s - s.tail_off_s,
                   s.ignition_s + s.burn_time_s, s.separation_s]
    jumps = [veh.nose_cone_separation_s, spin.despin_s, spin.despin_s + spin.despin_duration_s,
             spin.motor_separation_s, spin.motor_separation_s + spin.tipoff_duration_s, rcs.start_s, rcs.end_s,
             dis.start_s, veh.weathercock_end_s, veh.reentry_s] + [s.separation_s for s in veh.stages]
    events += jumps + [veh.chute_s, veh.chute_s + veh.chute_inflation_s]
    events += [p[0] for p in spin.profile_hz]
    grid = np.unique(np.concatenate([np.arange(0.0, t_end, grid_s), [e for e in events if 0 <= e <= t_end]]))
    jump_t = np.array(sorted({j for j in jumps if 0 < j < t_end}))
    # each jump time appears twice: first row = left limit, second = right limit
    st = np.sort(np.concatenate([grid, jump_t]))
    side_right = np.zeros(len(st), bool)
    for j in jump_t:
        idx = np.flatnonzero(st == j)
        side_right[idx[-1]] = True
    # evaluate with a tiny offset towards the side so that step functions take the right value
    te = st + np.where(side_right, 1e-9, -1e-9)
    te[0] = 0.0
    sv = np.zeros((len(st), kern.N_COLS))
    # thrust and mass
    thrust = np.zeros(len(st))
    fine = np.arange(0.0, t_end + 0.001, 0.001)
    mass = np.full(len(st), veh.payload_mass_kg + veh.nose_cone_mass_kg)
    for s in veh.stages:
        thrust += _thrust_profile(s, te)
        # burnt propellant: integral of thrust / (Isp g0), from a fine trapezoid integral
        fp = _thrust_profile(s, fine) / (s.isp_s * G0)
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (fp[1:] + fp[:-1]) * np.diff(fine))])
        burnt_s = np.interp(te, fine, cum)
        mass += np.where(te < s.separation_s, s.dry_mass_kg + s.propellant_kg - burnt_s, 0.0)
    mass -= np.where(te >= veh.nose_cone_separation_s, veh.nose_cone_mass_kg, 0.0)
    sv[:, kern.C_THRUST] = thrust
    sv[:, kern.C_MASS] = mass
    after_motor = te >= spin.motor_separation_s
    chute = np.clip((te - veh.chute_s) / veh.chute_inflation_s, 0.0, 1.0)
    cda = np.where(after_motor, np.where(te >= veh.reentry_s, veh.cd_area_reentry_m2, veh.cd_area_payload_m2),
                   veh.cd_area_ascent_m2)
    sv[:, kern.C_CDA] = cda + chute * (veh.chute_cd_area_m2 - cda)
    ia = np.array(veh.inertia_ascent_kgm2)
    ip = np.array(veh.inertia_payload_kgm2)
    sv[:, kern.C_IXX:kern.C_IZZ + 1] = np.where(after_motor[:, None], ip, ia)
    sv[:, kern.C_IXY:kern.C_IYZ + 1] = np.where(after_motor[:, None], np.array(veh.inertia_payload_products_kgm2), 0.0)
    prof = np.array(spin.profile_hz, dtype=float).reshape(-1, 2)
    target = 2 * np.pi * np.interp(te, prof[:, 0], prof[:, 1]) if len(prof) else np.zeros(len(st))
    despin = (te >= spin.despin_s) & (te < spin.despin_s + spin.despin_duration_s)
    spinning = te < spin.despin_s
    sv[:, kern.C_SPIN_TARGET] = np.where(spinning, target, 0.0)
    sv[:, kern.C_SPIN_GAIN] = np.where(spinning, spin.gain_per_s,
                                       np.where(despin, 1.0 / spin.despin_time_constant_s, 0.0))
    sv[:, kern.C_WEATHERCOCK] = np.where(te < veh.weathercock_end_s, veh.weathercock_frequency_rad_s, 0.0)
    sv[:, kern.C_RCS] = (rcs.enabled & (te >= rcs.start_s) & (te < rcs.end_s)).astype(float)
    tip = (te >= spin.motor_separation_s) & (te < spin.motor_separation_s + spin.tipoff_duration_s)
    tip_torque = ip * np.radians(spin.tipoff_dps) / spin.tipoff_duration_s
    sv[:, kern.C_TORQUE:kern.C_TORQUE + 3] = np.where(tip[:, None], tip_torque, 0.0)
    sv[:, kern.C_DISTURB] = (te >= dis.start_s).astype(float)
    if np.any(mass <= 0):
        raise ValueError("vehicle: the mass becomes zero or negative; check the stage masses")
    return st, sv


def orbit_schedule(sc: Scenario, duration: float, grid_s: float = 0.5):
    """Vehicle schedule of a flight in orbit (``sc.orbit``): the payload's mass and inertia, no
    thrust, drag, spin or fin torques, the pointing law's torque (:mod:`scenarios.sim.orbit`; it
    turns by less than 1e-3 rad per ``grid_s`` at rates below 0.1 deg/s, so the linear
    interpolation between rows is exact to ~1e-7 of the torque), the RCS and the disturbances as
    configured."""
    veh, rcs, dis = sc.vehicle, sc.rcs, sc.disturbance
    st = np.arange(0.0, duration + 1.0 + grid_s, grid_s)
    sv = np.zeros((len(st), kern.N_COLS))
    sv[:, kern.C_MASS] = veh.payload_mass_kg
    sv[:, kern.C_IXX:kern.C_IZZ + 1] = veh.inertia_payload_kgm2
    sv[:, kern.C_IXY:kern.C_IYZ + 1] = veh.inertia_payload_products_kgm2
    sv[:, kern.C_TORQUE:kern.C_TORQUE + 3] = orbit.pointing_torque(sc.orbit, st, inertia_tensor(veh))
    sv[:, kern.C_RCS] = (rcs.enabled & (st >= rcs.start_s) & (st < rcs.end_s)).astype(float)
    sv[:, kern.C_DISTURB] = (st >= dis.start_s).astype(float)
    return st, sv


def inertia_tensor(veh) -> np.ndarray:
    """The payload's inertia tensor [kg m^2] (principal moments, products with the kernel's sign)."""
    ixx, iyy, izz = veh.inertia_payload_kgm2
    ixy, ixz, iyz = veh.inertia_payload_products_kgm2
    return np.array([[ixx, -ixy, -ixz], [-ixy, iyy, -iyz], [-ixz, -iyz, izz]])


def orbit_initial_state(sc: Scenario) -> np.ndarray:
    """State at the epoch of ``sc.orbit``: position, e-frame velocity, the pointing law's attitude
    and body rate (i = e at t = 0)."""
    x, v_i = orbit.initial_inertial_state(sc.orbit)
    R_ib, w = orbit.pointing_law(sc.orbit, np.zeros(1))
    y0 = np.zeros(kern.N_STATE)
    y0[0:3] = x
    y0[3:6] = v_i - np.cross(earth.OMEGA_IE_E, x)
    y0[6:10] = matrix_to_quat(R_ib[0])
    y0[10:13] = w[0]
    return y0


def initial_state(sc: Scenario) -> np.ndarray:
    """State at lift-off: on the launcher, at rest in e, rotating with the Earth (or in orbit)."""
    if sc.orbit is not None:
        return orbit_initial_state(sc)
    la = sc.launch
    lat, lon = np.radians(la.lat_deg), np.radians(la.lon_deg)
    x0 = earth.geodetic_to_ecef(lat, lon, la.height_m)
    el, az, roll = np.radians(la.elevation_deg), np.radians(la.azimuth_deg), np.radians(la.roll_deg)
    xb_n = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)])
    down = np.array([0.0, 0.0, 1.0])
    yb_n = np.cross(down, xb_n)
    yb_n /= np.linalg.norm(yb_n)
    zb_n = np.cross(xb_n, yb_n)
    cr, sr = np.cos(roll), np.sin(roll)
    y_r, z_r = cr * yb_n + sr * zb_n, -sr * yb_n + cr * zb_n
    R_nb = np.stack([xb_n, y_r, z_r], axis=-1)
    R_eb = earth.R_en(lat, lon) @ R_nb
    q0 = matrix_to_quat(R_eb)
    w0 = R_eb.T @ earth.OMEGA_IE_E
    y0 = np.zeros(kern.N_STATE)
    y0[0:3] = x0
    y0[6:10] = q0
    y0[10:13] = w0
    return y0


def simulate_truth(sc: Scenario, duration: float | None = None) -> Truth:
    """Integrate the flight of ``sc`` for ``duration`` s (default ``sc.simulation.duration_s``)."""
    sim = sc.simulation
    duration = float(sim.duration_s if duration is None else duration)
    if not duration > 0:
        raise ValueError(f"duration = {duration}: expected > 0 s")
    dt_out = 1.0 / sim.truth_rate_hz
    n_out = int(round(duration * sim.truth_rate_hz))
    dt = dt_out / sim.substeps
    st, sv = build_schedule(sc, duration) if sc.orbit is None else orbit_schedule(sc, duration)
    rho_step, logrho = atmosphere.density_table()
    rcs = sc.rcs
    rcs_torque = np.array(rcs.torque_nm, dtype=float)
    rcs_force = np.array(rcs.specific_force_mg, dtype=float) * 1e-3 * G0
    rcs_thr = np.radians([rcs.threshold_dps, rcs.release_dps])
    d = sc.disturbance
    dist = np.array([d.torque_nm, d.amplitude_nm, d.period_s], dtype=float)
    prm = np.array([sc.vehicle.weathercock_min_speed_mps])
    Y = np.empty((n_out + 1, kern.N_STATE))
    F = np.empty((n_out + 1, 3))
    S = np.empty((n_out + 1, 3), dtype=np.int8)
    kern.integrate(initial_state(sc), dt, n_out, int(sim.substeps), st, sv, rho_step, logrho, rcs_torque,
                   rcs_force, rcs_thr, dist, prm, Y, F, S)
    t = np.arange(n_out + 1) * dt_out
    return Truth(t=t, x_e=Y[:, 0:3].copy(), v_e=Y[:, 3:6].copy(), q_eb=Y[:, 6:10].copy(),
                 omega_ib_b=Y[:, 10:13].copy(), f_b=F, int_omega_b=Y[:, 13:16].copy(),
                 int_f_b=Y[:, 16:19].copy(), rcs=S, liftoff_ns=timescales.parse_utc(start_utc(sc)),
                 dt=dt_out, events=_events(sc))


def start_utc(sc: Scenario) -> str:
    """UTC of t = 0: the lift-off, or the epoch of a flight in orbit."""
    return sc.launch.time_utc if sc.orbit is None else sc.orbit.epoch_utc


def _events(sc: Scenario) -> dict:
    """Event times [s] of the flight (only the start for a flight in orbit)."""
    if sc.orbit is not None:
        return {"epoch": 0.0}
    events = {"liftoff": 0.0, "nose_cone_separation": sc.vehicle.nose_cone_separation_s,
              "despin": sc.spin.despin_s, "motor_separation": sc.spin.motor_separation_s,
              "rcs_on": sc.rcs.start_s, "rcs_off": sc.rcs.end_s, "chute": sc.vehicle.chute_s}
    for i, s in enumerate(sc.vehicle.stages):
        events[f"stage{i + 1}_ignition"] = s.ignition_s
        events[f"stage{i + 1}_separation"] = s.separation_s
    return events


def summary(tr: Truth) -> dict:
    """Key figures of a flight: apogee, state at the start of the coast, rates (for reports/tests)."""
    _, _, h = tr.geodetic()
    speed = np.linalg.norm(tr.v_e, axis=1)
    i_apo = int(np.argmax(h))
    out = {"apogee_m": float(h[i_apo]), "apogee_t_s": float(tr.t[i_apo]), "min_height_m": float(np.min(h)),
           "max_spin_dps": float(np.degrees(np.max(np.abs(tr.omega_ib_b[:, 0]))))}
    i60 = int(np.searchsorted(tr.t, 60.0))
    if i60 < len(tr.t):
        out.update(height_T60_m=float(h[i60]), speed_T60_mps=float(speed[i60]))
    out["final_t_s"] = float(tr.t[-1])
    out["final_height_m"] = float(h[-1])
    return out
