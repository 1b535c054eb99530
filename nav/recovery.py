"""Recovery of the filter after an IMU gap or a divergence (re-initialisation from GPS), and of a
camera whose misalignment has locked onto a wrong value (re-opening its covariance).

The rules (:class:`Recovery`, tuning entries ``Tuning.recovery*``, TOML table ``[recovery]``):

* **IMU gap.** A step between two IMU samples longer than
  ``max(recovery_gap_s, recovery_gap_samples * dt_nominal)`` (``dt_nominal`` the median sample
  interval of the run; defaults 2 s and 50 samples) leaves the INS integrating across it with the
  last sample held, so its position, velocity and attitude are no longer the filter's estimate.
  The first usable GPS fix after the gap re-initialises the state (below), then updates it as usual.
* **Divergence.** ``recovery_gated_fixes`` consecutive GPS fixes (default 10) each with a block
  (position or velocity) rejected by the chi-square gate mean that the filter's prediction and its
  covariance no longer cover the fixes: the filter would reject every later fix. A fix with every
  block accepted resets the count; fixes with input problems do not count. The last fix of the run
  re-initialises the state.

Re-initialisation keeps the attitude and the sensor and camera estimates (with their covariance
and correlations) and takes position and velocity from the fix:

* position: the antenna fix minus the lever arm, back to the IMU sample before the stamp
  (:func:`nav.filter_state.extrapolate` over ``-dt_m``; a fix more than ``_MAX_DIFF_S`` after
  its sample, as those inside a gap, is not used); covariance the fix's ``P_x``;
* velocity: the fix's velocity with its ``P_v`` or, for position-only GPS, the difference with
  the previous usable fix (less than ``_MAX_DIFF_S`` earlier and after the gap) with covariance
  ``(P_x_j + P_x_j-1) / dt^2``; in both cases plus ``recovery_vel_sigma^2`` per axis;
* position and velocity are uncorrelated with every other state (their rows and columns of P are
  replaced); the attitude variance grows by ``recovery_att_sigma_gap^2`` or
  ``recovery_att_sigma_divergence^2`` per axis.

A camera's vectors can lock it out. One vector far from the truth with a tight covariance,
accepted while the attitude and misalignment priors are wide, moves the estimated misalignment
onto itself and shrinks its covariance; every later correct vector of that camera is then gated,
and the misalignment stays wrong (:class:`MisalignmentReopening`):

* **Camera lock-out.** ``recovery_gated_vectors`` consecutive vectors of one camera (Earth, Sun,
  Moon; default 20) rejected by the chi-square gate, with none of them accepted, re-open that
  camera's misalignment: its variance grows by the prior's, ``camera_misalignment.sigma^2`` per
  axis. The growth is process noise added between the epoch's update and the next propagation, so
  the smoother treats it as such (its gain across the re-opening is small). Only an estimated
  misalignment is re-opened; a camera whose vectors stay gated after the re-opening is re-opened
  again after as many more, so an estimate several prior sigmas from its vectors is reached in
  steps. The attitude is left alone: the other cameras and GPS hold it. ``[recovery] enabled =
  false`` turns this off with the rest.

Each recovery is recorded as ``(t_ns, reason, details)`` (reason ``"imu_gap"``, ``"divergence"``
or ``"camera_gated"``) in ``NavResult.recoveries`` and logged.
"""
from __future__ import annotations

import logging

import numpy as np

from nav.earth import OMEGA_E
from nav.filter_state import extrapolate
from nav.rotation import quat_to_matrix
from nav.schmidt import GATED, REASONS
from nav.tuning import VECTOR_TARGETS

log = logging.getLogger("nav.navigator")   # the run's logger: recoveries are part of its report

NS = 1_000_000_000
_MAX_DIFF_S = 2.0   #: longest interval [s] between two fixes giving a velocity, or from a fix back to its sample
_GATED_KEYS = (f"gps_pos_{REASONS[GATED]}", f"gps_vel_{REASONS[GATED]}")   #: reject counts of gated GPS blocks


def gap_threshold_s(ts, tuning) -> float:
    """The IMU step [s] beyond which a gap triggers a recovery (module docstring)."""
    dt_nom = float(np.median(np.diff(ts))) if ts.size > 1 else 0.0
    return max(tuning.recovery_gap_s, tuning.recovery_gap_samples * dt_nom)


