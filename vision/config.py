"""Configuration of the vision front end (`vision.frontend.process_frame`): one `TargetConfig` per
target, each with one options dataclass per processing stage, and the per-frame `FramePrior`.

The dataclasses hold the defaults, and only they: ``VisionConfig()`` is the configuration for the
ATEK-like cameras (the stage options' own defaults, and per target the values that differ from
them). The one camera-dependent value, the spacing of the Sun/Moon search lines
(``2 f tan(alpha_min)``, 003 §5), is computed from the camera's focal length by
`resolve_search_lines` (`default_config` and `process_frame` call it). Configuration files hold
overrides only (`scenarios.config.vision`).

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
mean(angle^2) < 5e-8 rad^2 (0.22 mrad RMS, 0.25 px); the Sun/Moon default of 1e-6 relaxes it for
JPEG and bloom. The defaults start from these figures and are checked on rendered frames
(docs/vision.md).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from vision.binarize import BinarizeConfig
from vision.borders import SearchConfig, search_line_spacing
from vision.candidates import DetectionConfig

__all__ = ["TARGETS", "ScoringOptions", "RansacOptions", "SideCheckOptions", "FitOptions", "FlankOptions",
           "CalibrationOptions", "LimbOptions", "PhaseOptions", "EdgeHeightOptions", "OccultationOptions",
           "TargetConfig", "VisionConfig",
           "FramePrior",
           "default_config", "resolve_search_lines"]

TARGETS = ("earth", "sun", "moon")


class _Checks:
    """Validation helpers: ``ValueError("Class.field = value; expected ...")``."""

    def _bad(self, name, expected):
        raise ValueError(f"{type(self).__name__}.{name} = {getattr(self, name)!r}; expected {expected}")

    def _ints(self, names, lo=1):
        for n in names:
            v = getattr(self, n)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= lo):
                self._bad(n, f"an integer >= {lo}")

    def _finite(self, names, lo=0.0, strict=False):
        for n in names:
            v = getattr(self, n)
            if not (math.isfinite(v) and (v > lo if strict else v >= lo)):
                self._bad(n, f"a finite number {'>' if strict else '>='} {lo:g}")

    def _fractions(self, names):
        for n in names:
            if not 0.0 <= getattr(self, n) <= 1.0:
                self._bad(n, "a fraction in [0, 1]")

    def _within(self, name, lo, hi, expected):
        v = getattr(self, name)
        if not (math.isfinite(v) and lo <= v <= hi):
            self._bad(name, expected)


@dataclass(frozen=True)
class ScoringOptions(_Checks):
    """Cheap scoring of the detected candidates (module docstring of `vision.frontend`, step 2).

    Attributes
    ----------
    max_candidates : candidates scored, the longest first.
    score_rays : pixels per candidate used for the cheap fit (spread along the edge), >= 8.
    direct_outlier_fraction : a candidate is first fitted directly (all scored pixels); when at
        most this fraction [0..1] is outside the RANSAC threshold the direct fit (refitted on its
        inliers) stands and RANSAC is skipped (most horizons and Suns: the cost of RANSAC is only
        paid on disturbed edges).
    curvature_tol_deg : pre-filter before any fit [deg]: at least one circle through three pixels
        spread along the edge must have an angular radius within this of alpha (Earth) or below
        ``alpha_max_deg`` plus this (Sun/Moon); the Sun's glare halo or a cloud bank does not
        (1 px of edge noise moves the radius of a third of a 1900 px horizon by ~2 deg).
    compete_fraction : once a candidate is accepted, candidates shorter than this fraction [0..1]
        of it are not scored (one Earth, one Sun: a much shorter edge cannot be the limb of the
        body whose limb was already found; it saves the RANSAC runs on cloud and glare edges).
    """

    max_candidates: int = 6
    score_rays: int = 160
    direct_outlier_fraction: float = 0.05
    curvature_tol_deg: float = 10.0
    compete_fraction: float = 0.5

    def __post_init__(self):
        self._ints(("max_candidates", "score_rays"))
        if self.score_rays < 8:
            self._bad("score_rays", ">= 8 pixels")
        self._finite(("curvature_tol_deg",), strict=True)
        self._fractions(("direct_outlier_fraction", "compete_fraction"))


@dataclass(frozen=True)
class RansacOptions(_Checks):
    """RANSAC cone fit of a disturbed candidate (`vision.ransac.ransac_cone`, 000 §2.3).

    Attributes
    ----------
    threshold_px : inlier distance to the cone [px] (converted per ray to an angle with the
        pixel angle, `vision.ransac.pixel_angle`); also the inlier test of the direct fit.
    max_hypotheses : most hypotheses drawn (one batch).
    confidence : adaptive stop, probability (0..1) of having drawn an all-inlier sample.
    min_inlier_fraction : fewest inliers as a fraction [0..1] of the scored pixels.
    """

    threshold_px: float = 2.0
    max_hypotheses: int = 200
    confidence: float = 0.999
    min_inlier_fraction: float = 0.6

    def __post_init__(self):
        self._ints(("max_hypotheses",))
        self._finite(("threshold_px",), strict=True)
        if not 0.0 < self.confidence < 1.0:
            self._bad("confidence", "in (0, 1)")
        self._fractions(("min_inlier_fraction",))


@dataclass(frozen=True)
class SideCheckOptions(_Checks):
    """Mirrored-nadir test (002 §3, `vision.probes.side_score`) and the Sun/Moon disc test.

    Attributes
    ----------
    step_px : step [px] from the edge to the probed pixels (also the outer ring of the disc test).
    min_agree : fraction [0..1] of the probes that must be on their expected side.
    rays : edge pixels probed.
    band_depth_deg : Earth, when the mirrored cone fits the arc as well (a short, nearly straight
        arc): how far [deg] towards the nadir the Earth's side is followed (`vision.probes.
        inward_kept`). A lit band of air over a dark (night or twilight) Earth is bright on one
        side of its lower edge and dark on the other, like a day limb, with the nadir mirrored
        into the sky; beyond the band the "Earth" falls back to the sky's darkness.
    band_level : the sky's darkness for that test, as a fraction of the edge's threshold (a day
        Earth, ocean included, stays above it in a frame exposed for the Earth).
    band_min_kept : least fraction of the followed probes that stay above ``band_level``.
    """

    step_px: float = 3.0
    min_agree: float = 0.8
    rays: int = 24
    band_depth_deg: float = 3.0
    band_level: float = 0.25
    band_min_kept: float = 0.5

    def __post_init__(self):
        self._ints(("rays",))
        self._finite(("step_px",), strict=True)
        self._fractions(("min_agree", "band_level", "band_min_kept"))
        self._within("band_depth_deg", 0.0, 30.0, "an angle in [0, 30] deg")


@dataclass(frozen=True)
class FitOptions(_Checks):
    """Final fit and covariance of the winning candidate (003 eqs. (33)-(38)).

    Attributes
    ----------
    rays : most pixels of the winning edge used (spread along it; the correlation length is
        scaled with the step, so the covariance of the correlated noise (003 eq. (34)) is that of
        the full edge).
    R_px2 : pixel-noise variance [px^2] (003 eq. (36): Earth 1 px^2; eq. (38): Sun 9 px^2;
        calibrated on rendered frames, docs/vision.md).
    L_px : correlation length of the pixel noise [px] (003 eqs. (35)-(36)), >= 1.
    """

    rays: int = 512
    R_px2: float = 1.0
    L_px: float = 300.0

    def __post_init__(self):
        self._ints(("rays",))
        self._finite(("R_px2",))
        if not self.L_px >= 1.0:
            self._bad("L_px", ">= 1 px (003 eq. (35))")


@dataclass(frozen=True)
class FlankOptions(_Checks):
    """Heights fitted on the unsaturated flanks of clipped limb profiles (`vision.limb.flank_heights`).

    When fewer than ``LimbOptions.min_used`` of the profiles are usable (the auto exposure clips
    the red limb maximum), the height of the edge pixel is fitted on the unsaturated flank of
    ``profiles`` profiles spread along the edge (eq. (4)'s shape of `vision.limb` with the
    exposure and black level free), interpolated along it, and the threshold edge fitted with
    those heights.

    Attributes
    ----------
    profiles : profiles fitted, 0..512; 0 = off.
    min_profiles : fewest fitted profiles for a result, >= 3.
    sigma_m : covariance term [m] (the heights' spread over sqrt(n) is added); measured per-frame
        mean height errors 0.2-0.6 km on clipped frames (docs/vision.md).
    """

    profiles: int = 16
    min_profiles: int = 8
    sigma_m: float = 600.0

    def __post_init__(self):
        if not (isinstance(self.profiles, int) and 0 <= self.profiles <= 512):
            self._bad("profiles", "an integer in [0, 512] (0 = off)")
        self._ints(("min_profiles",), lo=3)
        self._finite(("sigma_m",))


@dataclass(frozen=True)
class CalibrationOptions(_Checks):
    """Threshold edge calibrated on the usable limb profiles of the same frame.

    When fewer than ``below`` of the winner's inliers give a usable limb profile (a clipped limb
    maximum, a twilight limb: a short arc), but at least ``min_points`` do, at each usable point
    the threshold pixel lies ``a_i`` [rad] outside its fraction-of-peak crossing, whose height is
    known (``LimbOptions.height_m`` + Sun-path shift), so the threshold edge's effective thickness
    there is ``d_i = h_i + a_i / (d alpha / d d)``; their median ``d_thr`` replaces
    ``TargetConfig.atmosphere_m`` and the *whole* threshold arc is fitted with it (a long arc
    instead of the short usable one). Above 10 % usable profiles the short limb arc is better on
    average than the calibrated threshold arc, whose height varies 1-4 km along the limb.

    Attributes
    ----------
    below : usable fraction [0..1] under which the calibration runs; 0 = off.
    min_points : fewest usable profiles, >= 3.
    sigma_m : covariance term [m]: the spread of ``d_thr`` against the true mean height of the
        threshold edge (it lies 2-7 km low on rendered frames, docs/vision.md); the spread of the
        d_i over sqrt(n) is added.
    """

    below: float = 0.1
    min_points: int = 20
    sigma_m: float = 3000.0

    def __post_init__(self):
        self._fractions(("below",))
        self._ints(("min_points",), lo=3)
        self._finite(("sigma_m",))


@dataclass(frozen=True)
class LimbOptions(_Checks):
    """Fraction-of-peak limb edge (`vision.limb`; Earth only, needs a prior with x_e, R_ec, sun_c).

    The winner's edge pixels are moved to where the limb profile crosses ``fraction`` of its own
    maximum (exposure-invariant), at a tangent height fixed by the atmosphere (tau, H), and fitted
    with d = ``height_m`` (uncertainty ``height_sigma_m``) instead of the threshold edge with
    ``TargetConfig.atmosphere_m``.

    Attributes
    ----------
    fraction : fraction (0..1) of the profile's maximum; 0 = off (threshold edge).
    channel : colour channel of the decoded frame for the profile (BGR: 2 = red, the channel least
        often clipped on the blue limb; -1 = the mean).
    height_m : tangent height [m] of the crossing with the Sun overhead at the tangent point (the
        Sun-path shift is added per point); measured 18.2-18.5 km after the shift for 4..30 deg
        elevation on the benchmark frames.
    height_sigma_m : its frame-to-frame and along-the-limb spread [m] (covariance term).
    min_sun_elev_deg : limb points with the Sun lower than this [deg] at the tangent point are not
        used (below ~-3 deg the limb's maximum is the Earth's shadow edge).
    min_used : the fraction-of-peak edge is used only when at least this fraction [0..1] of the
        winner's inliers give a usable profile (not clipped, Sun high enough); else the flank fit,
        the calibration or the threshold edge with ``atmosphere_m``.
    sun_path : predict each point's crossing height from the Sun elevation at its tangent point
        (`vision.limb.fraction_height_shift`, eq. (5) of `vision.limb`: the sunlight's own path
        through the lower atmosphere lifts the limb maximum) and turn its ray by the shift, so one
        cone angle (``height_m``) fits all.
    scale_height_m : H of that model [m], 1..20 km (the standard atmosphere's 7-8.5 km).
    profile_below_deg : points with the Sun lower than this [deg] at the tangent point take the
        Sun elevation's change down their profile into account
        (`vision.limb.profile_height_shift`: kilometres near the terminator, 30-90 m at 8-15 deg
        and less above, where eq. (5) alone is used).
    sun_path_sigma : model error as a fraction of the frame's mean shift (covariance term).
    twilight_el_deg, twilight_dh_m : optional measured correction [m] added to the model at these
        Sun elevations [deg] (increasing; linear interpolation, 0 outside); empty: none.
    twilight_sigma_m : the per-frame spread [m] left after that correction, weighted in the
        covariance by the share of points below its last knot.
    refit_threshold_px : inlier threshold [px] of the refits with the limb heights (limb edge,
        flank, calibrated threshold edge): their rays lie on one cone to the heights' accuracy
        (~0.1 km, a fraction of a pixel), tighter than ``RansacOptions.threshold_px``, which must
        admit the threshold edge's 1-4 km of height variation along the limb.
    aerosol_weight, aerosol_g : the limb's scattering phase function (Rayleigh plus this weight
        [0..1] of a Henyey-Greenstein aerosol lobe of asymmetry g [0..1),
        `vision.limb.phase_function`): its change along each profile is divided out
        (`vision.limb.phase_slope`), which matters near the Sun; weight 0 = Rayleigh only.
    flank_width_max : a profile is used only when its flank, from the crossing down to 0.8 of the
        peak, spans at most this many times the tangent height eq. (4) gives
        (`vision.limb.flank_rise_height`): wider, its maximum is not the limb's but a surface
        brighter than the limb's flat top (a high Sun, resolved by a narrow field of view), and
        its crossing lies kilometres low. Tested where the Sun at the tangent point is above
        `vision.limb.resolved_sun_sine` (12.4 deg with the defaults: the limb's own drop above
        the surface is then less than the detector's 15 %). Measured ratios: 0.8-1.15 on rendered
        limbs (5-95 %), 1.0-2.4 on profiles peaking on sunlit clouds (median 2.1). 0: no test
        (neither this nor ``edge_width_max``).
    edge_width_max : the limb edge is not used (the threshold edge is) when the median of that
        ratio over its usable profiles, at any Sun elevation, exceeds this: no limb has a flank
        that wide (a scale height above 10.4 km at 1.3; the Earth's shadow and thinner air make it
        narrower), the profiles follow a brightness gradient on the twilight ground and their
        crossings lie on the disc. Measured frame medians: 0.72-1.14 on rendered limbs (standard
        and 6 km scale-height profiles, Sun -1.3 to +22 deg), at most 1.09 on the vision bench;
        1.48-2.47 where the limb edge on the ground missed its 3 sigma, 3.1-5.1 on ground edges
        under a limb separated by the Earth's shadow (`vision.frontend._outer_candidate`). 0: no test.
    flank : `FlankOptions`; calibrate : `CalibrationOptions` (clipped limb maxima).
    """

    fraction: float = 0.5
    channel: int = 2
    height_m: float = 18300.0
    height_sigma_m: float = 150.0
    min_sun_elev_deg: float = -3.0
    min_used: float = 0.1
    sun_path: bool = True
    scale_height_m: float = 8000.0
    profile_below_deg: float = 8.0
    sun_path_sigma: float = 0.05
    twilight_el_deg: tuple = ()
    twilight_dh_m: tuple = ()
    twilight_sigma_m: float = 1100.0
    refit_threshold_px: float = 2.0
    aerosol_weight: float = 0.25
    aerosol_g: float = 0.75
    flank_width_max: float = 1.3
    edge_width_max: float = 1.3
    flank: FlankOptions = FlankOptions()
    calibrate: CalibrationOptions = CalibrationOptions()

    def __post_init__(self):
        if not 0.0 <= self.fraction < 1.0:
            self._bad("fraction", "0 (off) or a fraction in (0, 1)")
        if self.channel not in (-1, 0, 1, 2):
            self._bad("channel", "-1 (mean) or a channel index 0, 1, 2 of the decoded (BGR) frame")
        if not (math.isfinite(self.height_m) and 0.0 <= self.height_m < 200e3):
            self._bad("height_m", "0 <= h < 200 km")
        self._finite(("height_sigma_m", "sun_path_sigma", "twilight_sigma_m"))
        self._within("min_sun_elev_deg", -10.0, 90.0, "an elevation in [-10, 90] deg (below ~-3 deg the "
                     "limb's maximum is the Earth's shadow edge)")
        self._fractions(("min_used",))
        if not isinstance(self.sun_path, bool):
            self._bad("sun_path", "true or false")
        self._within("scale_height_m", 1e3, 20e3, "a scale height of 1..20 km (Earth: 7-8.5 km)")
        self._within("profile_below_deg", -10.0, 90.0, "an elevation in [-10, 90] deg")
        kn, dv = tuple(self.twilight_el_deg), tuple(self.twilight_dh_m)
        if (len(kn) != len(dv) or len(kn) == 1
                or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in kn + dv)
                or any(b <= a for a, b in zip(kn[:-1], kn[1:])) or any(abs(v) > 30e3 for v in dv)):
            self._bad("twilight_el_deg", "with twilight_dh_m: equally long lists (>= 2 or empty) of "
                      "increasing elevations [deg] and height corrections |dh| <= 30 km [m]")
        self._finite(("refit_threshold_px",), strict=True)
        self._within("aerosol_weight", 0.0, 1.0, "a weight in [0, 1]")
        if not (math.isfinite(self.aerosol_g) and 0.0 <= self.aerosol_g < 1.0):
            self._bad("aerosol_g", "an asymmetry parameter in [0, 1)")
        if not (self.flank_width_max == 0.0 or 1.0 <= self.flank_width_max <= 10.0):
            self._bad("flank_width_max", "0 (no test) or a ratio in [1, 10]")
        if not (self.edge_width_max == 0.0 or 1.0 <= self.edge_width_max <= 10.0):
            self._bad("edge_width_max", "0 (no test) or a ratio in [1, 10]")


@dataclass(frozen=True)
class PhaseOptions(_Checks):
    """The Moon as cameras see it (`vision.moon`; Moon only): a phase-aware fit of the lit limb,
    search spacing and size gates from the expected apparent radius, brightness thresholds relative
    to the candidate.

    Attributes
    ----------
    aware : use `vision.moon.process_moon` (lit limb only, relative thresholds); false: the Moon is
        processed as the Sun (a full disc above a fixed threshold).
    radius_deg : expected apparent radius [deg] when the prior gives none (`FramePrior.moon_alpha`):
        the Moon's radius over its mean distance, 1737.4 km / 384 400 km.
    radius_sigma : 1-sigma of the expected radius as a fraction of it, without the prior's radius
        (the distance varies 356-406 thousand km: +-6.5 %, about 3.5 % rms); the limb is fitted
        with ``radius_deg`` and this term goes into the covariance.
    free_radius : without the prior's radius, fit the radius instead (003 §5's free-alpha fit, as
        for the Sun): unbiased on gibbous Moons, but pulled by the fading horns of crescents.
    radius_tol : accepted fitted radius (free-radius fit) and size gates, as a fraction of the
        expected radius (the distance varies by +-6 %; the lens's scale across the image).
    seed_above : seed threshold of the search, brightness above the frame's dark level (its
        ``seed_percentiles``) [0-255]: a dim half Moon peaks at ~57/255.
    seed_percentiles : percentiles of the frame brightness taken as its dark level, tried in
        turn until a candidate is accepted: the first the sky's, as long as it covers that share of
        the frame (the median is the Earth's when the Earth fills half of it, and would put the
        seed above a dim Moon); the next for a Moon in the glow above the Earth's limb, which joins
        the glow at the sky's level.
    edge_fraction : the edge threshold of each candidate, as a fraction of its peak above its local
        background (0..1): the lit limb of a Lommel-Seeliger Moon is a step from the background to
        its brightest value, crossed at its middle by 0.5.
    min_contrast : least peak above the local background [0-255] of an accepted candidate.
    limb_margin_deg : edge points whose outward normal (image) or whose position about the fitted
        centre (sphere) is within this angle of perpendicular to the Sun's projected direction are
        left out (the cusps, where the limb meets the terminator).
    spacing_radii : search-line spacing in expected radii at the coarsest pixel scale of the
        camera: a Moon lit at the fraction k is 2 k radii thick along the Sun's projected
        direction (its dim horns may fall below the seed threshold), so 0.4 finds Moons from 20 %
        lit in any orientation.
    edge_sigma_px : 1-sigma radial bias [px] of the threshold edge against the true limb
        (covariance term of the known-radius fit, whose direction moves with its radius).
    full_sigma_px : 1-sigma [px] per axis added to a disc fitted all round without a known lit
        side (no Sun direction, no terminator found): a nearly full Moon's terminator may run up
        to a pixel inside half of its outline, moving the centre by up to half a pixel.
    inner_step_px : without the Sun's direction, the lit side is found from the brightness this
        many pixels inside each edge point (`vision.moon.lit_direction`): 1 px stays inside a
        Moon 8 px across.
    min_lit_strength : least strength (0..1) of that brightness direction for it to give the lit
        side; below it (a disc about as bright inside all round: a nearly full Moon) the lit side
        comes from the geometry of the RANSAC inliers.
    """

    aware: bool = True
    radius_deg: float = 0.259
    radius_sigma: float = 0.035
    free_radius: bool = False
    radius_tol: float = 0.25
    seed_above: float = 12.0
    seed_percentiles: tuple = (5.0, 50.0, 90.0)
    edge_fraction: float = 0.5
    min_contrast: float = 20.0
    limb_margin_deg: float = 15.0
    spacing_radii: float = 0.4
    edge_sigma_px: float = 0.25
    full_sigma_px: float = 0.3
    inner_step_px: float = 1.0
    min_lit_strength: float = 0.3

    def __post_init__(self):
        if not isinstance(self.aware, bool):
            self._bad("aware", "true or false")
        self._within("radius_deg", 1e-3, 10.0, "an apparent radius in (0, 10] deg")
        self._within("radius_sigma", 0.0, 0.5, "a fraction in [0, 0.5]")
        if not isinstance(self.free_radius, bool):
            self._bad("free_radius", "true or false")
        self._within("radius_tol", 0.01, 0.9, "a fraction in [0.01, 0.9]")
        self._within("seed_above", 1.0, 254.0, "a brightness step in [1, 254]")
        q = tuple(self.seed_percentiles)
        if (not q or not all(isinstance(v, (int, float)) and 0.0 <= v <= 100.0 for v in q)
                or any(b <= a for a, b in zip(q[:-1], q[1:]))):
            self._bad("seed_percentiles", "a non-empty increasing list of percentiles in [0, 100]")
        self._within("edge_fraction", 0.05, 0.95, "a fraction in [0.05, 0.95]")
        self._finite(("min_contrast", "edge_sigma_px", "full_sigma_px"))
        self._within("limb_margin_deg", 0.0, 60.0, "an angle in [0, 60] deg")
        self._within("spacing_radii", 0.1, 4.0, "a multiple in [0.1, 4] of the expected radius")
        self._within("inner_step_px", 0.5, 10.0, "a distance in [0.5, 10] px")
        self._within("min_lit_strength", 0.0, 1.0, "a strength in [0, 1]")


@dataclass(frozen=True)
class EdgeHeightOptions(_Checks):
    """The Earth's edge height fitted with the nadir (`vision.edge_height`; Earth only).

    The height has a prior: N(``TargetConfig.atmosphere_m``, ``atmosphere_sigma_m^2``) for the
    threshold edge, N(``LimbOptions.height_m``, ``max(limb term, limb_prior_sigma_m)^2``) for the
    limb edge. It is a prior, not a measurement: its sigma must hold the edges of cameras the
    defaults were not tuned on. A sigma of 0 fixes the height (no fit, no covariance term).

    Attributes
    ----------
    estimate : fit the edge height with the direction (the cone half-angle free, as 003 §5 fits
        the Sun's radius), the prior as a pseudo-measurement; false: the height is the prior mean
        and its sigma enters the covariance through the tilt (``sigma^2 g g^T``).
    start_m : height [m] of the threshold edge's cone with which the candidates are scored
        (RANSAC, `vision.scoring`) and from which the joint fit starts, when the height is
        estimated; NaN: ``atmosphere_m``. The Earth default is 45 km, where the threshold edge of
        the renderer's limb sits, on whose frames the scoring is tuned; the fit then moves to the
        height the arc and the prior N(``atmosphere_m``, ``atmosphere_sigma_m^2``) give.
    limb_prior_sigma_m : 1-sigma [m] of the limb edge's height prior on an unseen camera and
        atmosphere (the limb term of `LimbOptions` is the model's spread where the model holds).
    constrained_ratio : the arc is said to constrain the height (``TargetResult.edge_from_arc``)
        when the posterior variance is below this fraction (0..1] of the prior's.
    along_sigma_m, along_L_px : the edge's height variation along the limb (the Sun's elevation
        and the exposure change along it: the threshold edge's height varies by 1-4 km over an
        arc on rendered frames) as a Gauss-Markov sequence of this sigma [m] and correlation
        length [px] along the edge; it bends the arc like a change of height, so it bounds what
        the arc can say about the height (`vision.edge_height`); on both edges (the limb edge's
        Sun-path model holds only where its profile is the assumed one).
    limb_gate : the limb edge is kept only when the arc's own (prior-free) height estimate is
        within this many sigmas (the estimate's and the limb model's combined) of the limb
        model's height ``LimbOptions.height_m``: an arc that disagrees says the limb profile is not
        the one the model assumes (another camera, another atmosphere), and the threshold edge
        with its wide prior is used instead. 0: always kept.
    cross_check_ratio : where the arc's own height sigma exceeds this many limb-prior sigmas (a
        narrow field of view: ~85 km on a 25 deg pinhole at 500 km; the ATEK fisheye's arcs stay
        below 3 x 20 km, some not below 20 km) the gate above cannot tell, and the limb edge is kept only when its nadir
        agrees with the threshold edge's within ``limb_gate`` sigmas of their difference
        (covariance the sum of theirs); else the threshold edge is used. 0: no cross-check.
    filter_state : the navigation filter estimates the edge height (its ``h_e`` state, one per
        camera, describing the limb edge when the limb model is on, else the threshold edge):
        the fit is the default one, and the records of that edge give the direction given the
        height (``P_c`` without the height's part: it is the filter's, not to be counted twice),
        ``VectorRecord.dedge_c`` the sensitivity ``d e_c / d h_e`` [1/m] at ``edge_height_m``,
        and the arc's own height ``edge_data_m`` with its sigma
        (`vision.edge_height.conditional_on_height`); records of the other edge are as without it.
    state_edge : the edge the filter's state describes with ``filter_state``: "limb" (the limb edge
        where the limb model is on, its "limb" and "flank" paths; else the threshold edge) or
        "threshold" (the threshold edge on every frame, the limb model not used for the Earth's
        vector): for a camera whose arc cannot check the limb model's height (a narrow field of
        view, see ``cross_check_ratio``), where the limb model's per-pixel heights err from frame
        to frame and along the arc in ways no edge height describes, and the threshold edge is one
        brightness level whose height the flight learns; its records give no arc's own height
        (its error repeats from frame to frame on such a camera, docs/vision.md). Without
        ``filter_state`` it has no effect.
    offset_gate : the flight's limb edge height offset (`vision.limb_offset`: one per camera, the
        weighted mean over its limb-edge frames of the arc's own height minus the prior's mean)
        tightens the limb edge's prior to N(mean, offset sigma^2 + limb term^2) when
        |offset| is within this many of its sigmas (the limb model holds on this camera, up to
        the offset); else the wide prior stays. 0: never tightened.
    arc_gate : the wrong-edge test (`vision.edge_check`): when the rays the winner's fit leaves
        out form a second horizon arc, the two arcs' nadirs (each fitted with the threshold edge's
        height prior) must agree within this many sigmas of their difference, else the frame has
        no Earth vector when the fit's own arc also lies in the shadow (``arc_shadow_el_deg``):
        near the terminator the dim ground below the horizon falls through the threshold first,
        and the edge follows it instead of the limb. Needs the prior's position, attitude and Sun
        direction (without them: no test). 0: no test.
    arc_shadow_el_deg : the Sun's elevation [deg] at the fitted arc's tangent points below which a
        disagreeing second arc rejects the fit; where the Sun is up the ground is lit to the
        horizon and the disagreeing arc is the wrong one.
    arc_min_fraction : the left-out rays are tested only when at least this fraction of the
        edge's rays are a second arc's inliers (a few scattered outliers are not an arc).
    offset_min_frames : limb-edge frames with an arc's own height a camera needs for its offset.
    offset_resolution_m : the offset tightens the prior only when ``offset_gate`` of its sigmas
        are at most this [m]: the flight must be able to see a disagreement of this size between
        its arcs and the limb model (at 0.04 deg of nadir per km on partial fisheye arcs, 3 km is
        0.12 deg). A few frames give sigmas of 4-8 km, within which mismatched atmospheres of
        10-20 km pass the gate; a long flight's hundreds of frames give well under 1 km.
    """

    estimate: bool = True
    start_m: float = math.nan
    limb_prior_sigma_m: float = 20e3
    constrained_ratio: float = 0.5
    along_sigma_m: float = 3000.0
    along_L_px: float = 600.0
    limb_gate: float = 3.0
    cross_check_ratio: float = 3.0
    filter_state: bool = False
    state_edge: str = "limb"
    offset_gate: float = 3.0
    offset_min_frames: int = 5
    offset_resolution_m: float = 3000.0
    arc_gate: float = 3.0
    arc_min_fraction: float = 0.15
    arc_shadow_el_deg: float = 0.0

    def __post_init__(self):
        self._finite(("offset_gate", "offset_resolution_m", "arc_gate"))
        self._within("arc_min_fraction", 0.01, 0.5, "a fraction in [0.01, 0.5]")
        self._within("arc_shadow_el_deg", -90.0, 90.0, "an elevation in [-90, 90] deg")
        self._ints(("offset_min_frames",), lo=2)
        if not isinstance(self.estimate, bool):
            self._bad("estimate", "true or false")
        if not isinstance(self.filter_state, bool):
            self._bad("filter_state", "true or false")
        if self.state_edge not in ("limb", "threshold"):
            self._bad("state_edge", '"limb" or "threshold"')
        self._finite(("limb_prior_sigma_m", "along_sigma_m", "limb_gate", "cross_check_ratio"))
        if not (math.isnan(self.start_m) or 0.0 <= self.start_m < 200e3):
            self._bad("start_m", "NaN (atmosphere_m) or 0 <= h < 200 km")
        if not self.along_L_px >= 1.0:
            self._bad("along_L_px", ">= 1 px")
        if not 0.0 < self.constrained_ratio <= 1.0:
            self._bad("constrained_ratio", "a fraction in (0, 1]")


@dataclass(frozen=True)
class OccultationOptions(_Checks):
    """A Sun or Moon disc against the Earth found in the same frame (`vision.occultation`; Sun and
    Moon only, when the frame has an Earth vector).

    Attributes
    ----------
    enabled : reject a disc whose lowest point is not above the Earth's edge, and add the
        refraction term to the covariance of one seen through the air above it.
    min_clearance_deg : least angle [deg] from the Earth's edge up to the disc's lowest point,
        along the great circle through the Earth's nadir and the disc's centre: 0 rejects a disc
        that reaches into the edge (partly hidden, the bright limb joins its outline) or lies
        inside the Earth's disc (a cloud or a glint: the Sun and the Moon are never in front of
        the Earth).
    edge_sigmas : the refraction term takes the Earth's edge at its height less this many of its
        sigmas, not below the ground: the lower the edge, the denser the air the light crosses.
    """

    enabled: bool = True
    min_clearance_deg: float = 0.0
    edge_sigmas: float = 3.0

    def __post_init__(self):
        if not isinstance(self.enabled, bool):
            self._bad("enabled", "true or false")
        self._within("min_clearance_deg", -5.0, 5.0, "an angle in [-5, 5] deg")
        self._within("edge_sigmas", 0.0, 10.0, "a number of sigmas in [0, 10]")


@dataclass(frozen=True)
class TargetConfig(_Checks):
    """Processing of one target (Earth, Sun or Moon): the body, what is accepted, and the options
    of each stage.

    Attributes
    ----------
    enabled : process this target.
    detection : threshold, brightness gate, edge search, minimum candidate length
        (`vision.candidates.DetectionConfig`).
    min_pixels : fewest inlier pixels for a vector.
    max_residual : acceptance, mean squared angular distance of the inliers from the cone [rad^2]
        (003 §7.3 re-derived, module docstring).
    alpha_min_deg, alpha_max_deg : accepted apparent radius of the Sun/Moon [deg] (glare included).
    gate_deg : largest angle [deg] of an accepted vector from the predicted direction when the
        prior gives one: Sun/Moon `FramePrior.sun_c`, ``moon_c``; Earth the geocentric nadir
        ``R_ec.T @ (-x_e / |x_e|)`` when the prior has x_e and R_ec (a glare edge that fits a cone
        of the Earth's radius elsewhere is rejected). Covers attitude-prior and mounting errors of
        a few degrees.
    atmosphere_m : effective atmosphere thickness d [m] (003 eq. (5)), 0..200 km; Earth only.
        The apparent horizon is where the limb's brightness crosses the threshold, at a tangent
        height d (of the edge pixels' straight lines of sight above the ellipsoid) that varies
        with exposure and illumination (003 §4, 004 §3.4.3): the mean of the edge height's prior
        (`EdgeHeightOptions`; the fixed height when it is not estimated).
    atmosphere_sigma_m : its 1-sigma uncertainty [m]: the sigma of the edge height's prior
        (`EdgeHeightOptions`); Earth only.
    edge_offset_px : distance [px] from the centres of the followed (white) border pixels to the
        brightness edge, which lies between them and their dark neighbours: half a pixel. The
        Earth cone is shrunk by this angle (without it the nadir is biased by ~0.03 deg on
        rendered frames); the Sun/Moon radius absorbs it.
    scoring, ransac, side_check, fit, limb, phase, edge, occultation : the stages' options
        (`ScoringOptions`, `RansacOptions`, `SideCheckOptions`, `FitOptions`, `LimbOptions`,
        `PhaseOptions`, `EdgeHeightOptions`, `OccultationOptions`; limb and edge: Earth only;
        phase: Moon only; occultation: Sun and Moon).
    """

    enabled: bool = True
    detection: DetectionConfig = DetectionConfig()
    min_pixels: int = 50
    max_residual: float = 4e-6
    alpha_min_deg: float = 0.2
    alpha_max_deg: float = 5.0
    gate_deg: float = 10.0
    atmosphere_m: float = 0.0
    atmosphere_sigma_m: float = 0.0
    edge_offset_px: float = 0.5
    scoring: ScoringOptions = ScoringOptions()
    ransac: RansacOptions = RansacOptions()
    side_check: SideCheckOptions = SideCheckOptions()
    fit: FitOptions = FitOptions()
    limb: LimbOptions = LimbOptions()
    phase: PhaseOptions = PhaseOptions()
    edge: EdgeHeightOptions = EdgeHeightOptions()
    occultation: OccultationOptions = OccultationOptions()

    def __post_init__(self):
        self._ints(("min_pixels",))
        self._finite(("max_residual", "alpha_max_deg", "gate_deg"), strict=True)
        self._finite(("atmosphere_sigma_m", "alpha_min_deg"))
        if not self.alpha_min_deg < self.alpha_max_deg < 90.0:
            self._bad("alpha_max_deg", "alpha_min_deg < alpha_max_deg < 90")
        if not (math.isfinite(self.atmosphere_m) and 0.0 <= self.atmosphere_m < 200e3):
            self._bad("atmosphere_m", "0 <= d < 200 km")


@dataclass(frozen=True)
class VisionConfig:
    """Front-end configuration: one `TargetConfig` per target, the Earth-radius fallback.

    The defaults are those of the ATEK-like cameras: Earth with the threshold edge's height prior
    10 +- 22 km (real orbital photographs' 0-10 km; the renderer's 45 and 60 km inside 2.3
    sigma; candidates scored at 45 km) and the fraction-of-peak limb edge; the Sun saturated (threshold
    250, 003 §5) and searched on lines spaced for 0.5 deg (`resolve_search_lines`); the Moon off
    (rarely in view in the ATEK flight; enable per scenario or ``--moon``), processed phase-aware
    (`PhaseOptions`, `vision.moon`) with the pixel noise of its threshold edge (R = 0.1 px^2,
    L = 4 px: quantisation of a hard step, calibrated on rendered Moons, docs/vision.md).

    ``sphere_radius_m``: radius [m] of the substitute sphere when there is no position prior (003
    §2.8; None = ``nav.earth.R_MEAN``, or the Gaussian radius at ``FramePrior.lat``).
    """

    earth: TargetConfig = TargetConfig(
        detection=DetectionConfig(BinarizeConfig(threshold=60.0, gate_min=2.0, gate_max=235.0), SearchConfig(), 40),
        min_pixels=100, atmosphere_m=10e3, atmosphere_sigma_m=22e3,
        scoring=ScoringOptions(score_rays=100),
        ransac=RansacOptions(threshold_px=4.0, max_hypotheses=100, min_inlier_fraction=0.5),
        fit=FitOptions(R_px2=0.2), edge=EdgeHeightOptions(start_m=45e3))
    sun: TargetConfig = TargetConfig(
        detection=DetectionConfig(BinarizeConfig(threshold=250.0), SearchConfig(alpha_min_deg=0.5), 12),
        min_pixels=12, max_residual=1e-6, alpha_max_deg=4.0,
        scoring=ScoringOptions(score_rays=100),
        ransac=RansacOptions(max_hypotheses=100, min_inlier_fraction=0.5),
        fit=FitOptions(R_px2=0.16))
    moon: TargetConfig = TargetConfig(
        enabled=False,
        detection=DetectionConfig(BinarizeConfig(threshold=120.0), SearchConfig(alpha_min_deg=0.5), 12),
        min_pixels=12, max_residual=1e-6, alpha_max_deg=1.0,
        ransac=RansacOptions(min_inlier_fraction=0.5),
        fit=FitOptions(R_px2=0.1, L_px=4.0))
    sphere_radius_m: float | None = None

    def target(self, name: str) -> TargetConfig:
        if name not in TARGETS:
            raise ValueError(f"target {name!r}; expected one of {TARGETS}")
        return getattr(self, name)


def resolve_search_lines(config: VisionConfig, focal_px: float) -> VisionConfig:
    """``config`` with the search-line spacing of every target whose `SearchConfig` gives
    ``alpha_min_deg`` but no ``line_spacing_px``: ``2 f tan(alpha_min)`` (003 §5,
    `vision.borders.search_line_spacing`) with the focal length ``focal_px`` [px] (the smaller of
    fx, fy). The same object when nothing is to be resolved."""
    kw = {}
    for name in TARGETS:
        tc = getattr(config, name)
        s = tc.detection.search
        if s.line_spacing_px is None and s.alpha_min_deg is not None:
            spacing = search_line_spacing(focal_px, math.radians(s.alpha_min_deg))
            det = dataclasses.replace(tc.detection, search=dataclasses.replace(s, line_spacing_px=spacing))
            kw[name] = dataclasses.replace(tc, detection=det)
    return dataclasses.replace(config, **kw) if kw else config


def default_config(focal_px: float = 1110.0) -> VisionConfig:
    """The default `VisionConfig` with its search lines spaced for a camera of focal length
    ``focal_px`` [px] (`resolve_search_lines`; 1110 px: the ATEK lens)."""
    return resolve_search_lines(VisionConfig(), focal_px)


@dataclass(frozen=True)
class FramePrior:
    """Prior knowledge for one frame: position ``x_e`` [m] (GPS/INS) and camera attitude ``R_ec``
    (camera -> e) enable the ellipsoid model (`vision.oblate.ellipsoid_model`); ``lat`` [rad]
    alone selects the Gaussian radius of curvature for the spherical model. ``sun_c``, ``moon_c``:
    predicted unit directions in the camera frame (ephemeris + attitude prior, e.g.
    ``R_ec.T @ nav.ephemeris.sun_direction_e(t, x_e)``): Sun/Moon candidates further than
    ``TargetConfig.gate_deg`` from them are rejected (lens-flare ghosts, glints; 004 §3.4); with
    x_e and R_ec, Earth candidates further than the Earth's ``gate_deg`` from the predicted
    geocentric nadir ``R_ec.T @ (-x_e / |x_e|)`` are rejected too (glare edges). ``moon_alpha``:
    the Moon's apparent radius [rad], ``asin(R_moon / distance)`` from the ephemeris: the Moon's
    limb is then fitted with that radius (`vision.moon`), else with a free one."""

    x_e: np.ndarray | None = None
    R_ec: np.ndarray | None = None
    lat: float | None = None
    sun_c: np.ndarray | None = None
    moon_c: np.ndarray | None = None
    moon_alpha: float | None = None
