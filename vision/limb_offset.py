"""The limb edge's height offset of one camera, learned over a flight, and the limb-edge fits
re-weighted with it.

A single frame cannot tell whether the limb model's edge height (`vision.limb`, the Sun-path
model at ``LimbOptions.height_m``) holds: its arc's own (prior-free) height sigma is ~10 km on
the ATEK fisheye, so the limb edge's prior is wide (``EdgeHeightOptions.limb_prior_sigma_m``)
and the nadir takes most of the arc's height error. The model's validity is a property of the
camera and the atmosphere, constant over a flight; the frames together resolve it. With the
arc's own height ``h_i`` (sigma ``s_i``) and the prior's mean ``m_i`` of each limb-edge frame,
the camera's offset is the inverse-variance mean

    b = sum(w_i (h_i - m_i)) / sum(w_i),  w_i = 1 / s_i^2,
    sigma_b^2 = max(1, chi2 / (n - 1)) / sum(w_i),  chi2 = sum(w_i (h_i - m_i - b)^2),

(frames independent; the scatter inflates sigma_b when it exceeds the sigmas). Where
``|b| <= offset_gate * sigma_b <= offset_resolution_m`` the flight shows the limb model holding
and every limb-edge fit of the camera takes the prior N(m_i, sigma_b^2 + sigma_l,i^2) (sigma_l
the model's own limb term; centred on the model, not on m_i + b: on rendered frames the arcs' own
heights sit ~1 km low, and a prior moved by b moves every nadir by ~0.04 deg) instead of the wide
one; elsewhere the wide prior stays (the edges of a camera whose
limb model fails do not follow one shifted height).

The fits are not repeated: the joint direction and height fit (`vision.edge_height`) is a
Gaussian over (direction, height) whose prior enters through the height alone, so replacing
N(m1, s1^2) by N(m2, s2^2) changes the height's marginal by a 1-D information update and moves
the direction along its regression on the height (the conditional of the direction given the
height is the data's, unchanged):

    1/S2 = 1/S1 - 1/s1^2 + 1/s2^2,  h2 = S2 (h1/S1 - m1/s1^2 + m2/s2^2),
    k = c / S1,  e2 = e1 + k (h2 - h1),  P2 = P1 - k c^T + S2 k k^T,  c2 = S2 k,

with (e1, P1, h1, S1, c) the wide-prior fit's direction, its covariance, height, height variance
and direction-height covariance (``TargetResult.edge_cov_c``). The inliers stay those of the
wide fit.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from vision.config import EdgeHeightOptions

__all__ = ["LimbOffset", "LimbEdge", "limb_edge", "estimate_limb_offset", "apply_limb_offset", "refine_limb_height"]


@dataclass(frozen=True)
class LimbOffset:
    """One camera's limb edge height offset over a flight.

    Attributes
    ----------
    camera : camera id of the records.
    offset_m : weighted mean of (arc's own height - prior mean) [m]; NaN below ``offset_min_frames``.
    sigma_m : its 1-sigma [m].
    frames : limb-edge frames with an arc's own height that entered.
    chi2_dof : scatter about the mean per degree of freedom.
    applied : the limb-edge fits were re-weighted with it (within ``offset_gate`` sigmas of 0).
    """

    camera: int
    offset_m: float
    sigma_m: float
    frames: int
    chi2_dof: float
    applied: bool

    def describe(self) -> str:
        """One line: the offset, its sigma, the frames and whether it was applied."""
        if not math.isfinite(self.offset_m):
            return f"camera {self.camera}: limb edge height offset not learned ({self.frames} limb-edge frames)"
        what = "applied" if self.applied else "not applied (the limb model does not hold: wide prior kept)"
        return (f"camera {self.camera}: limb edge height offset {self.offset_m / 1e3:+.1f} +- "
                f"{self.sigma_m / 1e3:.1f} km over {self.frames} frames (chi2/dof {self.chi2_dof:.2f}), {what}")


@dataclass(frozen=True)
class LimbEdge:
    """What a limb-edge Earth fit needs for its re-weighting (`limb_edge`).

    Attributes
    ----------
    prior_m, prior_sigma_m : the height prior the fit used [m].
    limb_sigma_m : the limb model's own height term [m] (0 when unknown).
    data_m, data_sigma_m : the arc's own (prior-free) height and its 1-sigma [m].
    cov_c : (3,) covariance of the camera-frame direction with the height [rad m].
    """

    prior_m: float
    prior_sigma_m: float
    limb_sigma_m: float
    data_m: float
    data_sigma_m: float
    cov_c: np.ndarray


def limb_edge(tr) -> LimbEdge | None:
    """The `LimbEdge` of an Earth `vision.results.TargetResult` whose record came from the limb
    edge with an arc that measures the height; else None."""
    if (tr is None or tr.record is None or not tr.limb_edge or tr.edge_cov_c is None
            or not (math.isfinite(tr.edge_data_m) and math.isfinite(tr.edge_data_sigma_m) and tr.edge_data_sigma_m > 0)
            or not (math.isfinite(tr.limb_prior_m) and tr.limb_prior_sigma_m > 0)):
        return None
    sl = tr.limb_sigma_m if math.isfinite(tr.limb_sigma_m) else 0.0
    return LimbEdge(float(tr.limb_prior_m), float(tr.limb_prior_sigma_m), float(sl), float(tr.edge_data_m),
                    float(tr.edge_data_sigma_m), np.asarray(tr.edge_cov_c, float).copy())


def estimate_limb_offset(fits, camera: int, opts: EdgeHeightOptions) -> LimbOffset:
    """The limb edge height offset of camera ``camera`` (module docstring) from ``fits``: pairs
    (`vision.results.VectorRecord`, `LimbEdge` or None) of a flight, any cameras and targets."""
    eds = [ed for r, ed in fits if ed is not None and r.target == "earth" and r.camera == camera]
    n = len(eds)
    if n < opts.offset_min_frames:
        return LimbOffset(camera, math.nan, math.nan, n, math.nan, False)
    d = np.array([ed.data_m - ed.prior_m for ed in eds])
    w = 1.0 / np.array([ed.data_sigma_m for ed in eds]) ** 2
    b = float(np.sum(w * d) / np.sum(w))
    chi2_dof = float(np.sum(w * (d - b) ** 2)) / (n - 1)
    sb = math.sqrt(max(1.0, chi2_dof) / float(np.sum(w)))
    applied = 0 < opts.offset_gate * sb <= opts.offset_resolution_m and abs(b) <= opts.offset_gate * sb
    return LimbOffset(camera, b, sb, n, chi2_dof, applied)


def apply_limb_offset(rec, ed: LimbEdge | None, off: LimbOffset):
    """The limb-edge Earth record ``rec`` (`vision.results.VectorRecord`, its fit ``ed``)
    re-weighted to the prior N(prior mean + offset, offset sigma^2 + limb term^2) (module
    docstring); ``rec`` itself when the offset is not applied, ``ed`` is None, the camera
    differs, or the new prior is not tighter."""
    if ed is None or not off.applied or rec.camera != off.camera or rec.target != "earth":
        return rec
    m1, s1 = ed.prior_m, ed.prior_sigma_m
    m2, s2 = m1, math.hypot(off.sigma_m, ed.limb_sigma_m)
    S1 = rec.edge_height_sigma_m**2
    if not (s2 < s1 and S1 > 0):
        return rec
    info2 = 1.0 / S1 - 1.0 / s1**2 + 1.0 / s2**2
    if not info2 > 0:
        return rec
    S2 = 1.0 / info2
    h2 = S2 * (rec.edge_height_m / S1 - m1 / s1**2 + m2 / s2**2)
    k = ed.cov_c / S1
    e2 = rec.e_c + k * (h2 - rec.edge_height_m)
    e2 = e2 / np.linalg.norm(e2)
    T = np.eye(3) - np.outer(e2, e2)
    P2 = rec.P_c - np.outer(k, ed.cov_c) + S2 * np.outer(k, k)
    P2 = T @ (0.5 * (P2 + P2.T)) @ T
    lam = float(np.linalg.eigvalsh(P2)[-1])
    return dataclasses.replace(rec, e_c=e2, P_c=P2, P_overbound=lam * np.eye(3), edge_height_m=float(h2),
                               edge_height_sigma_m=math.sqrt(S2))


def refine_limb_height(fits, opts: EdgeHeightOptions) -> tuple[list, list]:
    """Each camera's limb edge height offset over a flight's ``fits`` (pairs (VectorRecord,
    `LimbEdge` or None), any cameras and targets) and the records re-weighted by it
    (`apply_limb_offset`).

    Returns
    -------
    (records, offsets): the records in the order of ``fits``; one `LimbOffset` per camera with
    records, in camera order.
    """
    cams = sorted({r.camera for r, _ in fits})
    offs = {k: estimate_limb_offset(fits, k, opts) for k in cams}
    return [apply_limb_offset(r, ed, offs[r.camera]) for r, ed in fits], [offs[k] for k in cams]
