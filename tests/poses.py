"""Camera poses for rendering and vision tests: a camera at a geodetic point looking at an azimuth
and depression, as R_ec (camera to ECEF) and x_e."""
import math

import numpy as np

from nav import earth


def pose(az_deg, down_deg=20.0, h=230e3, lat=67.89, lon=21.10, roll_deg=0.0):
    """Camera at (lat, lon, h) looking ``down_deg`` below the local horizontal at azimuth ``az_deg``,
    image x horizontal (optionally rolled about the optical axis)."""
    la, lo = math.radians(lat), math.radians(lon)
    x = earth.geodetic_to_ecef(la, lo, h)
    az, el = math.radians(az_deg), -math.radians(down_deg)
    z_n = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), -math.sin(el)])
    x_n = np.cross([0.0, 0.0, 1.0], z_n)
    x_n /= np.linalg.norm(x_n)
    R_nc = np.column_stack([x_n, np.cross(z_n, x_n), z_n])
    r = math.radians(roll_deg)
    Rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return earth.R_en(la, lo) @ R_nc @ Rz, np.asarray(x)
