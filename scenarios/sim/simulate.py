"""Simulate a flight: truth, IMU, GPS and per-frame camera truth from one scenario and one seed.

Random numbers: one :class:`numpy.random.SeedSequence` per run, and one independent stream per
sensor, keyed by a fixed spawn key (IMU 1, GPS 2, camera k: 100 + k). Changing one sensor's
configuration (e.g. the GPS rate) therefore leaves every other sensor's draws unchanged.
Images are not rendered here: :func:`scenarios.sim.render.render_flight_images` renders them from the
returned flight as a stream, which ``horizon-nav simulate`` writes straight into the log.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nav import ephemeris
from scenarios.sim import camera_geometry as cg
from scenarios.sim.gps import GpsFixes, simulate_gps
from scenarios.sim.imu import ImuErrors, ImuSamples, simulate_imu
from scenarios.sim.scenario import Scenario, load_camera_for
from scenarios.sim.truth import Truth, simulate_truth

STREAM_IMU, STREAM_GPS, STREAM_CAMERA = 1, 2, 100

def rng_for(seed: int, stream: int) -> np.random.Generator:
    """Independent generator of one sensor: SeedSequence(seed, spawn_key=(stream,))."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(stream),)))


@dataclass
class CameraRun:
    """One camera of a run: index k (1-based), intrinsics, nominal and true mount, misalignment
    ``psi_c`` [rad] (003 eq. (50)), stamps ``t_ns`` (camera clock) and the per-frame truth."""
    k: int
    camera: object
    R_bc_nominal: np.ndarray
    R_bc: np.ndarray
    psi_c: np.ndarray
    t_ns: np.ndarray
    truth: cg.CameraTruth
    clock_offset_s: float


@dataclass
class FlightData:
    """Everything a simulated flight produced (numpy arrays; times in UTC ns where named ``*_ns``)."""
    scenario: Scenario
    seed: int
    duration: float
    truth: Truth
    imu: ImuSamples
    imu_errors: ImuErrors
    gps: GpsFixes
    cameras: list

    @property
    def liftoff_ns(self) -> int:
        return self.truth.liftoff_ns

    def to_ns(self, t_s) -> np.ndarray:
        return self.truth.liftoff_ns + np.round(np.asarray(t_s) * 1e9).astype(np.int64)


def simulate_cameras(sc: Scenario, truth: Truth, seed: int, step_px: float = 20.0) -> list[CameraRun]:
    """Mounts, misalignments and per-frame truth of every camera of ``sc``."""
    out = []
    _, _, h_all = truth.geodetic()
    for i, cfg in enumerate(sc.cameras):
        k = i + 1
        rng = rng_for(seed, STREAM_CAMERA + k)
        psi = rng.normal(0.0, np.radians(cfg.misalignment_sigma_deg), 3)
        R_nom = cg.mount_rotation(cfg.azimuth_deg, cfg.depression_deg, cfg.roll_deg)
        R_bc = cg.true_mount(cfg.azimuth_deg, cfg.depression_deg, cfg.roll_deg, psi)
        end = truth.t[-1] if cfg.end_s <= 0 else min(cfg.end_s, truth.t[-1])
        t = np.arange(cfg.start_s, end + 1e-9, 1.0 / cfg.rate_hz)
        idx = np.round(t / truth.dt).astype(int)
        if np.any(np.abs(idx * truth.dt - t) > 1e-9):
            raise ValueError(f"cameras[{i}]: frame times must fall on the truth grid "
                             f"(start_s a multiple of {truth.dt} s)")
        t_ns = truth.liftoff_ns + np.round(t * 1e9).astype(np.int64)
        x = truth.x_e[idx]
        sun = ephemeris.sun_direction_e(t_ns, x)
        moon = ephemeris.moon_direction_e(t_ns, x)
        cam = load_camera_for(cfg, sc.source)
        ct = cg.camera_truth(cam, R_bc, t, x, h_all[idx], truth.q_eb[idx], sun, moon,
                             radial_b=cg.radial_of(cfg.azimuth_deg), atmosphere_m=sc.simulation.horizon_atmosphere_m,
                             mask_deg=cfg.mask_deg, step_px=step_px)
        stamps = t_ns + int(round(cfg.clock_offset_s * 1e9))
        out.append(CameraRun(k, cam, R_nom, R_bc, psi, stamps, ct, cfg.clock_offset_s))
    return out


def simulate_flight(scenario: Scenario, seed: int = 0, duration: float | None = None, *,
                    imu_errors: bool = True, progress=None) -> FlightData:
    """Simulate ``scenario`` for ``duration`` s (default: the scenario's) with random seed ``seed``.

    ``progress``: optional callable ``progress(fraction, label)`` for a progress bar.
    ``imu_errors=False`` gives the error-free IMU (the truth check of tests/test_truth.py).
    """
    def step(frac, label):
        if progress is not None:
            progress(frac, label)

    duration = float(scenario.simulation.duration_s if duration is None else duration)
    step(0.0, "truth")
    truth = simulate_truth(scenario, duration)
    step(0.6, "imu")
    imu, errs = simulate_imu(truth, scenario.imu, rng_for(seed, STREAM_IMU), with_errors=imu_errors)
    step(0.7, "gps")
    gps = simulate_gps(truth, scenario.gps, rng_for(seed, STREAM_GPS))
    step(0.8, "cameras")
    cams = simulate_cameras(scenario, truth, seed)
    flight = FlightData(scenario, int(seed), duration, truth, imu, errs, gps, cams)
    step(1.0, "done")
    return flight
