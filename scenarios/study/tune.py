"""Maximum-likelihood tuning of the filter's noise parameters from a flight (``horizon-nav tune``).

The objective is the negative log-likelihood of the filter's innovations, the prediction-error
decomposition of :mod:`nav.likelihood`, as a function of the logarithms of the chosen parameters
(:data:`PARAMS`). The vectors are measured once (the vision on the images, or the log's vectors);
every evaluation replays the filter (:func:`nav.navigator.run`) on them with the parameters set.

The measurement set is fixed
----------------------------
The chi-square gate depends on the parameters: a measurement near the gate enters or leaves the
sum as they change, and the objective jumps. Each optimisation therefore runs on a fixed set,
with the gate switched off: the measurements the gate of the likelihood's filter accepts at the
starting tuning (the ones it rejects are removed from the inputs, so that the replay's gate and
the likelihood see the same measurements). After it converges the gate is applied again at the
estimate; if the set changed, the optimisation is repeated on the new set (at most
``max_rounds`` times). The estimate is thus consistent with its own gate, and within each
optimisation the objective is smooth.

The filter of the likelihood
----------------------------
The prediction-error decomposition is the likelihood of the measurements only when the
innovations are white, i.e. for the optimal filter of the model. A Schmidt filter's considered
errors are never corrected, so its innovations are correlated in time. Each evaluation therefore
runs the filter with every considered ("C") group estimated (:func:`estimated_everywhere`); the
tuning written keeps the modes of the base tuning, except the Gauss-Markov vector states when
their parameters were estimated (:func:`gm_mode_written`): a Schmidt filter keeps their
stationary covariance in every innovation covariance, which the likelihood does not fix.

The optimiser
-------------
Fisher scoring (Newton's method with the expected Hessian) with Levenberg-Marquardt damping
(set from the ratio of the achieved to the predicted decrease, :func:`_damping`), in
log-parameters within bounds (a factor :data:`BOUND_FACTOR` either side of the prior) and a
trust region of a factor 4 per step. One iteration costs p + 1 filter runs: at theta and at
theta + h e_i (forward differences, h = :data:`STEP`). Those runs give the derivatives of every
innovation and its covariance, hence the gradient (the score, :func:`nav.likelihood.score`) and
the Fisher information (:func:`nav.likelihood.fisher_information`); the same runs at the final
estimate give its standard errors. The score is taken from those derivatives rather than from
differences of -log L: a forward difference of -log L is off by h/2 times its curvature (for a
parameter known to 1 %, several standard errors), while a forward difference of an S that a
parameter scales is the derivative times the same (e^h - 1) / h in every term, which leaves the
score's zero, the estimate, where it is and the information 5 % high (standard errors 2.5 % low).
Scoring converges in a handful of iterations on this likelihood, where a quasi-Newton method with
finite-difference gradients needs several times the runs.

Identification
--------------
Three classes, from the standard error ``se`` of a parameter's logarithm (the Fisher information
at the estimate):

* *identified*: ``3 se <= ln 1.3`` (:data:`SE_LOG_IDENTIFIED`, 0.087): the 3-sigma interval of the
  estimate, ``exp(+-3 se)``, lies within 30 % of it, so the truth is within 30 % of the estimate
  whenever it is inside that interval (99.7 % for a correct standard error);
* *weakly identified*: ``se`` between that and ``ln 2``: the flight tells the parameter to better
  than a factor 2 but not to 30 %; the estimate is kept (it belongs to the joint maximum with the
  identified ones, and the data reject the prior more often than not) and reported as weak;
* *unidentified* (flat likelihood): ``se >= ln 2`` (:data:`SE_LOG_FLAT`). These are found one at
  a time, the largest standard error first, the others' errors then taken with it fixed (of two
  parameters the flight constrains only together, one is fixed and the other estimated); they keep
  their prior and the others are re-estimated with them fixed, except those whose prior the flight
  rejects (-log L higher by more than :data:`LR_GAP` with that parameter alone at its prior:
  one-sided information, such as a white noise below what the other errors let the flight see),
  which keep their estimate without a standard error.

A parameter none of whose measurements are in the flight (e.g. the Sun's white noise without a Sun
vector, the GPS scale without GPS) is left out before the optimisation, with the reason.

Adding a parameter is one :class:`Param` in :data:`PARAMS`: how to read it from and set it in a
:class:`nav.tuning.Tuning`, the measurement kinds it needs and its key in the tuning TOML (an
edge-height sigma becomes ``Param("edge_height_sigma", ...)`` reading the tuning field the edge
state adds, needing the edge measurements' kind).
"""
from __future__ import annotations

import logging
import math
import re
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from nav.error_state import TRANSITION_GROUPS, gyro_gm_taus
from nav.likelihood import fisher_information, innovation_set, negative_log_likelihood, score
from nav.navigator import GpsData, VectorData, run
from nav.schmidt import GATED, REASONS
from nav.tuning import G0, Tuning

log = logging.getLogger(__name__)

STEP = 0.05            #: finite-difference step in log-parameters
#: relative accuracy an *identified* parameter is promised to (within 30 % of the truth) ...
REL_ACCURACY = 0.30
#: ... at this many standard errors (3: 99.7 % for a correct standard error)
Z_IDENTIFIED = 3.0
#: largest standard error of a log-parameter called identified: Z * SE <= ln(1 + 0.30), so the
#: Z-sigma interval exp(+-Z SE) lies inside [1/1.3, 1.3], within [0.7, 1.3] of the truth
SE_LOG_IDENTIFIED = math.log(1.0 + REL_ACCURACY) / Z_IDENTIFIED
#: standard error of a log-parameter from which the likelihood is called flat (unidentified, the
#: parameter kept at its prior): the flight does not pin it to a factor 2 at 1 sigma
SE_LOG_FLAT = math.log(2.0)
BOUND_FACTOR = 30.0    #: the estimate stays within this factor of the prior
MAX_STEP_LOG = math.log(4.0)   #: largest change of a log-parameter in one iteration
RIDGE = 1.0            #: added to the information in the step (not in the standard errors)
#: rise of -log L at the prior beyond which a weak parameter keeps its estimate (chi-square 1 dof
#: at 0.999: 10.8 / 2)
LR_GAP = 5.4
VECTOR_KINDS = ("hor", "sun", "moon")
GATE_REASON = REASONS[GATED]   #: an innovation's reason when the chi-square gate rejected it
AIDING = {"gps_pos", "gps_vel", "hor", "sun", "moon"}
RAD_S_TO_DEG_RTH = math.degrees(1.0) * 60.0   #: rad/sqrt(s) -> deg/sqrt(h)
DEG_H = math.radians(1.0) / 3600.0    #: 1 deg/h in rad/s
AXES = "xyz"   #: the body axes of the per-axis parameters (``gyro_gm_sigma_x`` ...)