class Recovery:
    """Watches the epoch loop for gaps and divergence and re-initialises the state (module
    docstring). ``next_gap``: the first IMU sample after the next gap (``N``: none left); the loop
    calls :meth:`passed` when a propagation reaches it, :meth:`before` at each measurement epoch
    while a gap recovery is pending, :meth:`diverged` after each epoch's update and :meth:`after`
    when it is true."""

    def __init__(self, ts, t_ns, tuning, sources):
        self.tuning, self.t_ns = tuning, t_ns
        self.events = []
        gi = [i for i, s in enumerate(sources) if s.name == "gps"]
        self.on = bool(tuning.recovery) and bool(gi)
        self.gps_si = gi[0] if gi else -1
        self.gps = sources[self.gps_si] if gi else None
        ends = np.flatnonzero(np.diff(ts) > gap_threshold_s(ts, tuning)) + 1 if self.on else np.empty(0, int)
        self.gap_ends = ends.tolist() + [ts.size]
        self.gi = 0
        self.next_gap = self.gap_ends[0]
        self.pending = None
        self.n_gated = 0
        self.gated_total = 0
        self.watch = self.on and tuning.recovery_gated_fixes > 0

    def passed(self, k_end: int) -> None:
        """A propagation reached sample ``k_end`` at or after the next gap's end: a gap recovery
        is pending (one for any number of gaps before the next fix)."""
        while self.next_gap <= k_end:
            g = self.next_gap
            gap_s = float(self.t_ns[g] - self.t_ns[g - 1]) / NS
            if self.pending is None:
                self.pending = {"gap_s": gap_s, "gap_start_ns": int(self.t_ns[g - 1]), "gap_end_ns": int(self.t_ns[g])}
            else:
                self.pending["gap_s"] += gap_s
            self.gi += 1
            self.next_gap = self.gap_ends[self.gi]

    def before(self, at, evs, st) -> bool:
        """At a measurement epoch with a pending gap recovery: re-initialise from the first usable
        GPS fix among ``evs`` (the epoch's events ``(t_ns, source, index)``). ``at(t_m)``: the
        extrapolation arguments ``(f, w, dt_m)`` to a stamp. Returns whether it did."""
        for t_m, si, j in evs:
            if si == self.gps_si and self._reinitialise(st, j, t_m, at(t_m), "imu_gap", self.pending,
                                                       self.tuning.recovery_att_sigma_gap):
                self.pending = None
                self.n_gated = 0
                return True
        return False

    def diverged(self, rejected, innovations: list, n0: int) -> bool:
        """After an epoch's update: count the GPS fixes with a gated block (the run's reject
        counts tell whether the epoch added one; its innovations from ``n0`` on, read only while
        the count is not zero, whether a fix was accepted); whether ``recovery_gated_fixes`` came
        in a row."""
        total = rejected.get(_GATED_KEYS[0], 0) + rejected.get(_GATED_KEYS[1], 0)
        if total != self.gated_total:
            self.gated_total = total
            self.n_gated += 1
            return self.n_gated >= self.tuning.recovery_gated_fixes
        if self.n_gated and any(innovations[i].camera < 0 and innovations[i].accepted
                                for i in range(n0, len(innovations))):
            self.n_gated = 0
        return False

    def after(self, evs, at, st) -> bool:
        """After :meth:`diverged` said so: re-initialise from the epoch's last usable GPS fix.
        Returns whether it did."""
        for t_m, si, j in reversed(evs):
            if si == self.gps_si and self._reinitialise(st, j, t_m, at(t_m), "divergence",
                                                       {"gated_fixes": self.n_gated},
                                                       self.tuning.recovery_att_sigma_divergence):
                self.n_gated = 0
                return True
        return False

    def _velocity(self, j: int, t_m: int):
        """Velocity at fix j and its covariance, or None (module docstring)."""
        g = self.gps
        if g.has_v and g.bad_v[j] is None:
            return g.v[j], g.P_v[j], "fix"
        i = j - 1
        while i >= 0 and g.bad_x[i] is not None:
            i -= 1
        if i < 0:
            return None
        dt = (t_m - g.t_ns[i]) / NS
        if not 0 < dt <= _MAX_DIFF_S or (self.pending is not None and g.t_ns[i] < self.pending["gap_end_ns"]):
            return None
        return (g.x[j] - g.x[i]) / dt, (g.P_x[j] + g.P_x[i]) / dt ** 2, "difference"

    def _reinitialise(self, st, j: int, t_m: int, at, reason: str, details: dict, att_sigma: float) -> bool:
        g = self.gps
        if g.bad_x[j] is not None or abs(at[2]) > _MAX_DIFF_S:
            return False
        vel = self._velocity(j, t_m)
        if vel is None:
            return False
        v_g, P_v, v_src = vel
        f, w, dt_m = at
        R_eb = quat_to_matrix(st.q)
        w_eb = w - R_eb.T @ np.array([0.0, 0.0, OMEGA_E])
        nav_m = st.nav.copy()
        nav_m[0:3] = g.x[j] - R_eb @ g.lever
        nav_m[3:6] = v_g - R_eb @ np.cross(w_eb, g.lever)
        x_k, v_k, _, _ = extrapolate(nav_m, f, w, -dt_m, OMEGA_E)
        jump_x, jump_v = float(np.linalg.norm(x_k - st.x)), float(np.linalg.norm(v_k - st.v))
        lay, P = st.layout, st.P
        ix, iv, ip = lay["dx"], lay["dv"], lay["psi"]
        for sl in (ix, iv):
            P[sl, :] = 0.0
            P[:, sl] = 0.0
        P[ix, ix] = 0.5 * (g.P_x[j] + g.P_x[j].T)
        P[iv, iv] = 0.5 * (P_v + P_v.T) + self.tuning.recovery_vel_sigma ** 2 * np.eye(3)
        P[ip, ip] += att_sigma ** 2 * np.eye(3)
        st.x[:], st.v[:] = x_k, v_k
        info = dict(details, position_jump_m=jump_x, velocity_jump_m_s=jump_v, velocity_from=v_src,
                    fix_t_ns=int(t_m))
        self.events.append((int(t_m), reason, info))
        log.warning("recovery (%s) at %d ns: state re-initialised from GPS (position moved %.1f m, velocity "
                    "%.2f m/s; %s)", reason, t_m, jump_x, jump_v,
                    ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in details.items()))
        return True


