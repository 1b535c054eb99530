"""The flight simulator: a scenario file (:mod:`.scenario`) becomes a true trajectory (:mod:`.truth`
with its numba integrator :mod:`._truth_kernel` and the US 1976 :mod:`.atmosphere`), IMU samples and
GPS fixes with their errors (:mod:`.imu`, :mod:`.gps`), per-frame camera truth
(:mod:`.camera_geometry`), camera images (:mod:`.render` with :mod:`._render_kernel` and the
:mod:`.clouds` cube map) and horizon/Sun vectors with the vision error model
(:mod:`.truth_vectors`); :mod:`.simulate` assembles a whole flight. The public names below are
imported from their module on first use (:mod:`scenarios._lazy`).
"""
from typing import TYPE_CHECKING

from scenarios._lazy import lazy_exports

if TYPE_CHECKING:
    from .camera_geometry import camera_truth, mount_rotation
    from .gps import GpsFixes, simulate_gps
    from .imu import ImuSamples, simulate_imu
    from .render import RenderOptions, render_flight_images, render_frame
    from .scenario import Scenario, library, library_names, load_scenario
    from .simulate import FlightData, simulate_cameras, simulate_flight
    from .truth import Truth, simulate_truth
    from .truth_vectors import TruthVectors, flight_truth_vectors, log_truth_vectors

__all__ = [
    "Scenario", "load_scenario", "library", "library_names",
    "Truth", "simulate_truth", "ImuSamples", "simulate_imu", "GpsFixes", "simulate_gps",
    "camera_truth", "mount_rotation", "FlightData", "simulate_flight", "simulate_cameras",
    "RenderOptions", "render_frame", "render_flight_images",
    "TruthVectors", "flight_truth_vectors", "log_truth_vectors",
]
__getattr__ = lazy_exports(__name__, __file__)