@dataclass(frozen=True)
class Param:
    """A tunable parameter: its value in a Tuning (SI), how to set it, the measurement kinds of
    which it needs at least one, and its TOML entries ``(table, key, factor from SI)``."""
    name: str
    unit: str
    get: Callable
    set: Callable
    needs: frozenset
    toml: tuple
    applies: Callable = lambda t: None   #: a reason the tuning does not use it, or None
    to_unit: float = 1.0                 #: SI -> the unit shown
    #: one body axis of a per-axis entry: the tuning's three values (SI) the TOML list is written from
    axes: Callable | None = None

    def entries(self, value: float, tuned: Tuning | None = None) -> list:
        """``[(table, key, value)]`` of the TOML for the SI value; a per-axis parameter writes the
        list of ``tuned``'s three values."""
        if self.axes is not None and tuned is not None:
            return [(tb, key, [x * f for x in self.axes(tuned)]) for tb, key, f in self.toml]
        return [(tb, key, value * f if f is not None else 0.0) for tb, key, f in self.toml]


def _set_pair(fieldname: str, target: str):
    def setter(t: Tuning, v: float) -> Tuning:
        pairs = dict(getattr(t, fieldname))
        pairs[target] = v
        return replace(t, **{fieldname: tuple(sorted(pairs.items()))})
    return setter


def _gm_used(t: Tuning):
    return "the Gauss-Markov vector states are off (vectors.gm_mode)" if t.vector_gm_mode == "off" else None


def _group_used(name: str):
    return lambda t: f"the {name} state is off" if not getattr(t, name).on else None


def _gyro_gm_form(quantum: bool):
    """``applies`` of a Gauss-Markov gyro parameter: the state is on, in its sigma / tau form
    (``quantum`` False) or its rate-quantum form (True, ``[states.gyro_gm] quantum_dps``)."""
    off = _group_used("gyro_gm")

    def reason(t: Tuning):
        why = off(t)
        if why:
            return why
        if (t.gyro_gm_quantum > 0) != quantum:
            return ("the gyro_gm state has no rate quantum ([states.gyro_gm] quantum_dps)" if quantum else
                    "the gyro_gm state is the rate quantum's rounding (its sigma and tau follow quantum_dps)")
        return None
    return reason


def _group_param(name: str, unit: str, key: str, factor: float, group: str | None = None) -> Param:
    """The 1-sigma of state group ``group`` (default ``name``) as parameter ``name``."""
    g = group or name
    return Param(name, unit, lambda t: getattr(t, g).sigma,
                 lambda t, v: replace(t, **{g: replace(getattr(t, g), sigma=v)}), frozenset(AIDING),
                 (("states." + g, key, 1.0 / factor),), _group_used(g), 1.0 / factor)


def _params() -> dict:
    p = {}
    for tg in VECTOR_KINDS:
        p[f"vector_white_{tg}"] = Param(f"vector_white_{tg}", "", lambda t, tg=tg: t.vector_white_for(tg),
                                        _set_pair("vector_white_by_target", tg), frozenset({tg}),
                                        (("vectors", f"white_noise_{tg}", 1.0),))
        p[f"vector_cov_scale_{tg}"] = Param(f"vector_cov_scale_{tg}", "x", lambda t, tg=tg: t.vector_cov_scale_for(tg),
                                            _set_pair("vector_cov_scale_by_target", tg), frozenset({tg}),
                                            (("vectors", f"cov_scale_{tg}", 1.0),))
    p["correlation_time"] = Param("correlation_time", "s", lambda t: t.correlation_time_s,
                                  lambda t, v: replace(t, correlation_time_s=v), frozenset(VECTOR_KINDS),
                                  (("vectors", "correlation_time_s", 1.0),), _gm_used)
    p["gyro_white"] = Param("gyro_white", "deg/sqrt(h)", lambda t: t.gyro_white, lambda t, v: replace(t, gyro_white=v),
                            frozenset(AIDING), (("imu", "gyro_white_noise_deg_rth", RAD_S_TO_DEG_RTH),
                                                ("imu", "gyro_white_noise_extra_deg_rth", None)),
                            to_unit=RAD_S_TO_DEG_RTH)
    p["accel_white"] = Param("accel_white", "mg/sqrt(Hz)", lambda t: t.accel_white,
                             lambda t, v: replace(t, accel_white=v), frozenset(AIDING),
                             (("imu", "accel_white_noise_mg_rthz", 1.0 / (1e-3 * G0)),
                              ("imu", "accel_white_noise_extra_mg_rthz", None)), to_unit=1.0 / (1e-3 * G0))
    p["gyro_bias"] = _group_param("gyro_bias", "deg/h", "sigma_deg_h", DEG_H)
    p["accel_bias"] = _group_param("accel_bias", "mg", "sigma_mg", 1e-3 * G0)
    p["gyro_gm_sigma"] = replace(_group_param("gyro_gm_sigma", "deg/h", "sigma_deg_h", DEG_H, "gyro_gm"),
                                 applies=_gyro_gm_form(False))
    p["gyro_gm_tau"] = Param("gyro_gm_tau", "s", lambda t: t.gyro_gm_tau_s, lambda t, v: replace(t, gyro_gm_tau_s=v),
                             frozenset(AIDING), (("states.gyro_gm", "correlation_time_s", 1.0),),
                             _gyro_gm_form(False))
    p["gyro_quantum_scale"] = Param("gyro_quantum_scale", "", lambda t: t.gyro_gm_quantum_scale,
                                    lambda t, v: replace(t, gyro_gm_quantum_scale=v), frozenset(AIDING),
                                    (("states.gyro_gm", "quantum_scale", 1.0),), _gyro_gm_form(True))
    for i, ax in enumerate(AXES):
        p[f"gyro_gm_sigma_{ax}"] = Param(f"gyro_gm_sigma_{ax}", "deg/h", lambda t, i=i: float(t.gyro_gm_sigmas()[i]),
                                         lambda t, v, i=i: replace(t, gyro_gm=replace(
                                             t.gyro_gm, sigma=_axis_set(t.gyro_gm_sigmas(), i, v))),
                                         frozenset(AIDING), (("states.gyro_gm", "sigma_deg_h", 1.0 / DEG_H),),
                                         _gyro_gm_form(False), 1.0 / DEG_H, lambda t: t.gyro_gm_sigmas())
        p[f"gyro_gm_tau_{ax}"] = Param(f"gyro_gm_tau_{ax}", "s", lambda t, i=i: float(gyro_gm_taus(t.gyro_gm_tau_s)[i]),
                                       lambda t, v, i=i: replace(t, gyro_gm_tau_s=_axis_set(
                                           gyro_gm_taus(t.gyro_gm_tau_s), i, v)),
                                       frozenset(AIDING), (("states.gyro_gm", "correlation_time_s", 1.0),),
                                       _gyro_gm_form(False), axes=lambda t: gyro_gm_taus(t.gyro_gm_tau_s))
    p["gps_noise_scale"] = Param("gps_noise_scale", "x", lambda t: t.gps_noise_scale,
                                 lambda t, v: replace(t, gps_noise_scale=v), frozenset({"gps_pos", "gps_vel"}),
                                 (("gps", "noise_scale", 1.0),))
    return p