class MisalignmentReopening:
    """Watches each camera's vectors for a lock-out and re-opens its misalignment (module
    docstring). The loop calls :meth:`count` after each epoch's update and :meth:`reopen` after
    the epoch's posterior is recorded, before the next propagation."""

    def __init__(self, tuning, layout, n_cam: int, events: list):
        self.n_max = tuning.recovery_gated_vectors
        self.on = (bool(tuning.recovery) and self.n_max > 0 and n_cam > 0
                   and tuning.camera_misalignment.estimated)
        self.var = tuning.camera_misalignment.sigma ** 2
        self.slices = [layout[layout.cam_name(c)] for c in range(n_cam)] if self.on else []
        self.streak = [0] * n_cam
        self.due = []
        self.events = events

    def count(self, innovations: list, n0: int) -> None:
        """The epoch's innovations from ``n0`` on: per camera, its vectors gated in a row; a
        camera reaching ``recovery_gated_vectors`` is due."""
        for inn in innovations[n0:]:
            c = inn.camera
            if c < 0 or inn.kind not in VECTOR_TARGETS:
                continue
            if inn.accepted:
                self.streak[c] = 0
            elif inn.reason == REASONS[GATED]:
                self.streak[c] += 1
                if self.streak[c] >= self.n_max and c not in self.due:
                    self.due.append(c)

    def reopen(self, st, t_ns: int) -> None:
        """Grow each due camera's misalignment variance by the prior's and record the event."""
        for c in self.due:
            i = np.arange(self.slices[c].start, self.slices[c].stop)
            st.P[i, i] += self.var
            info = {"camera": c, "gated_vectors": self.streak[c], "sigma_added_deg": float(np.degrees(np.sqrt(self.var)))}
            self.events.append((int(t_ns), "camera_gated", info))
            log.warning("recovery (camera_gated) at %d ns: camera index %d's misalignment re-opened after %d of its "
                        "vectors in a row were rejected by the gate (%.3g deg 1 sigma added per axis)",
                        t_ns, c, self.streak[c], info["sigma_added_deg"])
            self.streak[c] = 0
        self.due.clear()
