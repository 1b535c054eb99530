"""The filter's initial state (003 §7.4): the log's truth, a given state, or TRIAD on the first
epoch with a horizon and a Sun vector, back-propagated to the start of the window with the INS.

On the image path TRIAD first runs on vectors measured without an attitude prior (the substitute
sphere of 003 §2.8): their nadir is turned into the geocentric one (003 eq. (39)) with the
attitude of a first TRIAD and the free-inertial INS (:func:`.vision_worker.geocentric_correction`)
and TRIAD repeated on the corrected vectors.
"""
from __future__ import annotations

import dataclasses

from scenarios.config.toml_file import read_toml
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nav import ins
from nav.navigator import InitialState
from nav.rotation import quat_to_matrix
from scenarios.errors import UserError
from scenarios.replay.inputs import PYTHON, Wording, parse_time

NS = 1_000_000_000
#: the initialisation methods a caller names (``None``: TRIAD when the vectors allow it, else truth)
METHODS = (None, "truth", "given", "triad", "align")


@dataclass(repr=False)
class Start:
    """The initial state of the filter and how it was found.

    Attributes
    ----------
    state : nav.navigator.InitialState
        Time, position, velocity and attitude at the start of the navigation.
    method : str
        ``"truth"`` (the log's /truth/state), ``"given"`` (a state file or an ``InitialState``) or
        ``"triad"`` (003 §7.4) or ``"align"`` (in-motion alignment from GPS and the IMU,
        :func:`nav.initialise.aligned_initial_state`).
    triad : nav.initialise.TriadInit or None
        The TRIAD result (epoch, attitude, back-propagation) when ``method`` is ``"triad"``.
    notes : list of str
        What the caller should know (e.g. why TRIAD was not possible).
    request : object
        The ``init`` argument this start answers (``"auto"``, a method, a path or a state).
    alignment : nav.initialise.Alignment or None
        The alignment and its attitude covariance when ``method`` is ``"align"``; the filter
        starts with its attitude sigma (:func:`.steps.navigate`).
    vel_sigma : float or None
        1-sigma [m/s] of the initial velocity when it comes from position-only GPS fixes (their
        slope, :func:`nav.initialise.gps_velocity_sigma`); the filter starts with it
        (:func:`.steps.navigate`) instead of the tuning's ``init_vel_sigma``, which is meant for a
        measured velocity.
    """

    state: InitialState
    method: str
    triad: object = None
    notes: list = field(default_factory=list)
    request: object = "auto"
    alignment: object = None
    vel_sigma: float | None = None

    def __repr__(self) -> str:
        t = f", TRIAD epoch {self.triad.t_triad_ns}" if self.triad is not None else ""
        return f"Start({self.method}, t_ns={self.state.t_ns}{t})"


def split_request(init) -> tuple:
    """``init`` of the Python functions -> (method or None, state file or None, InitialState or None):
    ``"auto"``/None, ``"truth"``, ``"triad"``, ``"align"``, a path to a state TOML, or an ``InitialState``."""
    if isinstance(init, InitialState):
        return "given", None, init
    if init is None or init == "auto":
        return None, None, None
    if isinstance(init, str) and init in ("truth", "triad", "given", "align"):
        return init, None, None       # "given" without its file: initial_state says what is missing
    if isinstance(init, (str, Path)):
        return "given", str(init), None
    raise UserError(f"init: expected 'auto', 'truth', 'triad', 'align', a state file or an InitialState, got {init!r}")


def initial_state(flight, vectors, method, init_file=None, state=None, *, search: bool = False,
                  wording: Wording = PYTHON) -> Start:
    """The initial state of ``flight`` (a :class:`.steps.Flight`) by ``method`` (None: TRIAD when
    ``vectors`` hold an epoch with both a horizon and a Sun vector and the log has GPS, else the
    truth). ``search``: ``vectors`` come from the image path's search without attitude prior, so
    their Earth vectors are corrected to the geocentric nadir and TRIAD repeated on them."""
    inp, imu, gps, mode = flight.inputs, flight.imu, flight.gps, flight.vision
    R_bc = flight.mounts
    w = wording
    notes: list = []
    tri = None
    has_pair = vectors is not None and {"hor", "sun"} <= set(np.unique(vectors.target))
    if method is None:
        if has_pair and gps is not None:
            method = "triad"
        else:
            method = "truth" if inp.truth is not None else "align"
            notes.append("initialisation: no epoch with both a horizon and a Sun vector for TRIAD (003 §7.4); "
                         + (f"using the log's truth ({w.set('init', 'truth')})" if method == "truth"
                            else "in-motion alignment from GPS and the accelerometer"))
    alignment = None
    v_from_gps = False
    # the log's whole GPS record: the position and velocity at the window's start interpolated
    # between fixes on both sides of it (for position-only fixes, a slope over a symmetric window)
    full_gps = inp.gps if inp.gps is not None else gps
    if state is not None:
        init = state
    elif method == "align":
        init, alignment = _aligned(imu, gps, w)
    elif method == "truth":
        if inp.truth is None:
            raise UserError(f"{w.set('init', 'truth')}: {inp.path} has no /truth/state; use "
                            + ("--init triad or given" if w.cli else f"init='triad' or {w.given_state()}"))
        init = _truth_init(inp, imu, w)
    elif method == "given":
        if not init_file:
            raise UserError("--init given: needs --init-file STATE.toml (time, q_eb, position_e, velocity_e)" if w.cli
                            else "init='given': give the state file's path as init (time, q_eb, position_e, velocity_e)")
        init, v_from_gps = _given_init(init_file, inp, imu, w)
    else:
        if not has_pair:
            raise UserError(f"{w.set('init', 'triad')}: no epoch with both a horizon and a Sun vector"
                            + (f" (use {w.set('init', 'truth')}: the log has truth)" if inp.truth is not None else
                               f" (use {w.given_state()})"))
        if gps is None:
            raise UserError(f"{w.set('init', 'triad')}: needs GPS position and velocity")
        init, tri = triad(imu, full_gps, vectors, R_bc, w)
    if search and mode == "images" and vectors is not None:
        vectors = _correct_earth(vectors, imu, init, inp, R_bc)
        if method == "triad":
            init, tri = triad(imu, full_gps, vectors, R_bc, w)
    vel_sigma = None
    if state is None and inp.gps is not None and (method == "triad" or (method == "given" and v_from_gps)):
        from nav.initialise import gps_velocity_sigma
        vel_sigma = gps_velocity_sigma(inp.gps, init.t_ns)
    return Start(init, method, tri, notes, alignment=alignment, vel_sigma=vel_sigma)