def _axis_set(values, i: int, v: float) -> tuple:
    """``values`` (3,) as a tuple with element ``i`` set to ``v``."""
    out = [float(x) for x in values]
    out[i] = float(v)
    return tuple(out)


def per_axis(names, base: Tuning) -> list:
    """``names`` with ``gyro_gm_sigma`` / ``gyro_gm_tau`` replaced by their three body-axis
    parameters where ``base`` gives that value per axis (``[states.gyro_gm]`` lists)."""
    split = {"gyro_gm_sigma": np.ndim(base.gyro_gm.sigma) > 0, "gyro_gm_tau": np.ndim(base.gyro_gm_tau_s) > 0}
    out = []
    for n in names:
        out += [f"{n}_{ax}" for ax in AXES] if split.get(n) else [n]
    return out


#: every tunable parameter by name (the per-camera P_c scales are built by :func:`param`)
PARAMS = _params()
#: ``vector_cov_scale_<target>_camera_<k>``: the P_c scale of one camera (the log's number k)
_CAMERA_PARAM = re.compile(r"vector_cov_scale_(" + "|".join(VECTOR_KINDS) + r")_camera_([1-9][0-9]*)")


def camera_param_name(target: str, number: int) -> str:
    """The name of the P_c scale of ``target`` on the log's camera ``number``."""
    return f"vector_cov_scale_{target}_camera_{number}"


def param(name: str, numbers=()) -> Param:
    """The parameter ``name``: one of :data:`PARAMS`, or a per-camera P_c scale
    ``vector_cov_scale_<target>_camera_<k>`` on the log's camera k, which is the filter's camera
    index ``numbers.index(k)`` (``numbers``: the log's numbers of the filter's cameras; empty:
    index k - 1). Raises ``ValueError`` naming an unknown parameter."""
    if name in PARAMS:
        return PARAMS[name]
    m = _CAMERA_PARAM.fullmatch(name)
    if not m:
        raise ValueError(f"params: unknown parameter {name!r}; expected some of {sorted(PARAMS)} or "
                         f"vector_cov_scale_<target>_camera_<k>")
    tg, k = m.group(1), int(m.group(2))
    numbers = list(numbers)
    if numbers and k not in numbers:
        raise ValueError(f"params: {name}: camera {k} is not replayed (cameras: {numbers})")
    c = numbers.index(k) if numbers else k - 1
    return Param(name, "x", lambda t: t.vector_cov_scale_for(tg, c), _set_pair("vector_cov_scale_by_camera", (c, tg)),
                 frozenset({(tg, c)}), (("vectors", f"cov_scale_{tg}_camera_{k}", 1.0),))


def is_gm_param(name: str) -> bool:
    """A parameter of the Gauss-Markov vector errors (:data:`GM_PARAMS`, or a per-camera P_c scale)."""
    return name in GM_PARAMS or _CAMERA_PARAM.fullmatch(name) is not None


#: the parameters ``tune`` estimates unless told otherwise (those the flight can carry; the ones
#: without measurements are dropped with the reason). Not the turn-on bias sigmas ``gyro_bias`` and
#: ``accel_bias``: each is the spread of a constant over units, of which a flight holds one draw
#: per axis, so even a perfectly observed bias leaves the standard error of log sigma at
#: 1 / sqrt(2 * 3) = 0.41 (three samples), far from identified (0.087); an estimate from one
#: flight is that draw's noise. They are estimated when named in ``--params``.
DEFAULT_PARAMS = ("vector_white_hor", "vector_white_sun", "vector_white_moon", "vector_cov_scale_hor",
                  "vector_cov_scale_sun", "vector_cov_scale_moon", "correlation_time", "gyro_white", "accel_white",
                  "gyro_gm_sigma", "gyro_gm_tau", "gyro_quantum_scale", "gps_noise_scale")


@dataclass
class TuneInputs:
    """What the filter replays: the IMU, initial state, GPS, vectors, mountings and lever arm."""
    imu: object
    init: object
    gps: GpsData | None
    vectors: VectorData | None
    R_bc: list
    lever_b: tuple = (0.0, 0.0, 0.0)
    #: the log's camera numbers of the filter's camera indices (empty: index + 1); they name the
    #: per-camera parameters (:func:`param`)
    cam_numbers: tuple = ()


