"""The vision front end, assembled: from a raw, distorted camera frame to Earth-nadir, Sun and Moon
direction vectors with covariances (003 §3, §5; 000 §2.3-2.4; 002 §3; 004 §2.2).

Pipeline per target (`process_frame`)
-------------------------------------
1. Detection (`vision.candidates.detect`): brightness gate, threshold, border-following edge
   search (one brightness histogram per frame, shared by the targets). Earth: image border and payload-mask boundary only (003 §3.1); Sun/Moon: plus search
   lines ``2 f tan(alpha_min)`` apart (003 §5).
2. Candidate scoring, cheap: each candidate (longest first, at most ``max_candidates``; after
   one is accepted, only those at least ``compete_fraction`` as long) is subsampled to at most
   ``score_rays`` pixels spread along it, only those pixels are unprojected
   (`vision.camera.unproject`), and fitted directly; when more than ``direct_outlier_fraction``
   of them miss the cone by ``ransac_threshold_px`` (converted per ray to an angle,
   `vision.ransac.pixel_angle`), the pre-verified RANSAC cone fit (`vision.ransac.ransac_cone`,
   000 §2.3) runs instead. Earth: known alpha from the height (prior) and the effective
   atmosphere thickness d (003 eq. (5)), in the fit frame of the limb model (`vision.oblate`).
   Sun/Moon: alpha estimated (003 §5).
3. Acceptance per candidate, each failure giving a reason: enough pixels and inliers, residual
   (mean squared angular distance of the inliers from the cone, `vision.nadir.angle_residual`)
   below ``max_residual`` (003 §7.3, re-derived below), Sun/Moon apparent radius inside
   ``[alpha_min, alpha_max]``, within ``gate_deg`` of a predicted direction when the prior gives
   one (Sun/Moon: ephemeris + attitude; Earth: the geocentric nadir from x_e and R_ec), a disc that is bright inside and dark around (`_disc_check`), the implied conic passes through the image (003 §3.3 sanity check),
   and the mirrored-nadir test (002 §3): pixels a few pixels on the body side of the edge must be
   bright and those on the space side dark (`vision.nadir.earth_side_check`); a fit that fails it
   is retried from its mirror image (`vision.nadir.mirrored_direction`, refined locally).
4. The accepted candidate with the smallest residual wins (003 §3.4). Only the winner is
   processed fully: all its pixels are unprojected with the Jacobian
   (`vision.camera.unproject_jacobian`), inliers re-selected, refitted, and the O(m) covariance of
   003 eq. (33) with the correlated pixel noise (R, L) of eqs. (34)-(36), (38) is computed
   (`vision.covariance.direction_covariance`), plus, for the Earth, the term of the uncertain
   effective atmosphere thickness (sigma_d, below), and the spherical overbound of eq. (37).
   Earth with a prior giving x_e, R_ec and the Sun direction: before the covariance the winner's
   inlier pixels are moved to the fraction-of-peak crossing of the limb profile
   (`vision.limb.limb_edge_points`, exposure-invariant) and refitted with d = ``limb_height_m``
   (sigma ``limb_height_sigma_m``) when enough profiles are usable (``limb_*`` settings).

Residual thresholds (003 §7.3 re-derived for our residual)
----------------------------------------------------------
003 accepts horizons with delta < 0.025 and Suns with delta < 0.5e-5, delta being eq. (28): the
*sum* over the m edge points of squared distances along x_p on the z = f plane, with f = 1
(normalised coordinates; with f in pixels the 0.025 would be below the quantisation noise of a
single pixel). Our residual is the *mean* squared angular distance [rad^2]. A plane distance
dx at off-axis angle theta is an angle of about dx cos^2(theta); for 003's horizons (m ~ 2000
pixels spanning the 1920 px width, theta ~ 30-45 deg, cos^-4 ~ 2-4) delta < 0.025 means
mean(angle^2) < 0.025 / 2000 / 3 ~ 4e-6 rad^2 (2 mrad RMS, ~2.2 px at f = 1110 px). For the Sun
(a saturated, blooming disc, m ~ 100 pixels near the axis) delta < 0.5e-5 means
mean(angle^2) < 5e-8 rad^2 (0.22 mrad RMS, 0.25 px). The defaults (`scenarios/library/vision/
default.toml`) start from these figures and were checked on rendered frames (docs/vision.md).

Covariance terms
----------------
- Pixel noise, 003 eqs. (33)-(36) (Earth R = 1 px^2, L = 300 px) and (38) (Sun R = 9 px^2).
- Effective atmosphere thickness (Earth): the apparent horizon is where the limb's brightness
  crosses the threshold, at a tangent height d that varies with exposure and illumination
  (003 §4, 004 §3.4.3). With the *constrained* unit-norm fit a wrong d is a wrong alpha, and on
  a partial arc a wrong alpha tilts e towards the arc (nearly 1:1 for a short arc), so
  ``P_c += sigma_d^2 g g^T`` with ``g = de/dd`` (by a second fit at d + 1 km). 003 §4 found the
  estimate insensitive to d because its linear fit (eq. (24)) does not use alpha at all (the
  direction of lstsq(H, cos(alpha) 1) is independent of alpha; see `vision.nadir`); that
  estimator is ill-conditioned on partial arcs, which is why the constrained fit is used.
"""
from __future__ import annotations

import functools
import math
import threading
import time
from dataclasses import dataclass, field

import numba
import numpy as np

from vision.binarize import BinarizeConfig, as_frame, brightness_histogram
from vision.borders import SearchConfig, search_line_spacing, search_rows
from vision.camera import FisheyeCamera, project, unproject, unproject_jacobian
from vision.candidates import Candidate, Detection, DetectionConfig, detect
from vision.covariance import direction_covariance, largest_eigenvalue, tangent_basis
from vision.limb import (LimbEdgeConfig, flank_heights, fraction_height_shift, limb_edge_points, phase_slope,
                         profile_height_shift, tangent_height_sun, turn_towards)
from vision.mask import PayloadMask
from vision.nadir import (ConeFit, _norm3, angle_residual, angle_residuals, conic_type, within_cone,
                          direction_and_radius, mirrored_direction, nadir_from_horizon)
from vision.oblate import LimbModel, ellipsoid_model, sphere_model
from vision.ransac import pixel_angle, ransac_cone

__all__ = ["TargetConfig", "VisionConfig", "FramePrior", "VectorRecord", "CandidateResult",
           "TargetResult", "FrameResult", "process_frame", "conic_polyline", "default_config",
           "TARGETS"]

TARGETS = ("earth", "sun", "moon")