#: the largest attitude sigma an in-motion alignment may start the filter with: beyond it the
#: first updates are far from linear (003 §7.4 starts TRIAD-initialised filters at 2 deg)
ALIGN_MAX_SIGMA_DEG = 5.0


def _aligned(imu, gps, w: Wording):
    """:func:`nav.initialise.aligned_initial_state` over the first 60 s, or a refusal naming what
    to give instead when GPS velocity is missing or the motion does not determine the attitude."""
    from nav.initialise import aligned_initial_state
    if gps is None or gps.v_e is None or len(gps.t_ns) < 2:
        raise UserError(f"{w.set('init', 'align')}: needs GPS position and velocity; give {w.given_state()} "
                        "(time and q_eb, roll/pitch/heading or the launcher's azimuth/elevation)")
    try:
        init, al = aligned_initial_state(imu, gps, int(imu.t_ns[0]), window_s=60.0)
    except ValueError as e:
        raise UserError(f"{w.set('init', 'align')}: {e}; give {w.given_state()}") from None
    sigma = np.degrees(al.att_sigma)
    if not np.isfinite(sigma) or sigma > ALIGN_MAX_SIGMA_DEG:
        raise UserError(f"{w.set('init', 'align')}: the first 60 s of motion give the attitude to {sigma:.1f} deg "
                        f"(1 sigma; at most {ALIGN_MAX_SIGMA_DEG:g} deg usable: the heading needs turns or speed "
                        f"changes and gyros that do not saturate); give {w.given_state()}")
    return init, al


def triad(imu, gps, vectors, R_bc, wording: Wording = PYTHON):
    """TRIAD at the first epoch with both vectors after the start, back-propagated to the start
    (003 §7.4). The back-propagation needs an IMU interval: epochs before the second IMU sample (a
    frame at the window start) are skipped for the next one. Returns (InitialState, TriadInit)."""
    from nav.initialise import triad_initialise
    try:
        ti = triad_initialise(imu, gps, vectors, R_bc, int(imu.t_ns[0]), not_before_ns=int(imu.t_ns[min(1, imu.t_ns.size - 1)]))
    except ValueError as e:
        raise UserError(f"{wording.set('init', 'triad')}: {e}") from None
    return ti.initial, ti


def _given_init(path, inp, imu, w: Wording) -> tuple:
    """The state file's InitialState, and whether its position and velocity came from the GPS."""
    p = Path(path)
    what = f"{w.name('init_file')} {p}"
    d, _ = read_toml(p, "state file", label=what)
    t = parse_time(str(d["time"]), inp.liftoff_ns, f"{what}: time") if "time" in d else int(imu.t_ns[0])
    i = int(np.searchsorted(imu.t_ns, t))
    if i >= imu.t_ns.size - 1:
        raise UserError(f"{what}: time is after the IMU record")
    t0 = int(imu.t_ns[i])
    from_gps = False
    if "position_e" in d:
        x, v = np.asarray(d["position_e"], float), np.asarray(d.get("velocity_e", [0, 0, 0]), float)
    elif inp.gps is not None:
        from_gps = True
        from nav.initialise import gps_interpolator
        x, v = gps_interpolator(inp.gps)(t0)
    else:
        raise UserError(f"{what}: no position_e and the log has no GPS")
    q = _given_attitude(d, x, imu, i, what)
    if q.shape != (4,) or not np.isclose(np.linalg.norm(q), 1.0, atol=1e-6):
        raise UserError(f"{what}: q_eb must be a unit quaternion [x, y, z, w]")
    return InitialState(t0, x, v, q), from_gps


