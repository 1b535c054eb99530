"""Results of the vision front end (`vision.frontend.process_frame`): the direction-vector
records, and per target and candidate what happened (for logs, annotation and tests)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vision.candidates import Detection
from vision.nadir import ConeFit

__all__ = ["VectorRecord", "CandidateResult", "TargetResult", "FrameResult"]


@dataclass(frozen=True)
class VectorRecord:
    """One direction vector (the DirectionVector log message, docs/log-format.md).

    e_c : unit vector in the camera frame (Earth: geocentric nadir -x_e/|x_e| with the ellipsoid
        model, 003 eq. (39); the substitute-sphere centre with the spherical model).
    P_c : full 3x3 covariance (003 eq. (33) + atmosphere term); P_overbound : eq. (37).
    residual : mean squared angular residual of the inliers [rad^2].
    pixel_count : pixels of the winning edge candidate; inlier_count : its inliers (counted on the
        up to ``fit.rays`` pixels used for the final fit, scaled to the whole edge).
    conic_type : "ellipse" / "hyperbola" of the fitted cone in the image (003 Table 1).
    alpha : cone half-angle [rad] (Earth: in the fit frame of the limb model; Sun/Moon: estimated).
    model : "ellipsoid", "sphere" (Earth) or "" (Sun/Moon).
    edge_height_m, edge_height_sigma_m : Earth: the effective height [m] of the edge the fit used
        (`TargetResult.limb_path`: the threshold edge, or the limb edge at the Sun overhead) and
        its 1-sigma, fitted with the direction where the arc constrains it, else the prior's
        (`vision.edge_height`); NaN for the Sun/Moon.
    dedge_c : Earth with ``EdgeHeightOptions.filter_state``, on the edge the filter's state
        describes: (3,) ``d e_c / d h_e`` [1/m], how the vector moves when the true edge is higher
        than ``edge_height_m`` (the filter's edge height column); None otherwise. ``e_c`` and ``P_c`` are then the direction given the
        height ``edge_height_m`` and its covariance (`vision.edge_height.conditional_on_height`).
    edge_data_m, edge_data_sigma_m : Earth with ``EdgeHeightOptions.filter_state``: the arc's own
        (prior-free) edge height [m] and its 1-sigma [m] (inf where the arc cannot separate the
        height from the tilt, or where the state describes the threshold edge:
        ``EdgeHeightOptions.state_edge``), the filter's measurement of the height; NaN otherwise.
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
    edge_height_m: float = math.nan
    edge_height_sigma_m: float = math.nan
    dedge_c: np.ndarray | None = None
    edge_data_m: float = math.nan
    edge_data_sigma_m: float = math.nan

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
    edge_cov_c: np.ndarray | None = None  # Earth: (3,) covariance of e_c with the edge height [rad m]
    edge_from_arc: bool = False  # Earth: the arc constrains the edge height (vision.edge_height)
    edge_dedge_c: np.ndarray | None = None  # Earth, filter_state: (3,) d e_c / d h_e [1/m] (VectorRecord.dedge_c)
    edge_data_m: float = math.nan  # Earth: the arc's own (prior-free) edge height [m] (vision.edge_height)
    edge_data_sigma_m: float = math.inf  # Earth: its 1-sigma [m]
    limb_prior_m: float = math.nan  # Earth, limb edge: mean [m] of the height prior the fit used
    limb_prior_sigma_m: float = math.nan  # Earth, limb edge: that prior's 1-sigma [m]
    limb_sigma_m: float = math.nan  # Earth, limb edge: the limb model's own height term [m] (vision.limb)
    limb_rejected_m: float = math.nan  # Earth: the limb edge's own height [m] when it disagreed with
    # the limb model (EdgeHeightOptions.limb_gate) and the threshold edge was used instead
    limb_width_ratio: float = math.nan  # Earth: median flank width of the usable limb profiles over
    # eq. (4)'s (vision.limb_refit); above LimbOptions.edge_width_max the limb edge is not used
    inner_candidate: int | None = None  # Earth: the winner by residual, whose limb profiles were the
    # ground's (limb_width_ratio above LimbOptions.edge_width_max), replaced by the accepted
    # candidate beyond its edge (vision.frontend._outer_candidate); None: not replaced
    inner_width_ratio: float = math.nan  # Earth: that candidate's limb_width_ratio
    second_arc: object = None  # Earth: the wrong-edge test's second arc (vision.edge_check.SecondArc) where
    # the fitted arc lies in the shadow, else None
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