@dataclass
class Estimate:
    name: str
    prior: float          #: SI
    value: float          #: SI (the prior when unidentified)
    se_log: float         #: standard error of the log-parameter (inf: not identified at all)
    identified: bool      #: 3 se_log <= ln 1.3: within 30 % at 3 sigma (module docstring)
    reason: str | None = None   #: why it is not identified
    unit: str = ""
    to_unit: float = 1.0
    #: the estimate is written without a standard error: at the search bound, or one-sided
    #: (the likelihood flat on one side, the prior rejected)
    at_bound: bool = False
    #: weakly identified: estimated (se_log < ln 2) but not to 30 % at 3 sigma
    weak: bool = False

    @property
    def status(self) -> str:
        """``identified``, ``weak``, ``one-sided`` (or at the search bound) or ``unidentified``."""
        if self.identified:
            return "identified"
        if self.weak:
            return "weak"
        return "one-sided" if self.at_bound else "unidentified"

    @property
    def estimated(self) -> bool:
        """The value is the flight's estimate (written to the tuning), not the prior."""
        return self.identified or self.weak or self.at_bound

    def line(self) -> str:
        v, p = self.value * self.to_unit, self.prior * self.to_unit
        if self.identified or self.weak:
            tag = "" if self.identified else f" weakly identified: {self.reason}"
            return (f"{self.name:24s} {v:11.4g} {self.unit:12s} +- {100 * self.se_log:5.1f} % "
                    f"(prior {p:.4g}, x{self.value / self.prior:.3g}){tag}")
        if self.at_bound:
            return f"{self.name:24s} {v:11.4g} {self.unit:12s} {self.reason} (prior {p:.4g})"
        return f"{self.name:24s} {p:11.4g} {self.unit:12s} not identified: {self.reason}"


@dataclass
class TuneResult:
    estimates: list
    tuning: Tuning
    nll_prior: float
    nll: float
    evaluations: int
    seconds: float
    converged: bool
    n_measurements: int
    rounds: int
    warnings: list = field(default_factory=list)
    #: settings of the base the tuning written changes, ``[(table, key, value, why)]``
    #: (:func:`gm_mode_written`)
    settings: list = field(default_factory=list)

    @property
    def seconds_per_evaluation(self) -> float:
        return self.seconds / max(self.evaluations, 1)

    def by_name(self) -> dict:
        return {e.name: e for e in self.estimates}

    def report(self) -> str:
        lines = [e.line() for e in self.estimates]
        lines.append(f"-log L {self.nll_prior:.2f} at the prior -> {self.nll:.2f} ({self.n_measurements} measurement "
                     f"blocks, {self.rounds} gating round(s)); {self.evaluations} filter runs, "
                     f"{self.seconds_per_evaluation:.2f} s each, {self.seconds:.0f} s in all"
                     + ("" if self.converged else "; NOT CONVERGED: the best point is reported"))
        lines += [f"warning: {w}" for w in self.warnings]
        lines += [f"[{tb}] {key} = {val!r} in the tuning written: {why}" for tb, key, val, why in self.settings]
        return "\n".join(lines)


class Objective:
    """-log L of the innovations over a fixed measurement set, as a function of log-parameters
    (module docstring). Counts the filter runs and their time; ``progress`` (a tqdm bar or None)
    is advanced by one per run."""

    def __init__(self, inputs: TuneInputs, base: Tuning, params: list, progress=None):
        self.inputs, self.base, self.params, self.progress = inputs, base, params, progress
        self.theta0 = np.log([p.get(base) for p in params])
        self.evaluations, self.seconds = 0, 0.0
        self.gps, self.vectors = inputs.gps, inputs.vectors
        self.keys = None
        self.one_sided = {}
        self.flat_se = {}   #: name -> standard error when the parameter was found flat and fixed

    def written(self, theta) -> Tuning:
        """The base tuning with the parameters at ``theta``: the modes and the gate as written."""
        t = self.base
        for p, th in zip(self.params, theta):
            t = p.set(t, float(math.exp(th)))
        return t

    def tuning(self, theta, *, gate: bool = False) -> Tuning:
        """The filter of the likelihood at ``theta``: the considered groups estimated (the optimal
        filter of the model, whose innovations are white), no divergence recovery and no re-opened
        misalignment (both follow the gate), and the gate off (the set is fixed) unless ``gate``,
        which :meth:`fix_set` uses to choose the set this same filter accepts."""
        t = replace(estimated_everywhere(self.written(theta)), recovery_gated_fixes=0, recovery_gated_vectors=0)
        return t if gate else replace(t, gate_probability=1.0)

    def run(self, tuning: Tuning, gps=None, vectors=None):
        inp = self.inputs
        t0 = time.perf_counter()
        res = run(inp.imu, inp.init, tuning, gps=gps if gps is not None else self.gps,
                  vectors=vectors if vectors is not None else self.vectors, R_bc=inp.R_bc, lever_b=inp.lever_b,
                  store_for_smoother=False, unaided=False)
        self.seconds += time.perf_counter() - t0
        self.evaluations += 1
        if self.progress is not None:
            self.progress.update(1)
        return res

    def fix_set(self, theta) -> int:
        """The measurements the gate accepts at ``theta`` become the fixed set (the others are
        removed from the inputs). Returns how many blocks changed against the previous set."""
        res = self.run(self.tuning(theta, gate=True), self.inputs.gps, self.inputs.vectors)
        gated = {(i.t_ns, i.kind, i.camera) for i in res.innovations if not i.accepted and i.reason == GATE_REASON}
        self.gps, self.vectors = _without(self.inputs.gps, self.inputs.vectors, gated)
        keys = {(i.t_ns, i.kind, i.camera) for i in res.innovations if i.accepted}
        changed = len(keys ^ self.keys) if self.keys is not None else len(keys)
        self.keys = keys
        return changed

    def __call__(self, theta):
        """``(-log L, InnovationSet)`` at ``theta``."""
        iset = innovation_set(self.run(self.tuning(theta)).innovations)
        return negative_log_likelihood(iset)[0], iset

    def many(self, pts, mapper=map) -> list:
        """``[self(theta) for theta in pts]``, the runs through ``mapper`` (a ``map``-like callable,
        e.g. :func:`executor_mapper`'s, which runs them in other processes or on a Dask cluster);
        the runs and their time are counted here either way."""
        if mapper is map:
            return [self(th) for th in pts]
        out = list(mapper(_remote_call, [self] * len(pts), [np.asarray(th, float) for th in pts]))
        for _f, _iset, sec in out:
            self.evaluations += 1
            self.seconds += sec
            if self.progress is not None:
                self.progress.update(1)
        return [(f, iset) for f, iset, _sec in out]

    def __getstate__(self):
        # the parameters travel by name (their accessors are closures) and the progress bar stays
        st = dict(self.__dict__, progress=None, params=[p.name for p in self.params])
        return st

    def __setstate__(self, st):
        self.__dict__.update(st, params=[param(n, st["inputs"].cam_numbers) for n in st["params"]])


