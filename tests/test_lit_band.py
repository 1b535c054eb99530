"""A lit band of air over a dark Earth (twilight or night below a sunlit upper atmosphere) seen
by a narrow camera: the band's lower edge is bright on its upper side and dark below, like a day
limb upside down, and on a short arc the mirrored cone fits as well as the true one (002 §3). The
front end must not return the nadir mirrored into the sky."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from tests.moon_frames import moon_over_earth
from vision.config import VisionConfig
from vision.frontend import process_frame


def test_a_lit_band_over_a_dark_earth_gives_no_mirrored_nadir():
    """40 rendered horizon views from 500 km through 3-6 deg rectilinear lenses
    (`tests.moon_frames.moon_over_earth`, seed 1: the Sun anywhere, so some limbs are twilit
    bands over a night Earth), the Earth only, the height given. Before the band test
    (`SideCheckOptions.band_depth_deg`) 3 of the 16 Earth vectors were 137 deg off (the band's
    lower edge, the nadir mirrored into the sky) with a 3 sigma of 1.5 deg. Now every Earth vector
    is inside its 3 sigma, and the band frames say why they have none (measured: 12 vectors, 4
    band frames, one of them a band's upper edge whose nadir was right by chance)."""
    rng = np.random.default_rng(1)
    c = VisionConfig()
    cfg = dataclasses.replace(c, sun=dataclasses.replace(c.sun, enabled=False))
    found, band = 0, 0
    for i in range(40):
        f = moon_over_earth(rng, rng.uniform(8, 60), rng.uniform(0.2, 1.0), seed=i)
        res = process_frame(f.image, f.camera, cfg, height_m=500e3)
        rec = res.record("earth")
        if rec is None:
            band += "a lit band over a dark Earth" in res.reasons["earth"]
            continue
        found += 1
        err = math.degrees(math.acos(min(1.0, float(rec.e_c @ f.earth_c))))
        assert err < 3 * rec.sigma_deg, (i, err, rec.sigma_deg)
    assert found >= 10 and band >= 3, (found, band)