@dataclass(frozen=True)
class TargetConfig:
    """Processing of one target (Earth, Sun or Moon).

    Attributes
    ----------
    enabled : process this target.
    detection : threshold, brightness gate, edge search, minimum candidate length
        (`vision.candidates.DetectionConfig`).
    min_pixels : fewest inlier pixels for a vector.
    max_candidates : candidates scored (the longest first).
    score_rays : pixels per candidate used for the cheap RANSAC scoring (spread along the edge).
    ransac_threshold_px : RANSAC inlier distance to the cone [px] (converted per ray to an angle).
    ransac_max_hypotheses, ransac_confidence : RANSAC budget (000 §2.3, adaptive stop).
    min_inlier_fraction : fewest RANSAC inliers as a fraction of the scored pixels.
    max_residual : acceptance, mean squared angular distance of the inliers from the cone [rad^2]
        (003 §7.3 re-derived, module docstring).
    R_px2, L_px : pixel-noise variance [px^2] and correlation length [px] (003 eqs. (36), (38)).
    atmosphere_m : effective atmosphere thickness d [m] (003 eq. (5)); Earth only.
    atmosphere_sigma_m : its 1-sigma uncertainty [m], added to the covariance; Earth only.
    alpha_min_deg, alpha_max_deg : accepted apparent radius of the Sun/Moon (glare included).
    side_check_px : step [px] from the edge to the pixels of the mirrored-nadir test (002).
    side_check_min : fraction of those pixels that must be on their expected side.
    side_check_rays : edge pixels probed by that test.
    gate_deg : largest angle of an accepted vector from the predicted direction when the prior
        gives one: Sun/Moon `FramePrior.sun_c`, ``moon_c``; Earth the geocentric nadir
        ``R_ec.T @ (-x_e / |x_e|)`` when the prior has x_e and R_ec (a glare edge that fits a cone
        of the Earth's radius elsewhere, 78 deg off in a replay, is rejected). Covers
        attitude-prior and mounting errors of a few degrees.
    fit_rays : most pixels of the winning edge used for the final fit and covariance (spread
        along it; the correlation length is scaled with the step, so the covariance of the
        correlated noise (003 eq. (34)) is that of the full edge, module docstring).
    direct_outlier_fraction : a candidate is first fitted directly (all scored pixels); when at
        most this fraction is outside the RANSAC threshold the direct fit (refitted on its inliers)
        stands and RANSAC is skipped (most horizons and Suns: the cost of RANSAC is only paid on
        disturbed edges).
    curvature_tol_deg : pre-filter before any fit: at least one circle through three pixels spread
        along the edge must have an angular radius within this of alpha (Earth) or below
        ``alpha_max_deg`` plus this (Sun/Moon); the Sun's glare halo or a cloud bank does not
        (1 px of edge noise moves the radius of a third of a 1900 px horizon by ~2 deg).
    compete_fraction : candidates are scored longest first; once one is accepted, candidates
        shorter than this fraction of it are not scored (one Earth, one Sun: a much shorter edge
        cannot be the limb of the body whose limb was already found; it saves the RANSAC runs on
        cloud and glare edges).
    edge_offset_px : distance from the centres of the followed (white) border pixels to the
        brightness edge, which lies between them and their dark neighbours: half a pixel. The
        Earth cone is shrunk by this angle (without it the nadir is biased by ~0.03 deg on
        rendered frames); the Sun/Moon radius absorbs it.
    limb_fraction : Earth: > 0 moves the winner's edge pixels to where the limb profile crosses
        this fraction of its own maximum (`vision.limb`, exposure-invariant), and fits with
        d = ``limb_height_m`` (uncertainty ``limb_height_sigma_m``) instead of the threshold edge
        with ``atmosphere_m``; needs a prior with x_e, R_ec and ``sun_c``. 0 = off.
    limb_channel : colour channel of the decoded frame for the limb profile (BGR: 2 = red).
    limb_height_m, limb_height_sigma_m : tangent height of the fraction-of-peak crossing [m] and
        its frame-to-frame and along-the-limb spread (docs/vision.md).
    limb_min_sun_elev_deg : limb points with the Sun lower than this at the tangent point are not
        used (the lower limb is dimmed by the sunlight's own path, `vision.limb.tangent_height_sun`).
    limb_min_used : the fraction-of-peak edge is used only when at least this fraction of the
        winner's inliers give a usable profile (not clipped, Sun high enough); else the threshold
        edge with ``atmosphere_m`` stands.
    limb_sun_path : predict each limb point's crossing height from the Sun elevation at its
        tangent point (`vision.limb.fraction_height_shift`, eq. (5) of `vision.limb`; the
        sunlight's own path through the lower atmosphere lifts the limb maximum) and turn its ray
        by the shift, so one cone angle (``limb_height_m`` = the overhead-Sun height) fits all.
    limb_scale_height_m : H of that model [m].
    limb_profile_below_deg : points with the Sun lower than this at the tangent point take the
        Sun elevation's change down their profile into account
        (`vision.limb.profile_height_shift`: kilometres near the terminator, 30-90 m at 8-15 deg
        and less above, where eq. (5) alone is used: it costs ~3 us per point).
    limb_sun_path_sigma : model error as a fraction of the frame's mean shift (covariance term).
    limb_twilight_el_deg, limb_twilight_dh_m : measured correction [m] added to the model at these
        Sun elevations [deg] (linear interpolation, 0 outside): near the terminator the model is
        1-7 km low (docs/vision.md); ``limb_twilight_sigma_m`` the per-frame spread left after it,
        weighted in the covariance by the share of points below the last knot.
    limb_aerosol_weight, limb_aerosol_g : the limb's scattering phase function (Rayleigh plus this
        weight of a Henyey-Greenstein aerosol lobe of asymmetry g, `vision.limb.phase_function`):
        its change along each profile is divided out (`vision.limb.phase_slope`), which matters
        near the Sun; 0 = Rayleigh only.
    limb_refit_threshold_px : inlier threshold [px] of the refits with the limb heights (limb edge,
        flank, calibrated threshold edge): their rays lie on one cone to the heights' accuracy
        (~0.1 km, a fraction of a pixel), so a tighter one than ``ransac_threshold_px`` (which
        must admit the threshold edge's 1-4 km of height variation along the limb).
    limb_flank_profiles : when fewer than ``limb_min_used`` of the profiles are usable (a clipped
        limb maximum), the height of the edge pixel is fitted on the unsaturated flank of this
        many profiles spread along the edge (`vision.limb.flank_heights`: eq. (4)'s shape with
        the exposure and black level free), interpolated along it, and the threshold edge fitted
        with those heights; 0 = off. At least ``limb_flank_min_profiles`` must fit;
        ``limb_flank_sigma_m`` the covariance term (with the heights' spread over sqrt(n)).
    limb_calibrate_below : when fewer than this fraction of the winner's inliers give a usable
        limb profile (a clipped limb maximum, a twilight limb: a short arc), but at least
        ``limb_calibrate_min_points`` do, the threshold edge is *calibrated* on the same frame
        instead: at each usable point the threshold pixel lies ``a_i`` [rad] outside its
        fraction-of-peak crossing, whose height is known (``limb_height_m`` + Sun-path shift), so
        the threshold edge's effective thickness there is ``d_i = h_i + a_i / (d alpha / d d)``;
        their median ``d_thr`` replaces ``atmosphere_m`` and the *whole* threshold arc is fitted
        with it (a long arc instead of the short usable one). 0 = off. The covariance term is
        ``limb_calibrate_sigma_m`` (measured spread of ``d_thr`` against the true mean height of
        the threshold edge, docs/vision.md) with the spread of the d_i over sqrt(n) added.
    """

    enabled: bool = True
    detection: DetectionConfig = DetectionConfig()
    min_pixels: int = 50
    max_candidates: int = 6
    score_rays: int = 160
    ransac_threshold_px: float = 2.0
    ransac_max_hypotheses: int = 200
    ransac_confidence: float = 0.999
    min_inlier_fraction: float = 0.6
    max_residual: float = 4e-6
    R_px2: float = 1.0
    L_px: float = 300.0
    atmosphere_m: float = 0.0
    atmosphere_sigma_m: float = 0.0
    alpha_min_deg: float = 0.2
    alpha_max_deg: float = 5.0
    side_check_px: float = 3.0
    side_check_min: float = 0.8
    side_check_rays: int = 24
    gate_deg: float = 10.0
    fit_rays: int = 512
    edge_offset_px: float = 0.5
    direct_outlier_fraction: float = 0.05
    curvature_tol_deg: float = 10.0
    compete_fraction: float = 0.5
    limb_fraction: float = 0.0
    limb_channel: int = 2
    limb_height_m: float = 19.5e3
    limb_height_sigma_m: float = 250.0
    limb_min_sun_elev_deg: float = 10.0
    limb_min_used: float = 0.1
    limb_sun_path: bool = False
    limb_scale_height_m: float = 8000.0
    limb_profile_below_deg: float = 8.0
    limb_sun_path_sigma: float = 0.2
    limb_twilight_el_deg: tuple = ()
    limb_twilight_dh_m: tuple = ()
    limb_twilight_sigma_m: float = 1100.0
    limb_refit_threshold_px: float = 4.0
    limb_aerosol_weight: float = 0.0
    limb_aerosol_g: float = 0.75
    limb_flank_profiles: int = 0
    limb_flank_min_profiles: int = 8
    limb_flank_sigma_m: float = 600.0
    limb_calibrate_below: float = 0.0
    limb_calibrate_min_points: int = 20
    limb_calibrate_sigma_m: float = 1500.0

    def __post_init__(self):
        def bad(name, expected):
            raise ValueError(f"TargetConfig.{name} = {getattr(self, name)!r}; expected {expected}")

        for name in ("min_pixels", "max_candidates", "score_rays", "ransac_max_hypotheses",
                     "side_check_rays", "fit_rays"):
            if not (isinstance(getattr(self, name), int) and getattr(self, name) >= 1):
                bad(name, "an integer >= 1")
        if self.score_rays < 8:
            bad("score_rays", ">= 8 pixels")
        for name in ("ransac_threshold_px", "max_residual", "side_check_px", "alpha_max_deg", "gate_deg",
                     "curvature_tol_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                bad(name, "a finite number > 0")
        for name in ("R_px2", "atmosphere_sigma_m", "alpha_min_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                bad(name, "a finite number >= 0")
        if not self.L_px >= 1.0:
            bad("L_px", ">= 1 px (003 eq. (35))")
        if not 0.0 < self.ransac_confidence < 1.0:
            bad("ransac_confidence", "in (0, 1)")
        for name in ("min_inlier_fraction", "side_check_min", "direct_outlier_fraction", "compete_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                bad(name, "a fraction in [0, 1]")
        if not self.alpha_min_deg < self.alpha_max_deg < 90.0:
            bad("alpha_max_deg", "alpha_min_deg < alpha_max_deg < 90")
        if not (math.isfinite(self.atmosphere_m) and 0.0 <= self.atmosphere_m < 200e3):
            bad("atmosphere_m", "0 <= d < 200 km")
        if not 0.0 <= self.limb_fraction < 1.0:
            bad("limb_fraction", "0 (off) or a fraction in (0, 1)")
        if self.limb_channel not in (-1, 0, 1, 2):
            bad("limb_channel", "-1 (mean) or a channel index 0, 1, 2 of the decoded (BGR) frame")
        if not (math.isfinite(self.limb_height_m) and 0.0 <= self.limb_height_m < 200e3):
            bad("limb_height_m", "0 <= h < 200 km")
        if not (math.isfinite(self.limb_height_sigma_m) and self.limb_height_sigma_m >= 0):
            bad("limb_height_sigma_m", "a finite number >= 0")
        if not (math.isfinite(self.limb_min_sun_elev_deg) and -10.0 <= self.limb_min_sun_elev_deg <= 90.0):
            bad("limb_min_sun_elev_deg", "an elevation in [-10, 90] deg (below ~-3 deg the limb's maximum is "
                "the Earth's shadow edge)")
        if not 0.0 <= self.limb_min_used <= 1.0:
            bad("limb_min_used", "a fraction in [0, 1]")
        if not isinstance(self.limb_sun_path, bool):
            bad("limb_sun_path", "true or false")
        if not (math.isfinite(self.limb_scale_height_m) and 1e3 <= self.limb_scale_height_m <= 20e3):
            bad("limb_scale_height_m", "a scale height of 1..20 km (Earth: 7-8.5 km)")
        if not (math.isfinite(self.limb_profile_below_deg) and -10.0 <= self.limb_profile_below_deg <= 90.0):
            bad("limb_profile_below_deg", "an elevation in [-10, 90] deg")
        if not (math.isfinite(self.limb_sun_path_sigma) and self.limb_sun_path_sigma >= 0):
            bad("limb_sun_path_sigma", "a finite fraction >= 0 of the Sun-path shift")
        kn, dv = tuple(self.limb_twilight_el_deg), tuple(self.limb_twilight_dh_m)
        if (len(kn) != len(dv) or len(kn) == 1
                or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in kn + dv)
                or any(b <= a for a, b in zip(kn[:-1], kn[1:])) or any(abs(v) > 30e3 for v in dv)):
            bad("limb_twilight_el_deg", "with limb_twilight_dh_m: equally long lists (>= 2 or empty) of "
                "increasing elevations [deg] and height corrections |dh| <= 30 km [m]")
        if not (math.isfinite(self.limb_twilight_sigma_m) and self.limb_twilight_sigma_m >= 0):
            bad("limb_twilight_sigma_m", "a finite number >= 0")
        if not (math.isfinite(self.limb_refit_threshold_px) and self.limb_refit_threshold_px > 0):
            bad("limb_refit_threshold_px", "a threshold > 0 px")
        if not (math.isfinite(self.limb_aerosol_weight) and 0.0 <= self.limb_aerosol_weight <= 1.0):
            bad("limb_aerosol_weight", "a weight in [0, 1]")
        if not (math.isfinite(self.limb_aerosol_g) and 0.0 <= self.limb_aerosol_g < 1.0):
            bad("limb_aerosol_g", "an asymmetry parameter in [0, 1)")
        if not (isinstance(self.limb_flank_profiles, int) and 0 <= self.limb_flank_profiles <= 512):
            bad("limb_flank_profiles", "an integer in [0, 512] (0 = off)")
        if not (isinstance(self.limb_flank_min_profiles, int) and self.limb_flank_min_profiles >= 3):
            bad("limb_flank_min_profiles", "an integer >= 3")
        if not (math.isfinite(self.limb_flank_sigma_m) and self.limb_flank_sigma_m >= 0):
            bad("limb_flank_sigma_m", "a finite number >= 0")
        if not 0.0 <= self.limb_calibrate_below <= 1.0:
            bad("limb_calibrate_below", "a fraction in [0, 1] (0 = off)")
        if not (isinstance(self.limb_calibrate_min_points, int) and self.limb_calibrate_min_points >= 3):
            bad("limb_calibrate_min_points", "an integer >= 3")
        if not (math.isfinite(self.limb_calibrate_sigma_m) and self.limb_calibrate_sigma_m >= 0):
            bad("limb_calibrate_sigma_m", "a finite number >= 0")


@dataclass(frozen=True)
class VisionConfig:
    """Front-end configuration: one `TargetConfig` per target, the Earth-radius fallback.

    ``sphere_radius_m``: radius of the substitute sphere when there is no position prior (003
    §2.8; None = ``nav.earth.R_MEAN``, or the Gaussian radius at ``FramePrior.lat``).
    """

    earth: TargetConfig = TargetConfig()
    sun: TargetConfig = TargetConfig()
    moon: TargetConfig = TargetConfig(enabled=False)
    sphere_radius_m: float | None = None

    def target(self, name: str) -> TargetConfig:
        if name not in TARGETS:
            raise ValueError(f"target {name!r}; expected one of {TARGETS}")
        return getattr(self, name)


def default_config(focal_px: float = 1110.0) -> VisionConfig:
    """Defaults for the ATEK-like cameras: the values of scenarios/library/vision/default.toml
    (which `scenarios.config.vision` loads; tests/test_frontend.py checks they agree), kept here so
    that `vision` needs no file I/O. ``focal_px`` sets the Sun/Moon search-line spacing."""
    sun_spacing = search_line_spacing(focal_px, math.radians(0.5))
    earth = TargetConfig(
        detection=DetectionConfig(BinarizeConfig(threshold=60.0, gate_min=2.0, gate_max=235.0), SearchConfig(), 40),
        min_pixels=100, max_residual=4e-6, R_px2=0.2, L_px=300.0,
        atmosphere_m=45e3, atmosphere_sigma_m=7e3, ransac_threshold_px=4.0, min_inlier_fraction=0.5,
        score_rays=100, ransac_max_hypotheses=100, limb_fraction=0.5, limb_height_m=18300.0, limb_height_sigma_m=150.0,
        limb_min_sun_elev_deg=-3.0, limb_sun_path=True, limb_sun_path_sigma=0.05, limb_refit_threshold_px=2.0,
        limb_aerosol_weight=0.25, limb_aerosol_g=0.75, limb_flank_profiles=16,
        limb_calibrate_below=0.1, limb_calibrate_sigma_m=3000.0)
    sun = TargetConfig(
        detection=DetectionConfig(BinarizeConfig(threshold=250.0), SearchConfig(line_spacing_px=sun_spacing), 12),
        min_pixels=12, max_residual=1e-6, R_px2=0.16, L_px=300.0, alpha_min_deg=0.2,
        alpha_max_deg=4.0, ransac_threshold_px=2.0, min_inlier_fraction=0.5, score_rays=100,
        ransac_max_hypotheses=100)
    moon = TargetConfig(
        enabled=False,
        detection=DetectionConfig(BinarizeConfig(threshold=120.0), SearchConfig(line_spacing_px=sun_spacing), 12),
        min_pixels=12, max_residual=1e-6, R_px2=9.0, L_px=300.0, alpha_min_deg=0.2,
        alpha_max_deg=1.0, min_inlier_fraction=0.5)
    return VisionConfig(earth=earth, sun=sun, moon=moon)


@dataclass(frozen=True)
class FramePrior:
    """Prior knowledge for one frame: position ``x_e`` [m] (GPS/INS) and camera attitude ``R_ec``
    (camera -> e) enable the ellipsoid model (`vision.oblate.ellipsoid_model`); ``lat`` [rad]
    alone selects the Gaussian radius of curvature for the spherical model. ``sun_c``, ``moon_c``:
    predicted unit directions in the camera frame (ephemeris + attitude prior, e.g.
    ``R_ec.T @ nav.ephemeris.sun_direction_e(t, x_e)``): Sun/Moon candidates further than
    ``TargetConfig.gate_deg`` from them are rejected (lens-flare ghosts, glints; 004 §3.4); with
    x_e and R_ec, Earth candidates further than the Earth's ``gate_deg`` from the predicted
    geocentric nadir ``R_ec.T @ (-x_e / |x_e|)`` are rejected too (glare edges)."""

    x_e: np.ndarray | None = None
    R_ec: np.ndarray | None = None
    lat: float | None = None
    sun_c: np.ndarray | None = None
    moon_c: np.ndarray | None = None


@dataclass(frozen=True)
class VectorRecord:
    """One direction vector (the DirectionVector log message, docs/log-format.md).

    e_c : unit vector in the camera frame (Earth: geocentric nadir -x_e/|x_e| with the ellipsoid
        model, 003 eq. (39); the substitute-sphere centre with the spherical model).
    P_c : full 3x3 covariance (003 eq. (33) + atmosphere term); P_overbound : eq. (37).
    residual : mean squared angular residual of the inliers [rad^2].
    pixel_count : pixels of the winning edge candidate; inlier_count : its inliers (counted on the
        up to ``fit_rays`` pixels used for the final fit, scaled to the whole edge).
    conic_type : "ellipse" / "hyperbola" of the fitted cone in the image (003 Table 1).
    alpha : cone half-angle [rad] (Earth: in the fit frame of the limb model; Sun/Moon: estimated).
    model : "ellipsoid", "sphere" (Earth) or "" (Sun/Moon).
    """

    t_ns: int
    camera: int
    target: str
    e_c: np.ndarray
    P_c: np.ndarray
    P_overbound: np.ndarray
    residual: float
    pixel_count: int
    inlier_count: int
    conic_type: str
    alpha: float
    model: str = ""

    @property
    def sigma_deg(self) -> float:
        """1-sigma angle of the overbound [deg]."""
        return math.degrees(math.sqrt(self.P_overbound[0, 0]))


@dataclass
class CandidateResult:
    """Outcome of one candidate: fit (None if it failed early), residual, reason ("" = accepted)."""

    index: int
    n_pixels: int
    fit: ConeFit | None = None
    residual: float = math.inf
    inliers: int = 0
    reason: str = ""
    mirrored: bool = False


@dataclass
class TargetResult:
    """Everything about one target in one frame, for records and annotation."""

    target: str
    detection: Detection | None
    candidates: list = field(default_factory=list)
    winner: int | None = None
    points: np.ndarray | None = None     # winner's pixels (m, 2)
    inlier_mask: np.ndarray | None = None
    record: VectorRecord | None = None
    reason: str = ""
    baseline_e_c: np.ndarray | None = None   # general conic fit (vision.conic) on the winner
    baseline_reason: str = ""
    limb_edge: bool = False   # Earth: the fraction-of-peak limb edge was used (vision.limb)
    limb_used: float = 0.0    # its fraction of usable limb profiles
    limb_shift_m: float = 0.0  # mean Sun-path height shift of its points (vision.limb eq. (5))
    limb_path: str = ""       # Earth: "limb" (fraction-of-peak edge), "flank" (threshold edge with
    # heights fitted on the unsaturated profile flanks), "calibrated" (threshold edge
    # with d calibrated on the usable limb profiles), "" (threshold edge with atmosphere_m)
    limb_d_m: float = math.nan  # effective thickness of the threshold edge [m]: calibrated d_thr, or
    # the mean height fitted on the profile flanks
    cone_alpha: float = math.nan  # Earth: median angle of the inlier rays about the vector [rad], the
    # visible horizon's cone (its conic type; drawn by the replay's overlay)


@dataclass
class FrameResult:
    """`process_frame` output: the vector records, a reason per target without a vector, the
    per-target details and the stage timings [s]."""

    records: list
    reasons: dict
    targets: dict
    timings: dict
    model: str

    def record(self, target: str) -> VectorRecord | None:
        for r in self.records:
            if r.target == target:
                return r
        return None


# -------------------------------------------------------------------------------------------------
# helpers


@functools.lru_cache(maxsize=512)
def _subsample(m: int, k: int) -> np.ndarray:
    """At most k indices spread evenly over 0..m-1 (edge order kept). Cached per (m, k) (the
    same edge lengths recur from frame to frame); the returned array is read-only."""
    idx = np.arange(m) if m <= k else (_spread_indices(m, k) if k > 1 else np.zeros(max(k, 0), np.int64))
    idx.flags.writeable = False
    return idx


@numba.njit(cache=True)
def _spread_indices(m, k):  # pragma: no cover - numba
    """``np.unique(np.linspace(0, m - 1, k).round().astype(np.int64))`` for m > k > 1 (the same
    arithmetic: i * step, the last value exactly m - 1, round half to even; the step exceeds 1,
    so the rounded values are distinct and no sort is needed, but repeats are skipped anyway);
    np.unique and np.linspace cost ~20 us a call, and edge lengths change from frame to frame."""
    step = (m - 1) / (k - 1)
    out = np.empty(k, np.int64)
    n = 0
    for i in range(k):
        x = np.rint(i * step) if i < k - 1 else np.float64(m - 1)
        j = np.int64(x)
        if n == 0 or j > out[n - 1]:
            out[n] = j
            n += 1
    return out[:n]


def _median(x: np.ndarray) -> float:
    """``float(np.median(x))`` for a finite 1-D array, without np.median's per-call overhead
    (same arithmetic: the middle element, or the mean of the two middle ones)."""
    n = x.shape[0]
    if n == 0:
        return math.nan
    s = np.sort(x)
    if np.isnan(s[-1]):   # NaNs sort last; np.median gives NaN
        return math.nan
    h = n // 2
    return float(s[h]) if n % 2 else float((s[h - 1] + s[h]) / 2.0)


def conic_polyline(camera: FisheyeCamera, e_c: np.ndarray, alpha: float, n: int = 720,
                   model: LimbModel | None = None) -> np.ndarray:
    """Pixels (k, 2) of the cone (e, alpha) projected through the distorted camera model (the
    fitted conic drawn in distorted pixel space, 003 figs. 15, 27); NaN where a ray is beyond the
    lens's range or behind the camera. With ``model`` the cone is taken in its fit frame
    (e_c the fit-frame direction) and mapped back into the camera."""
    e = np.asarray(e_c, float)
    rays = math.cos(alpha) * e + math.sin(alpha) * (_unit_circle(n) @ tangent_basis(e).T)
    if model is not None and model.kind != "sphere":
        rays = rays @ model.M_inv.T
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        uv = project(camera, rays)
    return uv


@functools.lru_cache(maxsize=8)
def _unit_circle(n: int, endpoint: bool = True) -> np.ndarray:
    """(n, 2) [cos psi, sin psi] at ``np.linspace(0, 2 pi, n, endpoint)``, C-contiguous, read-only."""
    psi = np.linspace(0.0, 2 * math.pi, n, endpoint=endpoint)
    c = np.ascontiguousarray(np.stack([np.cos(psi), np.sin(psi)], axis=1))
    c.flags.writeable = False
    return c


def gate_search_rows(camera: FisheyeCamera, predicted: np.ndarray, angle: float,
                     search: SearchConfig) -> np.ndarray | None:
    """The rows of ``search``'s raster (003 §5) that can meet a body whose whole disc lies within
    ``angle`` [rad] of the ``predicted`` unit direction (gate + largest apparent radius): those
    between the top and bottom of that cap's image (a disc inside the cap crosses the same raster
    rows as before; the frame border is searched as always). None (the whole raster) when the cap
    reaches beyond the lens's range but not wholly; no rows when it lies wholly beyond it.

    The image of a cap inside the lens's range is bounded by the image of its rim (the projection
    is a diffeomorphism there), sampled at 64 points: between samples the rim bulges by
    <= r (1 - cos(pi / 64)) ~ 1e-3 r, r <= 1000 px, inside the 2 px margin.
    """
    rows = search_rows(camera.height, search.line_spacing_px, search.line_offset_px)
    if rows.size == 0 or not 0.0 < angle < math.pi / 2:
        return None
    off_axis = math.acos(max(-1.0, min(1.0, float(predicted[2]))))
    if off_axis - angle > camera.max_theta:
        return rows[:0]
    if off_axis + angle >= camera.max_theta:
        return None
    v = conic_polyline(camera, predicted, angle, 64)[:, 1]
    return rows[(rows >= v.min() - 2.0) & (rows <= v.max() + 2.0)]


def _in_image(camera: FisheyeCamera, uv: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return (np.isfinite(uv).all(axis=-1) & (uv[..., 0] >= -0.5) & (uv[..., 0] <= camera.width - 0.5)
                & (uv[..., 1] >= -0.5) & (uv[..., 1] <= camera.height - 0.5))


_PIXEL_ANGLE_CACHE: dict = {}


def _pixel_angle(camera: FisheyeCamera, uv: np.ndarray) -> np.ndarray:
    """`vision.ransac.pixel_angle` through a per-camera table over the distorted radius (the exact
    function is evaluated once per camera on 256 radii; linear interpolation between them, as
    ``np.interp`` on the table, `_interp_uniform`)."""
    q, pa, _ = _pixel_angle_table(camera)
    uv = np.asarray(uv, dtype=float)
    out = _interp_uniform(np.ascontiguousarray(uv.reshape(-1, 2)), camera.cx, camera.cy, camera.fx, camera.fy,
                          q[-1] / (q.size - 1), pa)
    return out.reshape(uv.shape[:-1])


@numba.njit(cache=True)
def _interp_uniform(uv, cx, cy, fx, fy, dq, tab):  # pragma: no cover - numba
    """``np.interp(r, q, tab)`` of the distorted radii r of pixels uv (n, 2) on the uniform grid
    q_j = j dq (end values beyond it): one pass instead of ~8 array operations per call."""
    n = uv.shape[0]
    out = np.empty(n)
    last = tab.shape[0] - 1
    for i in range(n):
        r = math.hypot((uv[i, 0] - cx) / fx, (uv[i, 1] - cy) / fy)
        x = r / dq
        if not x < last:                  # also NaN pixels: np.interp gives NaN for NaN
            out[i] = tab[last] if x >= last else math.nan
            continue
        j = int(x)
        out[i] = tab[j] + (tab[j + 1] - tab[j]) * (x - j)
    return out


def _max_pixel_angle(camera: FisheyeCamera) -> float:
    """The largest `_pixel_angle` in the image (its table's largest entry: interpolation between
    entries cannot exceed it)."""
    return _pixel_angle_table(camera)[2]


def _pixel_angle_table(camera: FisheyeCamera):
    """(radii, pixel angles, largest pixel angle) of `_pixel_angle`, cached per camera."""
    key = (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy, tuple(camera.k))
    tab = _PIXEL_ANGLE_CACHE.get(key)
    if tab is None:
        corners = np.array([[-0.5, -0.5], [camera.width - 0.5, camera.height - 0.5],
                            [-0.5, camera.height - 0.5], [camera.width - 0.5, -0.5]])
        rmax = float(np.max(np.hypot((corners[:, 0] - camera.cx) / camera.fx,
                                     (corners[:, 1] - camera.cy) / camera.fy)))
        rmax = min(rmax, camera.max_radius) if math.isfinite(camera.max_radius) else rmax
        q = np.linspace(0.0, rmax, 256)
        uvq = np.stack([camera.cx + q * camera.fx, np.full_like(q, camera.cy)], axis=-1)
        pa = pixel_angle(camera, uvq)
        tab = (q, pa, float(np.max(pa)))
        _PIXEL_ANGLE_CACHE[key] = tab
    return tab


def _side_score(image, camera, mask, threshold, rays_c, uv, e_c, alpha_c_space, step_px, n_probe):
    """Mirrored-nadir test (002 §3): step ``n_probe`` edge rays towards / away from e by
    ``step_px`` pixels, look at the image there, and check (as `vision.nadir.earth_side_check`)
    that the bright pixels are inside the cone (body) and the dark ones outside (space). Returns
    the agreeing fraction (NaN if no usable pixel). The per-probe work is one numba pass
    (`_side_kernel`: ~25 small numpy calls per candidate otherwise)."""
    sel = _subsample(rays_c.shape[0], n_probe)
    rays_c, uv = rays_c[sel], uv[sel]
    e = e_c / _norm3(e_c)
    pa = _pixel_angle(camera, uv)
    img = image if image.ndim == 3 else image[:, :, None]
    m = mask.mask if (mask is not None and mask.has_mask) else _NO_MASK
    good, total = _side_kernel(img, m, float(threshold), np.ascontiguousarray(rays_c), e, step_px * pa,
                               float(alpha_c_space), camera.fx, camera.fy, camera.cx, camera.cy,
                               np.asarray(camera.k), camera.max_theta)
    return good / total if total else math.nan


_NO_MASK = np.zeros((0, 0), dtype=bool)


@numba.njit(cache=True)
def _project1(x, y, z, fx, fy, cx, cy, k, max_theta):
    """Pixel of one ray: the formulas of `vision.camera._project_kernel` (NaN beyond max_theta)."""
    rho = math.hypot(x, y)
    theta = math.atan2(rho, z)
    if theta > max_theta or (rho == 0.0 and z <= 0.0):
        return math.nan, math.nan
    t2 = theta * theta
    n = k.shape[0]
    acc = k[n - 1]
    for i in range(n - 2, -1, -1):
        acc = acc * t2 + k[i]
    r_d = acc * theta
    scale = r_d / rho if rho > 0.0 else 0.0
    return cx + fx * scale * x, cy + fy * scale * y


@numba.njit(cache=True)
def _probe_brightness(img, mask, u, v):
    """Mean-channel brightness at the nearest pixel of (u, v) (``np.rint``, clipped), or -1 when (u, v)
    is outside the image (`_in_image`) or on the payload mask (an empty mask: none)."""
    h, w = img.shape[0], img.shape[1]
    if not (math.isfinite(u) and math.isfinite(v) and u >= -0.5 and u <= w - 0.5 and v >= -0.5
            and v <= h - 0.5):
        return -1.0
    iu = min(max(int(np.rint(u)), 0), w - 1)
    iv = min(max(int(np.rint(v)), 0), h - 1)
    if mask.shape[0] and mask[iv, iu]:
        return -1.0
    nc = img.shape[2]
    acc = 0.0
    for c in range(nc):
        acc += float(img[iv, iu, c])
    return acc / nc


@numba.njit(cache=True)
def _side_kernel(img, mask, threshold, rays, e, ang, alpha, fx, fy, cx, cy, k, max_theta):
    """Probes of `_side_score`: each ray turned by ang_j towards e and away from it (tangent
    ``t = e - (p.e) p`` normalised; rays with |t| <= 1e-9 skipped), projected, looked up
    (`_probe_brightness`); a bright probe (>= threshold) agrees when its angle from e is below
    alpha, a dark one when above. Returns (agreeing, usable) probe counts."""
    good = 0
    total = 0
    for sign in (1.0, -1.0):
        for j in range(rays.shape[0]):
            px, py, pz = rays[j, 0], rays[j, 1], rays[j, 2]
            d = px * e[0] + py * e[1] + pz * e[2]
            tx, ty, tz = e[0] - d * px, e[1] - d * py, e[2] - d * pz
            tn = math.sqrt(tx * tx + ty * ty + tz * tz)
            if not tn > 1e-9:
                continue
            ca, sa = math.cos(ang[j]), sign * math.sin(ang[j])
            qx = ca * px + sa * (tx / tn)
            qy = ca * py + sa * (ty / tn)
            qz = ca * pz + sa * (tz / tn)
            u, v = _project1(qx, qy, qz, fx, fy, cx, cy, k, max_theta)
            b = _probe_brightness(img, mask, u, v)
            if b < 0.0:
                continue
            qn = math.sqrt(qx * qx + qy * qy + qz * qz)
            c = (qx * e[0] + qy * e[1] + qz * e[2]) / qn
            a = math.acos(min(max(c, -1.0), 1.0))
            total += 1
            if (b >= threshold and a < alpha) or (b < threshold and a > alpha):
                good += 1
    return good, total


def _triple_radii(H: np.ndarray, n_triples: int = 6) -> np.ndarray:
    """Angular radii [rad] (<= pi/2) of the circles on the unit sphere through triples of rays
    spread along an ordered edge: the full span (first, middle, last) and ``n_triples - 1`` triples
    spanning a third of it. A plane through three unit rays cuts the sphere in a circle of angular
    radius rho with cos(rho) = distance of the plane from the origin."""
    m = H.shape[0]
    if m < 9:
        return np.zeros(0)
    return _triple_radii_kernel(np.ascontiguousarray(H, dtype=float), _triple_index(m, n_triples))


@functools.lru_cache(maxsize=512)
def _triple_index(m: int, n_triples: int) -> np.ndarray:
    """(n_triples, 3) indices of the triples of `_triple_radii` for an edge of m >= 9 rays."""
    s = m // 3
    starts = np.linspace(0, m - 1 - 2 * s, n_triples - 1).round().astype(np.int64)
    i = np.concatenate([[0], starts])
    j = np.concatenate([[m // 2], starts + s])
    k = np.concatenate([[m - 1], starts + 2 * s])
    idx = np.ascontiguousarray(np.stack([i, j, k], axis=1))
    idx.flags.writeable = False
    return idx


@numba.njit(cache=True)
def _triple_radii_kernel(H, idx):
    """arccos(|w . p1| / |w|), w = (p2 - p1) x (p3 - p1), for each index triple (p1, p2, p3);
    triples with |w| <= 1e-15 (collinear) are left out."""
    out = np.empty(idx.shape[0])
    n = 0
    for t in range(idx.shape[0]):
        i, j, k = idx[t, 0], idx[t, 1], idx[t, 2]
        ax, ay, az = H[j, 0] - H[i, 0], H[j, 1] - H[i, 1], H[j, 2] - H[i, 2]
        bx, by, bz = H[k, 0] - H[i, 0], H[k, 1] - H[i, 1], H[k, 2] - H[i, 2]
        wx, wy, wz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        wn = math.sqrt(wx * wx + wy * wy + wz * wz)
        if wn > 1e-15:
            c = abs(wx * H[i, 0] + wy * H[i, 1] + wz * H[i, 2]) / wn
            out[n] = math.acos(min(max(c, 0.0), 1.0))
            n += 1
    return out[:n]


def _disc_check(image, camera, mask, threshold, e_c, alpha, step_px, n: int = 16) -> str:
    """Sun/Moon disc test: the ring at alpha/2 about the fitted centre must lie in the image
    (at least 3/4 of its points, outside the payload mask) and be bright throughout, and at least
    3/4 of the ring at alpha + step_px pixels must be dark. Rejects short bright arcs (a saturated
    limb or glint at the image corner) that a small circle fits. Returns "" or the reason. The
    ring probes are one numba pass (`_disc_kernel`)."""
    T = tangent_basis(e_c)
    with np.errstate(invalid="ignore", divide="ignore"):
        uv_c = project(camera, e_c)
    pa = float(_pixel_angle(camera, uv_c[None, :])[0]) if np.isfinite(uv_c).all() else 1.0 / camera.fx
    img = image if image.ndim == 3 else image[:, :, None]
    m = mask.mask if (mask is not None and mask.has_mask) else _NO_MASK
    n_in, dark_in, n_out, dark_out = _disc_kernel(
        img, m, float(threshold), np.asarray(e_c, dtype=float), T, _unit_circle(n, False),
        0.5 * alpha, alpha + step_px * pa, camera.fx, camera.fy, camera.cx, camera.cy, np.asarray(camera.k),
        camera.max_theta)
    if n_in < 0.75 * n:
        return f"disc centre too close to the image edge or mask ({n_in}/{n} inner probes visible)"
    if dark_in:
        return f"disc not bright inside ({dark_in}/{n_in} inner probes below threshold)"
    if n_out and dark_out / n_out < 0.75:
        return f"bright around the disc ({n_out - dark_out}/{n_out} outer probes above threshold)"
    return ""


@numba.njit(cache=True)
def _disc_kernel(img, mask, threshold, e, T, cs, ang_in, ang_out, fx, fy, cx, cy, k, max_theta):
    """Rings of `_disc_check`: ``cos(ang) e + sin(ang) (cos psi t1 + sin psi t2)`` for the inner and
    the outer angle, projected and looked up (`_probe_brightness`). Returns (inner probes usable,
    of them below threshold, outer probes usable, of them below threshold)."""
    out = np.zeros(4, np.int64)
    for q in range(2):
        ang = ang_in if q == 0 else ang_out
        ca, sa = math.cos(ang), math.sin(ang)
        for j in range(cs.shape[0]):
            c, s = cs[j, 0], cs[j, 1]
            rx = c * T[0, 0] + s * T[0, 1]
            ry = c * T[1, 0] + s * T[1, 1]
            rz = c * T[2, 0] + s * T[2, 1]
            u, v = _project1(ca * e[0] + sa * rx, ca * e[1] + sa * ry, ca * e[2] + sa * rz,
                             fx, fy, cx, cy, k, max_theta)
            b = _probe_brightness(img, mask, u, v)
            if b < 0.0:
                continue
            out[2 * q] += 1
            if b < threshold:
                out[2 * q + 1] += 1
    return out[0], out[1], out[2], out[3]


def _refine_local(H: np.ndarray, e0: np.ndarray, c: float, iters: int = 8) -> np.ndarray:
    """Local minimum of |H e - c 1|^2 on |e| = 1 near e0 (Gauss-Newton in the tangent plane), for
    the mirrored-nadir alternative and the limb refits (the global minimum is
    `constrained_cone_fit`). One numba call (`_refine_kernel`): the numpy loop made ~10 small
    calls per iteration, up to 8 iterations, 2-4 times per frame."""
    e0 = np.asarray(e0, dtype=float)
    return _refine_kernel(np.ascontiguousarray(H, dtype=float), e0 / np.linalg.norm(e0), float(c), iters)


@numba.njit(cache=True)
def _tangent_basis(e):
    """`nav.rotation.tangent_basis` (same scalar arithmetic) of a unit vector."""
    e0, e1, e2 = e[0], e[1], e[2]
    n = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    e0, e1, e2 = e0 / n, e1 / n, e2 / n
    if abs(e0) < 0.9:
        t0, t1, t2 = 0.0, e2, -e1
    else:
        t0, t1, t2 = -e2, 0.0, e0
    tn = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    a0, a1, a2 = t0 / tn, t1 / tn, t2 / tn
    T = np.empty((3, 2))
    T[0, 0], T[1, 0], T[2, 0] = a0, a1, a2
    T[0, 1], T[1, 1], T[2, 1] = e1 * a2 - e2 * a1, e2 * a0 - e0 * a2, e0 * a1 - e1 * a0
    return T


@numba.njit(cache=True)
def _refine_kernel(H, e, c, iters):
    """Gauss-Newton of `_refine_local`: step ``dx = -lstsq(H T, H e - c)``, ``e <- (e + T dx) /
    |.|``, stop when |dx| < 1e-13. The two-column step from its 2x2 normal equations (Cholesky,
    one pass over the sums; a LAPACK gelsd call per iteration cost ~15 us, 5-10 per frame): their
    squared condition only slows the convergence, the fixed point ``(H T)^T (H e - c) = 0`` is the
    least-squares one whatever the step's rounding. A second column within rcond = eps max(m, 2)
    of the first's span (a degenerate edge) is dropped, as gelsd's minimum-norm step to first
    order."""
    m = H.shape[0]
    rcond = np.finfo(np.float64).eps * max(m, 2)
    e = e.copy()
    for _ in range(iters):
        T = _tangent_basis(e)
        s11 = s12 = s22 = s1r = s2r = 0.0
        for j in range(m):
            a0 = H[j, 0] * T[0, 0] + H[j, 1] * T[1, 0] + H[j, 2] * T[2, 0]
            a1 = H[j, 0] * T[0, 1] + H[j, 1] * T[1, 1] + H[j, 2] * T[2, 1]
            rj = H[j, 0] * e[0] + H[j, 1] * e[1] + H[j, 2] * e[2] - c
            s11 += a0 * a0
            s12 += a0 * a1
            s22 += a1 * a1
            s1r += a0 * rj
            s2r += a1 * rj
        if not s11 > 0.0:
            break
        # R = [[r11, r12], [0, r22]] of A = QR, Q^T r = (q1r, q2r), from the sums
        r11 = math.sqrt(s11)
        r12 = s12 / r11
        r22sq = s22 - r12 * r12
        q1r = s1r / r11
        if r22sq > (rcond * r11) ** 2:
            r22 = math.sqrt(r22sq)
            q2r = (s2r - r12 * q1r) / r22
            x1 = q2r / r22
            x0 = (q1r - r12 * x1) / r11
        else:
            x1 = 0.0
            x0 = q1r / r11
        d0, d1 = -x0, -x1
        e0 = e[0] + T[0, 0] * d0 + T[0, 1] * d1
        e1 = e[1] + T[1, 0] * d0 + T[1, 1] * d1
        e2 = e[2] + T[2, 0] * d0 + T[2, 1] * d1
        en = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        e[0], e[1], e[2] = e0 / en, e1 / en, e2 / en
        if math.sqrt(d0 * d0 + d1 * d1) < 1e-13:
            break
    return e


def _fit(H: np.ndarray, alpha: float | None, e_start: np.ndarray | None = None) -> ConeFit:
    if alpha is None:
        return direction_and_radius(H)
    if e_start is None:
        return nadir_from_horizon(H, alpha)
    e = _refine_local(H, e_start, math.cos(alpha))
    delta, kind = conic_type(e, alpha)
    return ConeFit(e_c=e, alpha=alpha, n=e, rhs=math.cos(alpha), discriminant=delta, conic=kind,
                   residual=angle_residual(H, e, alpha), m=H.shape[0], method="constrained")


def _alpha_sensitivity(H: np.ndarray, e: np.ndarray, alpha: float) -> np.ndarray:
    """d e / d alpha of the constrained fit (linearised normal equations in the tangent plane at
    e: x = (T^T N T)^-1 T^T H^T (c 1 - H e), c = cos(alpha), so de/dc = T (T^T N T)^-1 T^T H^T 1)."""
    T = tangent_basis(e)
    return _alpha_sensitivity_kernel(np.ascontiguousarray(H, dtype=float), T, math.sin(alpha))


@numba.njit(cache=True)
def _alpha_sensitivity_kernel(H, T, sin_alpha):  # pragma: no cover - numba
    """`_alpha_sensitivity`: A = H T, the 2x2 normal equations A^T A x = A^T 1 by Cramer's rule."""
    a00 = a01 = a11 = b0 = b1 = 0.0
    for j in range(H.shape[0]):
        x = H[j, 0] * T[0, 0] + H[j, 1] * T[1, 0] + H[j, 2] * T[2, 0]
        y = H[j, 0] * T[0, 1] + H[j, 1] * T[1, 1] + H[j, 2] * T[2, 1]
        a00 += x * x
        a01 += x * y
        a11 += y * y
        b0 += x
        b1 += y
    det = a00 * a11 - a01 * a01
    x0 = (a11 * b0 - a01 * b1) / det
    x1 = (a00 * b1 - a01 * b0) / det
    out = np.empty(3)
    for c in range(3):
        out[c] = (T[c, 0] * x0 + T[c, 1] * x1) * (-sin_alpha)
    return out


# -------------------------------------------------------------------------------------------------
# one target


@dataclass(frozen=True)
class _Consensus:
    """Direct-fit stand-in for `vision.ransac.RansacResult` (fit, inliers)."""

    fit: ConeFit
    inliers: np.ndarray


_RNG = threading.local()


def _candidate_rng(frame_seed: int, cand: Candidate) -> np.random.Generator:
    """RANSAC generator of one candidate, seeded by the frame's seed and the candidate itself
    (length, first pixel): its draws do not depend on which other candidates of the frame were
    scored before it (a change of the candidate order, or a candidate skipped by a cheaper test,
    leaves every other fit as it was).

    One PCG64 generator per thread, its 128-bit state set from a hash of those numbers (Python's
    tuple-of-int hash: the same in every process); seeding a new generator through numpy's
    SeedSequence costs ~10 us per candidate, this ~1 us."""
    g = getattr(_RNG, "generator", None)
    if g is None:
        g = _RNG.generator = np.random.Generator(np.random.PCG64(0))
    u0, v0 = cand.points[0].tolist()
    h = hash((frame_seed, cand.n_pixels, int(u0), int(v0))) & 0xFFFFFFFFFFFFFFFF
    g.bit_generator.state = {"bit_generator": "PCG64",
                             "state": {"state": (h * 0x9E3779B97F4A7C15F39CC0605CEDC835) & (2**128 - 1),
                                       "inc": 0xDA3E39CB94B95BDB},
                             "has_uint32": 0, "uinteger": 0}
    return g


def _gate_reachable(H: np.ndarray, predicted: np.ndarray, alpha: float | None, reach: float, need: int) -> bool:
    """Can a fit of these rays pass the gate? At least ``need`` rays (the fewest inliers of an
    accepted fit) must lie within ``reach`` [rad] of a cone of half-angle ``alpha`` about the unit
    direction ``predicted`` (Earth: | angle - alpha | <= reach), or within ``reach`` of ``predicted``
    itself (Sun/Moon, ``alpha`` None; their inliers lie within gate + alpha_max + threshold)."""
    return int(np.count_nonzero(within_cone(H, predicted, 0.0 if alpha is None else alpha, reach))) >= need


def _score_candidate(k: int, cand: Candidate, image, camera, mask, det, tc: TargetConfig,
                     model: LimbModel | None, frame_seed: int, predicted: np.ndarray | None = None) -> CandidateResult:
    res = CandidateResult(index=k, n_pixels=cand.n_pixels)
    if cand.n_pixels < tc.min_pixels:
        res.reason = f"{cand.n_pixels} pixels < min_pixels {tc.min_pixels}"
        return res
    idx = _subsample(cand.n_pixels, tc.score_rays)
    uv = cand.points[idx]
    rays_c = unproject(camera, uv)
    ok = np.isfinite(rays_c[:, 2])     # unproject: all three NaN beyond the lens's range
    n_ok = int(np.count_nonzero(ok))
    if n_ok < max(8, min(tc.min_pixels, idx.size) // 2):
        res.reason = "edge pixels outside the lens's valid range"
        return res
    if n_ok < ok.size:
        uv, rays_c = uv[ok], rays_c[ok]
    H = rays_c if model is None else model.to_fit(rays_c)
    min_inliers = max(3, int(math.ceil(tc.min_inlier_fraction * H.shape[0])))
    if predicted is not None:
        # gate pre-filter: an accepted fit lies within gate_deg of the prediction and has at
        # least min_inliers rays within the threshold of its cone (the direct fit: 95 %). Earth:
        # in the fit frame, +1 deg for its mapping (< 0.2 deg) and a mirrored refit's spread.
        # The threshold and the edge offset with the camera's largest pixel angle (before the
        # per-pixel angles: most candidates that fail here are not worth computing them for)
        p = predicted if model is None else model.to_fit(predicted)
        pa_max = _max_pixel_angle(camera)
        reach = (math.radians(tc.gate_deg + (tc.alpha_max_deg if model is None else 1.0))
                 + (tc.ransac_threshold_px + (0.0 if model is None else abs(tc.edge_offset_px))) * pa_max)
        if not _gate_reachable(H, p, None if model is None else model.alpha, reach, min_inliers):
            res.reason = (f"gate: fewer than {min_inliers} of {H.shape[0]} pixels can lie on a "
                          f"{'disc' if model is None else 'limb'} within gate_deg {tc.gate_deg:g} "
                          f"of the predicted direction")
            return res
    # curvature pre-filter: no triple of pixels spread along the edge lies on a circle of the
    # expected angular radius -> not this body's limb (saves the RANSAC on glare/cloud edges).
    # Earth: about the cone of the model, widened by the edge offset's largest angle
    rho = _triple_radii(H)
    if model is not None:
        ok_rho = np.abs(rho - model.alpha) <= (math.radians(tc.curvature_tol_deg)
                                               + abs(tc.edge_offset_px) * _max_pixel_angle(camera))
    else:
        ok_rho = rho <= math.radians(tc.alpha_max_deg + tc.curvature_tol_deg)
    if rho.size and not ok_rho.any():
        want = (f"{math.degrees(model.alpha):.1f}" if model is not None else f"<= {tc.alpha_max_deg:g}")
        res.reason = (f"curvature: circles through pixel triples have radii "
                      f"{math.degrees(rho.min()):.1f}-{math.degrees(rho.max()):.1f} deg, expected {want} "
                      f"+- {tc.curvature_tol_deg:g} deg")
        return res
    pa = _pixel_angle(camera, uv)
    thr = tc.ransac_threshold_px * pa
    alpha = None if model is None else model.alpha - tc.edge_offset_px * _median(pa)
    # shortcut: a clean edge is fitted directly; RANSAC (000 §2.3) only when that fit leaves
    # more than `direct_outlier_fraction` of the pixels outside the threshold
    rr = None
    try:
        f0 = _fit(H, alpha)
        in0 = within_cone(H, f0.e_c, f0.alpha, thr)
        if np.count_nonzero(in0) >= (1.0 - tc.direct_outlier_fraction) * in0.size:
            f1 = _fit(H[in0], alpha)
            rr = _Consensus(f1, within_cone(H, f1.e_c, f1.alpha, thr))
    except ValueError:
        rr = None
    try:
        if rr is None or rr.inliers.sum() < 3:
            rr = ransac_cone(H, _candidate_rng(frame_seed, cand), alpha=alpha, threshold=thr,
                             confidence=tc.ransac_confidence, max_hypotheses=tc.ransac_max_hypotheses,
                             n_preverify=4, batch=tc.ransac_max_hypotheses, min_inliers=min_inliers)
    except ValueError as exc:
        res.reason = f"no cone: {exc}"
        return res
    fit = rr.fit
    res.inliers = int(rr.inliers.sum())
    res.fit = fit
    res.residual = fit.residual
    if alpha is None and not (math.radians(tc.alpha_min_deg) <= fit.alpha <= math.radians(tc.alpha_max_deg)):
        res.reason = (f"apparent radius {math.degrees(fit.alpha):.3g} deg outside "
                      f"[{tc.alpha_min_deg:g}, {tc.alpha_max_deg:g}] deg")
        return res
    if alpha is None and predicted is not None:
        off = math.degrees(math.acos(max(-1.0, min(1.0, float(fit.e_c @ predicted)))))
        if off > tc.gate_deg:
            res.reason = f"{off:.1f} deg from the predicted direction > gate_deg {tc.gate_deg:g} (flare ghost?)"
            return res
    if alpha is None:
        why = _disc_check(image, camera, mask, det.threshold, fit.e_c, fit.alpha, tc.side_check_px)
        if why:
            res.reason = why
            return res
    # mirrored-nadir test (002): the body must be bright on its side of the edge
    inl = rr.inliers
    e_c = fit.e_c if model is None else model.to_camera(fit.e_c)
    alpha_c = fit.alpha if model is None else _median(angle_residuals(rays_c[inl], e_c, 0.0))
    side = _side_score(image, camera, mask, det.threshold, rays_c[inl], uv[inl], e_c, alpha_c,
                       tc.side_check_px, tc.side_check_rays)
    if not side >= tc.side_check_min and alpha is not None:
        alt = _fit(H[inl], alpha, mirrored_direction(fit.e_c, H[inl]))
        e_alt = model.to_camera(alt.e_c)
        side_alt = _side_score(image, camera, mask, det.threshold, rays_c[inl], uv[inl], e_alt, alpha_c,
                               tc.side_check_px, tc.side_check_rays)
        if side_alt >= tc.side_check_min and alt.residual <= tc.max_residual:
            fit, side, res.mirrored = alt, side_alt, True
            res.fit, res.residual = alt, alt.residual
    if not side >= tc.side_check_min:
        res.reason = (f"wrong side (002 mirrored nadir): {side:.2f} of the pixels beside the edge "
                      f"agree < {tc.side_check_min:g}")
        return res
    if alpha is not None and predicted is not None:
        # Earth gate: the geocentric nadir predicted by the prior (x_e, R_ec); a glare or cloud
        # edge that happens to fit a cone of the right radius points elsewhere
        e_cam = model.to_camera(fit.e_c)
        off = math.degrees(math.acos(max(-1.0, min(1.0, float(e_cam @ predicted)))))
        if off > tc.gate_deg:
            res.reason = (f"{off:.1f} deg from the predicted nadir > gate_deg {tc.gate_deg:g} "
                          f"(glare or cloud edge?)")
            return res
    if res.residual > tc.max_residual:
        res.reason = f"residual {res.residual:.3g} rad^2 > max_residual {tc.max_residual:.3g}"
        return res
    # 003 §3.3 sanity check: the implied conic must pass through the image
    if not _conic_passes_image(camera, fit.e_c, fit.alpha, model, H[inl]):
        res.reason = "the fitted conic does not pass through the image (003 §3.3)"
        return res
    return res


def _conic_passes_image(camera: FisheyeCamera, e_fit: np.ndarray, alpha: float, model: LimbModel | None,
                        H_inl: np.ndarray) -> bool:
    """003 §3.3 sanity check: does the cone (e_fit, alpha) of the fit frame project into the image?

    First the one cone ray nearest the mean inlier ray (the usual case: the inliers lie on the
    conic, inside the image; one projection), else 90 rays around the whole cone."""
    e = np.asarray(e_fit, dtype=float)
    r = H_inl.sum(axis=0) if H_inl.shape[0] else e
    t = r - (r @ e) * e
    nt = _norm3(t)
    if nt > 1e-12:
        p = math.cos(alpha) * e + (math.sin(alpha) / nt) * t
        if model is not None and model.kind != "sphere":
            p = model.M_inv @ p
        u, v = project(camera, p[None, :])[0].tolist()   # NaN (beyond the lens's range) fails
        if -0.5 <= u <= camera.width - 0.5 and -0.5 <= v <= camera.height - 0.5:
            return True
    return bool(np.any(_in_image(camera, conic_polyline(camera, e, alpha, 90, model))))


def tilt_corrected_attitude(R_ec: np.ndarray, e_c: np.ndarray, x_e: np.ndarray) -> np.ndarray:
    """The prior attitude camera -> e turned by the smallest rotation that maps the measured nadir
    ``e_c`` (camera frame) onto the geocentric nadir -x_e/|x_e| (003 eq. (39)).

    The limb's Sun-elevation test and height model (`vision.limb`) need the tangent points in e;
    with a free-inertial attitude prior a few degrees off, the Sun elevation there is off by as
    much, which the steep twilight part of the height model turns into kilometres (a 2 deg
    elevation error near the terminator: ~3 km, ~0.1 deg of nadir). The frame's own horizon fixes
    the two tilt angles of that error to the accuracy of the first fit (~0.1-0.5 deg); the rotation
    about the nadir is left as the prior has it (it moves the tangent points along the limb, which
    changes their Sun elevation by about sin(angle nadir to limb) times the error).
    """
    R = np.asarray(R_ec, dtype=float)
    a0, a1, a2 = (R @ np.asarray(e_c, dtype=float)).tolist()
    b0, b1, b2 = (-np.asarray(x_e, dtype=float)).tolist()
    na, nb = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2), math.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    a0, a1, a2, b0, b1, b2 = a0 / na, a1 / na, a2 / na, b0 / nb, b1 / nb, b2 / nb
    # Rodrigues' rotation a -> b about k = a x b / |a x b| (plain floats: numpy's small-vector
    # calls cost ~50 us here)
    k0, k1, k2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    s = math.sqrt(k0 * k0 + k1 * k1 + k2 * k2)
    c = a0 * b0 + a1 * b1 + a2 * b2
    if s < 1e-15:
        return R
    k0, k1, k2 = k0 / s, k1 / s, k2 / s
    d = 1.0 - c                        # I + s K + (1 - c) K^2 = c I + s K + (1 - c) k k^T
    rot = np.array([[c + d * k0 * k0, d * k0 * k1 - s * k2, d * k0 * k2 + s * k1],
                    [d * k0 * k1 + s * k2, c + d * k1 * k1, d * k1 * k2 - s * k0],
                    [d * k0 * k2 - s * k1, d * k1 * k2 + s * k0, c + d * k2 * k2]])
    return rot @ R


#: angle [rad] a limb ray is turned towards the body to find the Sun elevation's change down its
#: profile (~2 km of tangent height from a few hundred km up: the change is linear over it)
_PROFILE_STEP_RAD = 1e-3
#: the profile model runs on every this-many-th point along the edge, its correction to eq. (5)
#: interpolated between them (it varies smoothly along the limb; eq. (5) stays per point)
_PROFILE_STRIDE = 8


def _profile_correction(rays_e, h_t, mu, nadir_e, x_e, sun_e, dh_eq5, tc: TargetConfig, min_drop):
    """`vision.limb.profile_height_shift` minus eq. (5) (``dh_eq5``) for limb points in edge order:
    the Sun elevation's change down each profile, dmu/dh from the tangent point of the ray turned
    towards the body by `_PROFILE_STEP_RAD`; computed on every `_PROFILE_STRIDE`-th point and the
    last, linearly interpolated along the edge between them (0 where no profile model exists:
    a profile in the Earth's shadow)."""
    n = mu.size
    sub = np.arange(0, n, _PROFILE_STRIDE)
    if sub[-1] != n - 1:
        sub = np.append(sub, n - 1)
    turned = turn_towards(rays_e[sub], nadir_e, _PROFILE_STEP_RAD)
    h_b, mu_b = tangent_height_sun(turned, x_e, sun_e)
    corr = profile_height_shift(mu[sub], (mu_b - mu[sub]) / (h_b - h_t[sub]), tc.limb_fraction,
                                tc.limb_scale_height_m, tc.limb_height_m, min_drop) - dh_eq5[sub]
    fin = np.isfinite(corr)
    if not fin.any():
        return np.zeros(n)
    return np.interp(np.arange(n), sub[fin], corr[fin])


def _limb_refit(image, camera, tc: TargetConfig, limb, uv, rays_c, pa, e_c, e_start_fit, J=None):
    """Fraction-of-peak limb edge (`vision.limb`) on the winner's inlier pixels and the refit
    with its height; None when too few limb points are usable (the caller keeps the threshold
    edge). Returns (model, fit, uv, rays, J, inliers, sigma_d, used_fraction, mean_shift).

    With ``limb_sun_path`` each usable point's crossing height is predicted from the Sun
    elevation at its tangent point (`vision.limb.fraction_height_shift`, eq. (5) of `vision.limb`)
    and its ray is turned towards the body by ``alpha(d + dh) - alpha(d)``
    (`LimbModel.cone_angle_change`), so
    that all points sit at the overhead-Sun height ``limb_height_m`` of the fit (one cone angle);
    the covariance term is then ``sigma_d^2 = limb_height_sigma_m^2 + (limb_sun_path_sigma *
    mean dh)^2`` (the model's measured error grows with the shift, docs/vision.md)."""
    model_l, R_ec, x_e, sun_e = limb
    lc = LimbEdgeConfig(fraction=tc.limb_fraction, channel=tc.limb_channel)
    R_t = tilt_corrected_attitude(R_ec, e_c, x_e)
    slope = phase_slope(rays_c, e_c, pa, R_t.T @ sun_e, tc.limb_aerosol_weight, tc.limb_aerosol_g)
    uvn, rn, ok, Jn = limb_edge_points(image, camera, uv, rays_c, e_c, pa, lc, jacobian=True, phase_slope=slope)
    el = None
    twilight = False
    if ok.any():
        keep, dh, el, twilight = _sun_path_shifts(rn[ok], R_t, e_c, x_e, sun_e, tc, lc)
        ok[ok] = keep
        dh_sun = dh
    n_ok = int(ok.sum())
    m = uv.shape[0]
    used = n_ok / max(m, 1)
    calibrate = (tc.limb_calibrate_below > 0 and used < tc.limb_calibrate_below
                 and n_ok >= tc.limb_calibrate_min_points and J is not None)
    if n_ok < max(20, tc.limb_min_used * m):
        # too few usable profiles (a clipped limb maximum): heights fitted on the flanks, else
        # the threshold edge calibrated on the usable ones, else the threshold edge itself
        if tc.limb_flank_profiles > 0 and J is not None:
            fr = _flank_refit(image, camera, tc, lc, model_l, uv, rays_c, J, pa, e_c, R_t, x_e, sun_e, used)
            if fr is not None:
                # again with the attitude tilted onto this better nadir: the Sun elevations at
                # the tangent points shape the profiles (twilight), and the first fit's nadir
                # (threshold edge) is off by tenths of a degree
                R_t2 = tilt_corrected_attitude(R_ec, model_l.to_camera(fr[1].e_c), x_e)
                fr = _flank_refit(image, camera, tc, lc, model_l, uv, rays_c, J, pa, e_c, R_t2, x_e, sun_e, used) or fr
                return fr
        if not calibrate:
            return None
    if not (tc.limb_sun_path and n_ok):
        dh = np.zeros(n_ok)
    twi = 0.0
    if tc.limb_sun_path and n_ok and len(tc.limb_twilight_el_deg):
        kn = np.radians(np.asarray(tc.limb_twilight_el_deg, dtype=float))
        dh = dh + np.interp(el, kn, np.asarray(tc.limb_twilight_dh_m, dtype=float), left=0.0, right=0.0)
        twi = float(np.mean(el < kn[-1]))
    if calibrate:
        return _calibrated_threshold_refit(tc, model_l, uv, rays_c, J, pa, e_c, rn[ok], ok, dh, used)
    J2 = Jn[ok]
    thr = tc.limb_refit_threshold_px * pa[ok]
    rays2 = turn_towards(rn[ok], e_c, model_l.cone_angle_change(dh))
    r = _refit_turned(model_l, rays2, e_c, thr)
    if r is not None and twilight:
        # twilight: the shifts again with the attitude tilted onto this first limb fit's nadir (a
        # Sun elevation a tenth of a degree off moves the predicted heights by ~0.15 km there, and
        # the threshold edge's nadir that tilted R_t is off by tenths of a degree)
        R_t2 = tilt_corrected_attitude(R_ec, model_l.to_camera(r[0].e_c), x_e)
        dh2 = dh + (_sun_path_shifts(rn[ok], R_t2, e_c, x_e, sun_e, tc, lc, keep_all=True)[1] - dh_sun)
        rays3 = turn_towards(rn[ok], e_c, model_l.cone_angle_change(dh2))
        r2 = _refit_turned(model_l, rays3, e_c, thr)
        if r2 is not None:
            r, rays2, dh = r2, rays3, dh2
    if r is None:
        return None
    fit, inl = r
    shift = float(np.mean(dh[inl]))
    sigma_d = math.sqrt(tc.limb_height_sigma_m**2 + (tc.limb_sun_path_sigma * shift)**2
                        + (twi * tc.limb_twilight_sigma_m)**2)
    return model_l, fit, uvn[ok], rays2, J2, inl, sigma_d, used, shift, "limb", math.nan


def _sun_path_shifts(rays_c, R_t, e_c, x_e, sun_e, tc: TargetConfig, lc: LimbEdgeConfig, keep_all: bool = False):
    """Crossing-height shifts of limb rays (camera frame) with the attitude R_t (camera -> e):
    ``(keep, dh, el, twilight)``: keep the points with the Sun above ``limb_min_sun_elev_deg`` at
    their tangent points (all with ``keep_all``), dh [m] their shifts (eq. (5) of `vision.limb`,
    with the Sun elevation's change down the profile below ``limb_profile_below_deg``; zeros
    without ``limb_sun_path``), el [rad] their Sun elevations, twilight: some of them that low."""
    rays_e = rays_c @ R_t.T
    h_t, mu = tangent_height_sun(rays_e, x_e, sun_e)
    keep = np.ones(mu.size, bool) if keep_all else mu >= math.sin(math.radians(tc.limb_min_sun_elev_deg))
    dh = np.zeros(mu.size)
    low = keep & (mu < math.sin(math.radians(tc.limb_profile_below_deg)))
    if tc.limb_sun_path:
        dh = fraction_height_shift(mu, tc.limb_fraction, tc.limb_scale_height_m)
        if low.any():
            dh[low] += _profile_correction(rays_e[low], h_t[low], mu[low], R_t @ e_c, x_e, sun_e, dh[low],
                                           tc, lc.min_drop)
    return keep, dh[keep], np.arcsin(mu[keep]), bool(tc.limb_sun_path and low.any())


def _calibrated_threshold_refit(tc: TargetConfig, model_l: LimbModel, uv, rays_c, J, pa, e_c, rays_limb,
                                ok, dh, used):
    """Threshold edge calibrated with the usable limb profiles of the same frame
    (``TargetConfig.limb_calibrate_below``): ``d_i`` = the height whose cone is ``a_i`` wider than
    the cone of ``h_i`` (`LimbModel.height_change`) at the usable points
    (h_i = ``limb_height_m`` + Sun-path shift: the known height of the fraction-of-peak crossing;
    a_i the angle from it out to the threshold pixel), ``d_thr = median(d_i)``, and every
    threshold ray turned towards the body by ``alpha(d_thr) - alpha(limb_height_m)`` so that the
    whole arc fits the cone of ``limb_height_m`` (`LimbModel.cone_angle_change`, as for the Sun-path
    shift). None when the refit keeps fewer than 20 inliers."""
    a = np.arccos(np.clip(np.sum(rays_c[ok] * rays_limb, axis=1), -1.0, 1.0))
    # sign: positive when the limb crossing lies towards the body from the threshold pixel
    a = np.where(rays_limb @ e_c >= rays_c[ok] @ e_c, a, -a)
    d_i = tc.limb_height_m + model_l.height_change(model_l.cone_angle_change(dh) + a)
    d_thr = _median(d_i)
    mad = 1.4826 * _median(np.abs(d_i - d_thr))
    rays2 = turn_towards(rays_c, e_c, model_l.cone_angle_change(d_thr - tc.limb_height_m))
    r = _refit_turned(model_l, rays2, e_c, tc.limb_refit_threshold_px * pa)
    if r is None:
        return None
    sigma_d = math.sqrt(tc.limb_calibrate_sigma_m**2 + mad**2 / d_i.size)
    return (model_l, r[0], uv, rays2, J, r[1], sigma_d, used, float(np.mean(dh)) if dh.size else 0.0,
            "calibrated", d_thr)


def _refit_turned(model_l: LimbModel, rays2, e_c, thr):
    """The cone of ``model_l`` (d = ``limb_height_m``) fitted to rays already turned to that
    height, from e_c, with the inliers re-selected twice (``thr`` [rad] per ray); (fit, inliers)
    or None below 20 inliers."""
    H2 = model_l.to_fit(rays2)
    e0 = model_l.M @ e_c
    fit = _fit(H2, model_l.alpha, e0 / np.linalg.norm(e0))
    fit, inl, ok = _reselect_inliers(H2, fit, np.ones(rays2.shape[0], bool), thr,
                                     lambda Hi, f: _fit(Hi, model_l.alpha, f.e_c), 2, 20)
    return (fit, inl) if ok else None


def _reselect_inliers(H, fit, inliers, thr, refit, n_iter: int, min_inliers: int):
    """Local optimisation of a cone fit: the rays within ``thr`` [rad] of its cone, the fit
    ``refit(H[sel], fit)`` on them, repeated until the selection repeats (the fit on it is the one
    at hand) or ``n_iter`` times. Returns (fit, inliers, ok); ok is False when a selection had
    fewer than ``min_inliers`` rays (fit and inliers are then the last ones before it)."""
    for _ in range(n_iter):
        new = within_cone(H, fit.e_c, fit.alpha, thr)
        if new.sum() < min_inliers:
            return fit, inliers, False
        if (new == inliers).all():
            break
        inliers = new
        fit = refit(H[inliers], fit)
    return fit, inliers, True


def _flank_refit(image, camera, tc: TargetConfig, lc: LimbEdgeConfig, model_l: LimbModel, uv, rays_c, J, pa,
                 e_c, R_t, x_e, sun_e, used):
    """Threshold edge with each pixel's height fitted on the unsaturated flank of its limb profile
    (`vision.limb.flank_heights`; the limb maximum clipped by the exposure): on
    ``limb_flank_profiles`` profiles spread along the edge, the heights more than 3 robust
    sigmas (at least 1 km) from their median dropped, the rest interpolated along the edge; each
    threshold ray turned towards the body by ``alpha(h_i) - alpha(limb_height_m)`` and the cone of
    ``limb_height_m`` fitted. None with fewer than ``limb_flank_min_profiles`` fitted profiles or
    20 inliers. Covariance term ``limb_flank_sigma_m`` with the heights' spread over sqrt(n)."""
    m = uv.shape[0]
    idx = _subsample(m, tc.limb_flank_profiles)
    h = flank_heights(image, camera, uv[idx], rays_c[idx], e_c, pa[idx], R_t, x_e, sun_e, lc,
                      height_m=tc.limb_height_m, scale_height_m=tc.limb_scale_height_m,
                      aerosol_weight=tc.limb_aerosol_weight, aerosol_g=tc.limb_aerosol_g)
    fin = np.isfinite(h)
    if fin.sum() < tc.limb_flank_min_profiles:
        return None
    med = _median(h[fin])
    mad = 1.4826 * _median(np.abs(h[fin] - med))
    fin &= np.abs(h - med) <= max(3.0 * mad, 1000.0)
    if fin.sum() < tc.limb_flank_min_profiles:
        return None
    h_all = np.interp(np.arange(m), idx[fin], h[fin])
    rays2 = turn_towards(rays_c, e_c, model_l.cone_angle_change(h_all - tc.limb_height_m))
    r = _refit_turned(model_l, rays2, e_c, tc.limb_refit_threshold_px * pa)
    if r is None:
        return None
    sigma_d = math.sqrt(tc.limb_flank_sigma_m**2 + mad**2 / fin.sum())
    return model_l, r[0], uv, rays2, J, r[1], sigma_d, used, 0.0, "flank", float(np.mean(h[fin]))


def _process_target(name, image, camera, mask, tc: TargetConfig, model, frame_seed: int, timings,
                    baseline: bool, predicted: np.ndarray | None = None, limb=None,
                    hists: dict | None = None) -> TargetResult:
    t0 = time.perf_counter()
    hist = None
    if hists is not None:
        # one brightness histogram per frame and sample step, shared by the targets' detections
        step = tc.detection.binarize.sample_step
        hist = hists.get(step)
        if hist is None:
            hist = hists[step] = brightness_histogram(as_frame(image, (camera.height, camera.width)), step)
    rows = None
    if name != "earth" and predicted is not None:
        rows = gate_search_rows(camera, predicted, math.radians(tc.gate_deg + tc.alpha_max_deg), tc.detection.search)
    det = detect(image, tc.detection, mask, expected_shape=(camera.height, camera.width), hist=hist, rows=rows)
    t1 = time.perf_counter()
    timings[f"{name}.detect"] = t1 - t0
    out = TargetResult(name, det)
    if not det.candidates:
        out.reason = f"no candidate: {det.reason}"
        return out
    is_earth = name == "earth"
    cands = sorted(range(len(det.candidates)), key=lambda i: -det.candidates[i].n_pixels)[:tc.max_candidates]
    results = []
    accepted_len = 0
    for i in cands:
        n_i = det.candidates[i].n_pixels
        if accepted_len and n_i < tc.compete_fraction * accepted_len:
            break   # much shorter than an accepted edge: not the same body's limb (docstring)
        r_i = _score_candidate(i, det.candidates[i], image, camera, mask, det, tc,
                               model if is_earth else None, frame_seed, predicted)
        results.append(r_i)
        if not r_i.reason:
            accepted_len = max(accepted_len, n_i)
    out.candidates = results
    t2 = time.perf_counter()
    timings[f"{name}.score"] = t2 - t1
    good = [r for r in results if not r.reason]
    if not good:
        best = min(results, key=lambda r: r.residual)
        out.reason = (f"no accepted candidate among {len(det.candidates)} "
                      f"(best: candidate {best.index}, {best.reason})")
        return out
    win = min(good, key=lambda r: r.residual)
    cand = det.candidates[win.index]
    out.winner = win.index
    # full processing of the winner: <= fit_rays pixels spread along the whole edge, Jacobian,
    # inliers, refit, covariance with the correlation length scaled to the step
    step = max(1.0, cand.n_pixels / tc.fit_rays)
    sel = _subsample(cand.n_pixels, tc.fit_rays)
    uv = cand.points[sel]
    rays_c, J = unproject_jacobian(camera, uv)
    ok = np.isfinite(rays_c[:, 2])     # all three NaN beyond the lens's range
    if not ok.all():
        uv, rays_c, J = uv[ok], rays_c[ok], J[ok]
    pa = _pixel_angle(camera, uv)
    H = model.to_fit(rays_c) if is_earth else rays_c
    fit = win.fit
    thr = tc.ransac_threshold_px * pa
    inl = within_cone(H, fit.e_c, fit.alpha, thr)
    min_used = min(tc.min_pixels, int(math.ceil(tc.min_pixels / step)))
    if inl.sum() < max(min_used, 3):
        out.reason = f"candidate {win.index}: {int(inl.sum())} inliers on the full edge (min_pixels {tc.min_pixels})"
        return out
    if is_earth:
        fit = _fit(H[inl], fit.alpha, fit.e_c if win.mirrored else None)
    else:
        # iterated to a stable inlier set: the result does not depend on the RANSAC's draw as
        # much as a single re-selection (docs/vision.md, seventh session)
        fit, inl, _ = _reselect_inliers(H, direction_and_radius(H[inl]), inl, thr,
                                        lambda Hi, f: direction_and_radius(Hi), 10, max(min_used, 3))
    if fit.residual > tc.max_residual:
        out.reason = (f"candidate {win.index}: residual {fit.residual:.3g} rad^2 on the full edge > "
                      f"max_residual {tc.max_residual:.3g}")
        return out
    t3 = time.perf_counter()
    timings[f"{name}.refit"] = t3 - t2
    L_eff = max(1.0, tc.L_px / step)
    sigma_d = tc.atmosphere_sigma_m
    if is_earth and limb is not None and tc.limb_fraction > 0:
        lr = _limb_refit(image, camera, tc, limb, uv[inl], rays_c[inl], pa[inl], model.to_camera(fit.e_c), fit.e_c,
                         J[inl])
        t_limb = time.perf_counter()
        timings["earth.limb"] = t_limb - t3
        t3 = t_limb
        if lr is not None:
            model, fit, uv, rays_c, J, inl, sigma_d, out.limb_used, out.limb_shift_m, out.limb_path, out.limb_d_m = lr
            H = model.to_fit(rays_c)
            out.limb_edge = True
    if is_earth:
        e_c = model.to_camera(fit.e_c)
        cov = direction_covariance(rays_c[inl], J[inl], e_c, tc.R_px2, L_eff, method="constrained")
        P = cov.P_c
        if sigma_d > 0:
            # d e / d d = d e / d alpha * d alpha / d d (module docstring), mapped into the camera
            g_fit = _alpha_sensitivity(H[inl], fit.e_c, fit.alpha) * model.alpha_rate
            g = model.to_camera(fit.e_c + 1e-3 * g_fit) - e_c
            g /= 1e-3
            P = P + sigma_d**2 * np.outer(g, g)
        out.cone_alpha = _median(angle_residuals(rays_c[inl], e_c, 0.0))
        conic = conic_type(e_c, out.cone_alpha)[1]
    else:
        e_c = fit.e_c
        cov = direction_covariance(rays_c[inl], J[inl], fit.n, tc.R_px2, L_eff, method="linear")
        P = cov.P_c
        conic = fit.conic
    P = 0.5 * (P + P.T)
    lam = float(largest_eigenvalue(P))
    timings[f"{name}.covariance"] = time.perf_counter() - t3
    n_inl = int(round(int(inl.sum()) * cand.n_pixels / max(uv.shape[0], 1)))
    out.points = uv
    out.inlier_mask = inl
    out.record = VectorRecord(0, 0, name, e_c, P, lam * np.eye(3), float(fit.residual), int(cand.n_pixels),
                              min(n_inl, cand.n_pixels), conic, float(fit.alpha),
                              model.kind if is_earth else "")
    if baseline:
        from vision.conic import conic_nadir_fit
        tb = time.perf_counter()
        try:
            allr = unproject(camera, cand.points)
            allr = allr[np.all(np.isfinite(allr), axis=1)]
            e_b, _ = conic_nadir_fit(allr)
            out.baseline_e_c = e_b
        except (ValueError, np.linalg.LinAlgError) as exc:
            out.baseline_reason = str(exc)
        timings[f"{name}.baseline_conic_fit"] = time.perf_counter() - tb
    return out


def process_frame(image, camera: FisheyeCamera, config: VisionConfig, *, height_m: float | None = None,
                  mask: PayloadMask | None = None, prior: FramePrior | None = None,
                  rng: np.random.Generator | None = None, t_ns: int = 0, camera_id: int = 0,
                  baseline: bool = False) -> FrameResult:
    """Earth-nadir, Sun and Moon vectors of one decoded frame (see the module docstring).

    Parameters
    ----------
    image : (H, W, 3) or (H, W) uint8 frame as decoded (distorted); its size must be the camera's.
    camera : intrinsics (`vision.camera.FisheyeCamera`).
    config : `VisionConfig`.
    height_m : height above the ellipsoid [m] (the height prior of 003 eq. (5)); needed for the
        Earth unless ``prior.x_e`` is given.
    mask : payload mask of the camera, or None.
    prior : `FramePrior`; with x_e and R_ec the ellipsoid model is used (`vision.oblate`), else the
        spherical model with the local radius of curvature.
    rng : seeded generator for RANSAC (default: seed 0, reproducible).
    t_ns, camera_id : copied into the records.
    baseline : also run the general conic fit (`vision.conic.conic_nadir_fit`) on the Earth winner.

    Returns
    -------
    FrameResult; ``reasons[target]`` says why a target has no vector. Bad input (not a uint8
    frame, wrong size, bad mask) raises ValueError.
    """
    from nav import earth as _earth

    if not isinstance(camera, FisheyeCamera):
        raise ValueError(f"camera: {type(camera).__name__}, expected vision.camera.FisheyeCamera")
    if not isinstance(image, np.ndarray):
        raise ValueError(f"image: {type(image).__name__}, expected a decoded uint8 numpy array "
                         f"(decode bytes with cv2.imdecode first)")
    rng = np.random.default_rng(0) if rng is None else rng
    # one draw per frame: each candidate's RANSAC generator is derived from it (`_candidate_rng`)
    frame_seed = int(rng.integers(2**63))
    timings: dict[str, float] = {}
    reasons: dict[str, str] = {}
    targets: dict[str, TargetResult] = {}
    records: list[VectorRecord] = []
    model = None
    model_kind = ""
    if config.earth.enabled:
        d = config.earth.atmosphere_m
        if prior is not None and prior.x_e is not None and prior.R_ec is not None:
            model = ellipsoid_model(prior.x_e, prior.R_ec, d)
        else:
            if height_m is None:
                raise ValueError("height_m: required for the Earth (003 eq. (5)) without a position prior")
            if not (math.isfinite(height_m) and height_m > 0):
                raise ValueError(f"height_m = {height_m}; expected a finite height above the ellipsoid [m]")
            if config.sphere_radius_m is not None:
                r = config.sphere_radius_m
            elif prior is not None and prior.lat is not None:
                from vision.oblate import gaussian_radius
                r = gaussian_radius(prior.lat)
            else:
                r = _earth.R_MEAN
            model = sphere_model(height_m, r, d)
        model_kind = model.kind
    hists: dict = {}
    limb = None
    if (config.earth.enabled and config.earth.limb_fraction > 0 and prior is not None and prior.x_e is not None
            and prior.R_ec is not None and prior.sun_c is not None and image.ndim == 3):
        R_ec = np.asarray(prior.R_ec, dtype=float)
        limb = (ellipsoid_model(prior.x_e, R_ec, config.earth.limb_height_m), R_ec,
                np.asarray(prior.x_e, dtype=float), R_ec @ np.asarray(prior.sun_c, dtype=float))
    for name in TARGETS:
        tc = config.target(name)
        if not tc.enabled:
            continue
        pred = None
        if name == "earth" and prior is not None and prior.x_e is not None and prior.R_ec is not None:
            x = np.asarray(prior.x_e, dtype=float)
            pred = np.asarray(prior.R_ec, dtype=float).T @ (-x / np.linalg.norm(x))
        if prior is not None and name != "earth":
            pred = prior.sun_c if name == "sun" else prior.moon_c
            if pred is not None:
                pred = np.asarray(pred, dtype=float)
                if pred.shape != (3,) or not np.all(np.isfinite(pred)) or np.linalg.norm(pred) == 0:
                    raise ValueError(f"prior.{name}_c = {pred!r}; expected a finite 3-vector")
                pred = pred / np.linalg.norm(pred)
        tr = _process_target(name, image, camera, mask, tc, model, frame_seed, timings,
                             baseline and name == "earth", pred,
                             limb if name == "earth" else None, hists)
        targets[name] = tr
        if tr.record is not None:
            r = tr.record
            r = VectorRecord(int(t_ns), int(camera_id), r.target, r.e_c, r.P_c, r.P_overbound, r.residual,
                             r.pixel_count, r.inlier_count, r.conic_type, r.alpha, r.model)
            tr.record = r
            records.append(r)
        else:
            reasons[name] = tr.reason
    timings["total"] = sum(v for k, v in timings.items() if not k.endswith("baseline_conic_fit"))
    return FrameResult(records, reasons, targets, timings, model_kind)