def _remote_call(obj: Objective, theta) -> tuple:
    """One likelihood evaluation in a worker: ``(-log L, InnovationSet, seconds)``."""
    logging.getLogger("nav.navigator").setLevel(logging.ERROR)
    t0 = time.perf_counter()
    f, iset = obj(theta)
    return f, iset, time.perf_counter() - t0


@contextmanager
def executor_mapper(jobs: int = 0, scheduler: str | None = None, client=None):
    """A ``map``-like callable for :func:`tune` (``mapper=``) that runs the filter replays of the
    likelihood's derivatives (p per scoring iteration) in parallel: on a Dask cluster
    (``scheduler`` address or ``client``, as ``horizon-nav study --scheduler``), on ``jobs`` local
    processes (``jobs`` > 1), or the built-in ``map`` in this process. The results, and so the
    estimate, are those of the serial run: every replay is deterministic."""
    if scheduler and client is None:
        from scenarios.study.execute import check_scheduler
        client = check_scheduler(scheduler)
    if client is not None:
        yield lambda fn, *its: client.gather(client.map(fn, *its, pure=False))
    elif jobs > 1:
        from concurrent.futures import ProcessPoolExecutor
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            yield lambda fn, *its: list(pool.map(fn, *its))
    else:
        yield map


def estimated_everywhere(t: Tuning) -> Tuning:
    """``t`` with every considered ("C") error group estimated ("E"). The prediction-error
    decomposition is the likelihood only for the optimal filter: a Schmidt filter's innovations
    have the right covariance but are correlated in time (the considered errors are not
    corrected), so their product of marginals is not the likelihood of the measurements."""
    groups = TRANSITION_GROUPS + ("camera_misalignment", "camera_clock_offset", "edge_height")
    kw = {nm: replace(getattr(t, nm), mode="E") for nm in groups if getattr(t, nm).mode == "C"}
    if t.vector_gm_mode == "C":
        kw["vector_gm_mode"] = "E"
    return replace(t, **kw)


def _without(gps, vectors, gated: set):
    """The inputs without the gated blocks: a fix whose position is gated is removed, one whose
    velocity alone is gated keeps its position (velocity NaN); gated vectors are removed."""
    if gps is not None:
        t = np.asarray(gps.t_ns, np.int64)
        drop_pos = np.array([(int(x), "gps_pos", -1) in gated for x in t], bool)
        drop_vel = np.array([(int(x), "gps_vel", -1) in gated for x in t], bool)
        if drop_pos.any() or drop_vel.any():
            keep = ~drop_pos
            v = None if gps.v_e is None else np.array(gps.v_e, float)
            if v is not None:
                v[drop_vel] = np.nan
            gps = GpsData(t[keep], np.asarray(gps.x_e)[keep], np.asarray(gps.P_x)[keep],
                          None if v is None else v[keep], None if gps.P_v is None else np.asarray(gps.P_v)[keep])
    if vectors is not None:
        keep = np.array([(int(t), str(k), int(c)) not in gated
                         for t, k, c in zip(vectors.t_ns, vectors.target, vectors.camera)], bool)
        if not keep.all():
            vectors = VectorData(np.asarray(vectors.t_ns)[keep], np.asarray(vectors.camera)[keep],
                                 np.asarray(vectors.target)[keep], np.asarray(vectors.e_c)[keep],
                                 np.asarray(vectors.P_c)[keep])
    return gps, vectors


def _derivatives(obj: Objective, theta, iset0, mapper=map):
    """Gradient (p,) and Fisher information (p, p) at ``theta`` from the forward-difference
    derivatives of every innovation and its covariance over the p runs at theta + h e_i,
    h = :data:`STEP` (:func:`nav.likelihood.score`, :func:`nav.likelihood.fisher_information`;
    the module docstring says why forward differences serve)."""
    p = theta.size
    out = obj.many([theta + STEP * np.eye(p)[i] for i in range(p)], mapper)
    grad, info = np.zeros(p), np.zeros((p, p))
    for d, (idx, nu0, S0) in iset0.by_dim.items():
        dnu, dS = np.zeros((p, idx.size, d)), np.zeros((p, idx.size, d, d))
        for i in range(p):
            nup, Sp = _aligned(out[i][1], iset0, d)
            dnu[i], dS[i] = (nup - nu0) / STEP, (Sp - S0) / STEP
        grad += score(nu0, S0, dS, dnu)
        info += fisher_information(S0, dS, dnu)
    return grad, info


def _aligned(iset, ref, d):
    """The blocks of dimension d of ``iset`` in the order of ``ref`` (same fixed set; a block the
    run did not apply, e.g. a non-positive-definite S, contributes no derivative)."""
    idx_r = ref.by_dim[d][0]
    if iset.keys == ref.keys:
        return iset.by_dim[d][1:]
    pos = {k: i for i, k in enumerate(iset.keys)}
    where = {int(j): n for n, j in enumerate(iset.by_dim.get(d, (np.zeros(0, int),))[0])}
    nu_r, S_r = ref.by_dim[d][1], ref.by_dim[d][2]
    nu, S = nu_r.copy(), S_r.copy()
    for n, j in enumerate(idx_r):
        k = pos.get(ref.keys[j])
        if k is not None and k in where:
            nu[n], S[n] = iset.by_dim[d][1][where[k]], iset.by_dim[d][2][where[k]]
    return nu, S


def _solve_step(grad, info, lam, free):
    """Levenberg-Marquardt scoring step on the free parameters (the others stay), with a unit
    ridge (:data:`RIDGE`) so that a direction the flight barely informs moves by at most its
    gradient, and within the trust region. Returns ``(step, predicted decrease)``."""
    p = grad.size
    step = np.zeros(p)
    if not free.any():
        return step, 0.0
    I = info[np.ix_(free, free)]
    A = I + lam * np.diag(np.diag(I)) + RIDGE * np.eye(int(free.sum()))
    step[free] = -np.linalg.solve(A, grad[free])
    decrease = float(-0.5 * grad[free] @ step[free])
    big = np.max(np.abs(step))
    if big > MAX_STEP_LOG:
        step *= MAX_STEP_LOG / big
    return step, decrease