#: the ways a state file may give the attitude, each a set of keys
_ATTITUDE_KEYS = ("q_eb [x, y, z, w] (body to ECEF)", "roll_deg, pitch_deg, heading_deg (NED)",
                  "launcher_azimuth_deg, launcher_elevation_deg and optionally roll_deg (on the rail)")


def _given_attitude(d: dict, x_e, imu, i: int, what: str) -> np.ndarray:
    """q_eb from a state file: ``q_eb``, NED roll/pitch/heading, or the launcher's azimuth and
    elevation with the roll given or from the accelerometer over the first second at rest
    (:func:`nav.initialise.launcher_alignment`)."""
    from nav.initialise import euler_to_q_eb, launcher_alignment
    forms = [name for name, keys in (("q_eb", {"q_eb"}), ("roll/pitch/heading", {"pitch_deg", "heading_deg"}),
                                     ("launcher", {"launcher_azimuth_deg", "launcher_elevation_deg"}))
             if keys & set(d)]
    if len(forms) > 1:
        raise UserError(f"{what}: the attitude is given twice ({' and '.join(forms)}); give one of: "
                        f"{'; '.join(_ATTITUDE_KEYS)}")
    try:
        if "q_eb" in d:
            return np.asarray(d["q_eb"], float)
        if "launcher_azimuth_deg" in d or "launcher_elevation_deg" in d:
            az, el = float(d["launcher_azimuth_deg"]), float(d["launcher_elevation_deg"])
            if "roll_deg" in d:
                return launcher_alignment(az, el, x_e, roll_deg=float(d["roll_deg"])).q_eb
            rest = np.asarray(imu.t_ns[i:], np.int64) <= int(imu.t_ns[i]) + NS
            return launcher_alignment(az, el, x_e, f_b=imu.f_b[i:][rest]).q_eb
        if {"roll_deg", "pitch_deg", "heading_deg"} & set(d):
            return euler_to_q_eb(float(d["roll_deg"]), float(d["pitch_deg"]), float(d["heading_deg"]), x_e)
    except KeyError as e:
        raise UserError(f"{what}: missing key {e} for this attitude; give one of: {'; '.join(_ATTITUDE_KEYS)}") from None
    except (TypeError, ValueError) as e:
        raise UserError(f"{what}: attitude: {e}") from None
    raise UserError(f"{what}: no attitude; give one of: {'; '.join(_ATTITUDE_KEYS)} "
                    "(and position_e / velocity_e unless the log has GPS)")


def _truth_init(inp, imu, w: Wording) -> InitialState:
    tr = inp.truth
    t0 = int(imu.t_ns[0])
    j = int(np.searchsorted(tr.t_ns, t0))
    if j >= tr.t_ns.size or tr.t_ns[j] != t0:
        # start at the first IMU sample that has a truth sample
        common = np.intersect1d(imu.t_ns, tr.t_ns)
        if not common.size:
            raise UserError(f"{w.set('init', 'truth')}: no /truth/state sample at an IMU sample time")
        t0 = int(common[0])
        j = int(np.searchsorted(tr.t_ns, t0))
    return InitialState(t0, tr.x_e[j], tr.v_e[j], tr.q_eb[j])


def gps_at(inp, t_ns) -> np.ndarray:
    """The GPS position interpolated at ``t_ns`` (linear per axis)."""
    g = inp.gps
    t = np.asarray(t_ns, float)
    return np.stack([np.interp(t, g.t_ns.astype(float), g.x_e[:, i]) for i in range(3)], -1)


def free_inertial_R_eb(imu, init, t_ns) -> np.ndarray:
    """Body attitude R_eb (n, 3, 3) at ``t_ns`` from the free-inertial INS started at ``init`` (the
    IMU sample at or after each time; times before the start get the initial attitude)."""
    i0 = int(np.searchsorted(imu.t_ns, init.t_ns))
    ts = (imu.t_ns[i0:] - imu.t_ns[i0]) / NS
    _, _, Q = ins.propagate(init.x_e, init.v_e, init.q_eb, ts, imu.f_b[i0:], imu.w_b[i0:], sample=imu.sample)
    j = np.clip(np.searchsorted(imu.t_ns[i0:], np.asarray(t_ns, np.int64)), 0, len(ts) - 1)
    return quat_to_matrix(Q[j])


def _correct_earth(vectors, imu, init, inp, R_bc):
    """Substitute-sphere -> geocentric nadir with the free-inertial attitude from ``init``."""
    from scenarios.replay.vision_worker import geocentric_correction
    m = vectors.target == "hor"
    if not m.any():
        return vectors
    t = vectors.t_ns[m]
    R_eb = free_inertial_R_eb(imu, init, t)
    R_bc_a = np.array(R_bc)[vectors.camera[m]]
    R_ce = np.swapaxes(R_eb @ R_bc_a, -1, -2)
    e = vectors.e_c.copy()
    e[m] = geocentric_correction(vectors.e_c[m], gps_at(inp, t), R_ce)
    return dataclasses.replace(vectors, e_c=e)