def _variances(info: np.ndarray) -> np.ndarray:
    """Diagonal of inv(info); infinite for a parameter with a component along a direction the
    information does not fix (eigenvalue below 1e-10 of the largest)."""
    w, V = np.linalg.eigh(0.5 * (info + info.T))
    tol = max(float(w.max(initial=0.0)), 1e-300) * 1e-10
    good = w > tol
    var = (V[:, good] ** 2) @ (1.0 / w[good])
    flat = np.any(np.abs(V[:, ~good]) > 1e-3, axis=1)
    return np.where(flat, np.inf, var)


def _model_decrease(grad, info, step) -> float:
    """Decrease of -log L that the scoring model predicts for ``step``: ``-(g' s + s' I s / 2)``."""
    return float(-(grad @ step + 0.5 * step @ info @ step))


def _damping(lam: float, gain: float, predicted: float) -> float:
    """Levenberg-Marquardt damping after an accepted step from the ratio of the achieved to the
    predicted decrease (Nocedal & Wright, Numerical Optimization, alg. 4.1): below 1/4 the model
    overstates the decrease (a step across a curved valley, which then zigzags) and the damping
    grows tenfold; above 3/4 it shrinks tenfold; between, it stays."""
    rho = gain / predicted if predicted > 0 else 1.0
    if rho < 0.25:
        return min(lam * 10, 1e6)
    return max(lam / 10, 1e-6) if rho > 0.75 else lam


def optimise(obj: Objective, theta0, *, max_iter: int = 20, tol: float = 0.1, mapper=map):
    """Fisher scoring from ``theta0`` (module docstring); converged when the predicted or the
    achieved decrease of -log L is below ``tol`` (0.1: well below the 0.5 that one standard
    error moves it). Returns ``(theta, f, iset, info, converged)`` at the best point."""
    lo, hi = obj.theta0 - math.log(BOUND_FACTOR), obj.theta0 + math.log(BOUND_FACTOR)
    theta = np.clip(np.asarray(theta0, float), lo, hi)
    f, iset = obj(theta)
    lam, converged = 1e-3, False
    for _ in range(max_iter):
        grad, info = _derivatives(obj, theta, iset, mapper)
        free = ~(((theta <= lo + 1e-9) & (grad > 0)) | ((theta >= hi - 1e-9) & (grad < 0)))
        decrease = _solve_step(grad, info, 0.0, free)[1]
        log.info("tune: -log L %.3f, predicted decrease %.3g, %d of %d parameters free, theta/prior %s", f, decrease,
                 int(free.sum()), free.size, np.round(np.exp(theta - obj.theta0), 3).tolist())
        if decrease < tol:
            converged = True
            break
        for _try in range(6):
            step = _solve_step(grad, info, lam, free)[0]
            th_new = np.clip(theta + step, lo, hi)
            f_new, iset_new = obj(th_new)
            if f_new < f:
                lam = _damping(lam, f - f_new, _model_decrease(grad, info, th_new - theta))
                gain, theta, f, iset = f - f_new, th_new, f_new, iset_new
                break
            lam *= 10
        else:
            # no decrease along the damped steps: the optimum within the objective's precision
            # when the predicted decrease is small, else the best point so far
            converged = decrease < 0.05
            break
        if gain < tol:   # the step gained less than tol: converged (information at the new point)
            converged = True
            grad, info = _derivatives(obj, theta, iset, mapper)
            break
    else:
        grad, info = _derivatives(obj, theta, iset, mapper)
    return theta, f, iset, info, converged


def per_camera(names, seen: set, numbers=()) -> list:
    """``names`` with each per-target P_c scale ``vector_cov_scale_<target>`` whose target the
    flight has on two or more cameras replaced by one scale per camera
    (``vector_cov_scale_<target>_camera_<k>``, k the log's number of camera index c in ``seen``'s
    ``(target, c)`` pairs; ``numbers`` as in :func:`param`), without repeating a name."""
    out = []
    for n in names:
        tg = n.removeprefix("vector_cov_scale_")
        cams = sorted(c for kind, c in seen if kind == tg) if n.startswith("vector_cov_scale_") else []
        if n in PARAMS and len(cams) >= 2:
            new = [camera_param_name(tg, numbers[c] if numbers else c + 1) for c in cams]
        else:
            new = [n]
        out += [x for x in new if x not in out]
    return out


def _kind_text(kind) -> str:
    """A measurement kind, or ``(target, camera index)`` as "target on camera index 0" text."""
    return kind if isinstance(kind, str) else f"{kind[0]} (camera index {kind[1]})"


def available(names, base: Tuning, kinds: set, numbers=(), *, cameras: bool = True) -> tuple[list, dict]:
    """The parameters of ``names`` the flight and tuning can estimate, and the reason for each
    of the others. ``kinds``: the accepted measurement kinds, and ``(target, camera index)``
    pairs of the vectors; a per-target P_c scale is estimated per camera where the flight has its
    target on two or more cameras (:func:`per_camera`; ``cameras=False``: one scale per target)."""
    seen = {k for k in kinds if isinstance(k, tuple)}
    have = set(kinds) | {k[0] for k in seen}
    ok, why = [], {}
    for n in per_camera(per_axis(names, base), seen if cameras else set(), numbers):
        p = param(n, numbers)
        reason = p.applies(base)
        if reason is None and not (p.needs & have):
            reason = f"the flight has no accepted {'/'.join(sorted(map(_kind_text, p.needs)))} measurement"
        if reason is None and p.get(base) <= 0:
            reason = "its prior is zero (the tuning does not model it)"
        if reason:
            why[n] = reason
        else:
            ok.append(p)
    return ok, why


def tune(inputs: TuneInputs, base: Tuning, names=DEFAULT_PARAMS, *, max_iter: int = 20, max_rounds: int = 3,
         progress=None, mapper=map, cameras: bool = True) -> TuneResult:
    """Maximum-likelihood estimates of the parameters ``names`` (module docstring); a target's P_c
    scale per camera where two or more cameras see it (``cameras=False``: one per target,
    :func:`available`). The filter's per-measurement rejection warnings are silenced during the
    runs (each run would repeat them)."""
    nav_log = logging.getLogger("nav.navigator")
    level = nav_log.level
    nav_log.setLevel(logging.ERROR)
    try:
        return _tune(inputs, base, names, max_iter, max_rounds, progress, mapper, cameras)
    finally:
        nav_log.setLevel(level)


def _tune(inputs, base, names, max_iter, max_rounds, progress, mapper, cameras) -> TuneResult:
    t_start = time.perf_counter()
    obj0 = Objective(inputs, base, [], progress)
    obj0.fix_set(np.zeros(0))
    kinds = {k[1] for k in obj0.keys} | {(k[1], k[2]) for k in obj0.keys if k[1] in VECTOR_KINDS}
    params, why = available(list(names), base, kinds, inputs.cam_numbers, cameras=cameras)
    obj = Objective(inputs, base, params, progress)
    obj.gps, obj.vectors, obj.keys = obj0.gps, obj0.vectors, obj0.keys
    warn = []
    f_prior = obj(obj.theta0)[0] if params else obj0(np.zeros(0))[0]
    theta, rounds, converged, f, iset, info = obj.theta0.copy(), 0, True, f_prior, None, np.zeros((0, 0))
    while params and rounds < max_rounds:
        rounds += 1
        theta, f, iset, info, converged = optimise(obj, theta, max_iter=max_iter, mapper=mapper)
        obj.flat_se = {}
        weak = _weak(info, _at_bound(obj, theta), obj.flat_se, [p.name for p in params])
        weak &= ~_one_sided(obj, theta, f, weak, mapper)
        if weak.any() and not weak.all():
            theta, f, iset, info, se, converged = _refit(obj, theta, weak, max_iter, mapper)
        changed = obj.fix_set(theta)
        if changed == 0:
            break
        log.info("tune: the gate at the estimate changes %d measurement blocks; optimising again", changed)
        if rounds == max_rounds:
            warn.append(f"the gated measurement set still changes ({changed} blocks) after {rounds} rounds")
    if not converged:
        warn.append("the optimisation did not converge within its iterations: the best point is reported")
    ests = _estimates(obj, params, theta, info, why, base)
    tuned = base
    for e, p in zip(ests, params):
        tuned = p.set(tuned, e.value) if e.estimated else tuned
    settings = gm_mode_written(base, ests)
    if settings:
        tuned = replace(tuned, vector_gm_mode="E")
    warn += [f"{e.name} = {e.value * e.to_unit:.4g} {e.unit} has no standard error: {e.reason}"
             for e in ests if e.at_bound]
    n_meas = len(obj.keys) if obj.keys is not None else 0
    for w in warn:
        warnings.warn(w, RuntimeWarning, stacklevel=2)
    return TuneResult(ests, tuned, f_prior, f, obj.evaluations + obj0.evaluations,
                      time.perf_counter() - t_start, converged, n_meas, rounds, warn, settings)


#: the parameters of the Gauss-Markov vector errors (their stationary sigma and correlation time;
#: the per-camera P_c scales too, :func:`is_gm_param`)
GM_PARAMS = ("vector_cov_scale_hor", "vector_cov_scale_sun", "vector_cov_scale_moon", "correlation_time")


def gm_mode_written(base: Tuning, ests) -> list:
    """``[("vectors", "gm_mode", "E", why)]`` when the base considers the Gauss-Markov vector
    states and the flight estimated one of their parameters, else ``[]``.

    The estimate is the maximum of the likelihood of the filter that estimates them: its innovation
    covariance holds the states' covariance after their estimation, which a flight fixes through
    the increments of the process (driving noise ``2 k^2 P_c / T_c``, 003 eq. (45)). A Schmidt
    filter that considers them keeps their stationary covariance ``k^2 P_c`` in every S; when T_c
    is not short against the flight, the likelihood is flat along ``k^2 / T_c`` = const (the
    errors are biases with one draw per camera and target), so that covariance is not a property
    of the flight and the considered filter's NIS is not set by the estimate (docs/tuning.md
    "The filter the estimate is for"). The tuning written therefore estimates them."""
    if base.vector_gm_mode != "C":
        return []
    done = [e.name for e in ests if is_gm_param(e.name) and e.estimated]
    if not done:
        return []
    return [("vectors", "gm_mode", "E", f"estimated: the likelihood of {', '.join(done)} is that of the filter "
                                         f"estimating the Gauss-Markov vector states (base: considered)")]


def _one_sided(obj: Objective, theta, f: float, weak, mapper=map) -> np.ndarray:
    """Of the weak parameters, those whose prior the flight rejects: -log L rises by more than
    :data:`LR_GAP` when the parameter alone goes back to its prior (the likelihood is flat on one
    side of the estimate only, e.g. a white noise below what the other errors let the flight
    see). They keep their estimate, without a standard error (``obj.one_sided``: name -> rise)."""
    out = np.zeros(theta.size, bool)
    idx = np.flatnonzero(weak)
    pts = []
    for i in idx:
        th = theta.copy()
        th[i] = obj.theta0[i]
        pts.append(th)
    for i, (fi, _iset) in zip(idx, obj.many(pts, mapper)):
        rise = fi - f
        if rise > LR_GAP:
            out[i] = True
            obj.one_sided[obj.params[i].name] = rise
    return out


def _weak(info: np.ndarray, at_bound: np.ndarray, flat_se: dict | None = None, names=()) -> np.ndarray:
    """The parameters the flight does not identify: repeatedly the one with the largest standard
    error above :data:`SE_LOG_FLAT` (the others' errors taken with it fixed), so that of two
    parameters the flight only constrains together, one is fixed and the other estimated.
    ``flat_se`` (name -> se) receives the standard error each had when it was fixed."""
    keep = ~at_bound
    weak = np.zeros(at_bound.size, bool)
    while keep.any():
        idx = np.flatnonzero(keep)
        se = np.sqrt(_variances(info[np.ix_(idx, idx)]))
        if se.max() < SE_LOG_FLAT:
            break
        worst = idx[int(np.argmax(se))]
        weak[worst], keep[worst] = True, False
        if flat_se is not None:
            flat_se[names[worst]] = float(se.max())
    return weak


def _refit(obj: Objective, theta, weak, max_iter, mapper):
    """Re-estimate the identified parameters with the weak ones at their prior."""
    keep = ~weak
    sub = Objective(obj.inputs, obj.base, [p for p, k in zip(obj.params, keep) if not k], obj.progress)
    base_w = sub.written(sub.theta0)   # weak ones at their prior (the base's values)
    sub = Objective(obj.inputs, base_w, [p for p, k in zip(obj.params, keep) if k], obj.progress)
    sub.gps, sub.vectors, sub.keys = obj.gps, obj.vectors, obj.keys
    th, f, iset, info_k, conv = optimise(sub, theta[keep], max_iter=max_iter, mapper=mapper)
    obj.evaluations += sub.evaluations
    obj.seconds += sub.seconds
    full = obj.theta0.copy()
    full[keep] = th
    p = theta.size
    info = np.zeros((p, p))
    info[np.ix_(keep, keep)] = info_k
    se = np.full(p, np.inf)
    se[keep] = np.sqrt(_variances(info_k))
    return full, f, iset, info, se, conv


def _at_bound(obj: Objective, theta) -> np.ndarray:
    return np.abs(np.abs(theta - obj.theta0) - math.log(BOUND_FACTOR)) < 1e-9


def _estimates(obj: Objective, params, theta, info, why: dict, base: Tuning) -> list:
    out = []
    if params:
        atb = _at_bound(obj, theta)
        keep = np.diag(info) > 0
        se = np.full(len(params), np.inf)
        if keep.any():
            se[keep] = np.sqrt(_variances(info[np.ix_(keep, keep)]))
        # a parameter fixed as flat reports the standard error that made it flat (finite when the
        # flight carries some information: a factor-2 change is then seen in some flights)
        se = np.array([obj.flat_se.get(p.name, x) if not k else x for p, x, k in zip(params, se, keep)])
        for p, th, s, b in zip(params, theta, se, atb):
            ident, weak = bool(s <= SE_LOG_IDENTIFIED) and not b, bool(SE_LOG_IDENTIFIED < s < SE_LOG_FLAT) and not b
            reason = None
            if weak:
                reason = (f"3 standard errors ({300 * s:.0f} % in log) exceed ln 1.3 (a 30 % bound); "
                          f"the estimate is kept")
            elif not ident:
                reason = f"flat likelihood: standard error of log {p.name} {s:.2f} (>= ln 2, a factor-2 1-sigma)"
            if b:
                reason = f"at the bound of the search (x{math.exp(th - math.log(p.get(base))):.3g} of the prior)"
            elif not (ident or weak) and p.name in obj.one_sided:
                b = True
                reason = (f"one-sided: no standard error, but -log L is {obj.one_sided[p.name]:.1f} higher at the "
                          f"prior (x{math.exp(th - math.log(p.get(base))):.3g} of the prior kept)")
            out.append(Estimate(p.name, p.get(base), math.exp(th) if (ident or weak or b) else p.get(base), float(s),
                                ident, reason, p.unit, p.to_unit, bool(b), weak))
    for n, r in why.items():
        p = param(n, getattr(obj.inputs, "cam_numbers", ()))
        out.append(Estimate(n, p.get(base), p.get(base), math.inf, False, r, p.unit, p.to_unit))
    return out


# ------------------------------------------------------------------------------------------------
# the tuning TOML
# ------------------------------------------------------------------------------------------------

def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, float):
        return repr(float(f"{v:.6g}"))
    return str(v)


def _comment(comments: dict, where: tuple, p: Param, text: str) -> None:
    """The comment of a TOML entry; a per-axis parameter's (its name ends in the axis) joins
    those of the other axes."""
    if p.axes is not None:
        text = f"{p.name[-1]}: {text}"
        if where in comments:
            text = f"{comments[where]}; {text}"
    comments[where] = text


def tuning_toml(result: TuneResult, base_overrides: dict | None = None, header: str = "") -> str:
    """The tuning file: the base file's overrides with the identified estimates on top, each
    commented with its standard error; the unidentified parameters listed in comments."""
    tables: dict = {}
    comments: dict = {}
    for tb, kv in (base_overrides or {}).items():
        if tb == "states":
            for g, gkv in kv.items():
                tables.setdefault(f"states.{g}", {}).update(gkv)
        else:
            tables.setdefault(tb, {}).update(kv)
    lines = [f"# {ln}" if ln else "#" for ln in header.splitlines()]
    for tb, key, val, why in result.settings:
        tables.setdefault(tb, {})[key] = val
        comments[(tb, key)] = why
    for e in result.estimates:
        p = param(e.name)
        if e.at_bound:
            for tb, key, val in p.entries(e.value, result.tuning):
                tables.setdefault(tb, {})[key] = val
                _comment(comments, (tb, key), p, f"ML estimate {e.reason}; prior {e.prior * e.to_unit:.4g} {e.unit}")
            continue
        if not e.estimated:
            lines.append(f"# {e.name}: not identified ({e.reason}); kept at {e.prior * e.to_unit:.4g} {e.unit}")
            continue
        what = "ML estimate" if e.identified else "ML estimate, WEAKLY identified (3 SE > 30 %)"
        for tb, key, val in p.entries(e.value, result.tuning):
            tables.setdefault(tb, {})[key] = val
            _comment(comments, (tb, key), p, f"{what}, standard error {100 * e.se_log:.1f} % (1 sigma, log-parameter); "
                                              f"prior {e.prior * e.to_unit:.4g} {e.unit}")
    if any(e.estimated and e.name.startswith("vector_cov_scale_hor") for e in result.estimates):
        tables.setdefault("vectors", {})["cov_scale_edge_state"] = result.tuning.edge_height.mode
        comments[("vectors", "cov_scale_edge_state")] = ("the edge-height state the P_c scales were estimated with: "
                                                         "a replay with it turned on or off warns")
    for tb in sorted(tables):
        lines += ["", f"[{tb}]"]
        for key, val in tables[tb].items():
            c = comments.get((tb, key))
            lines.append(f"{key} = {_toml_value(val)}" + (f"   # {c}" if c else ""))
    return "\n".join(lines) + "\n"
