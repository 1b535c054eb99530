"""Study files (TOML): a base scenario and tuning, the parameters to vary, the Monte Carlo seeds.

A study is a set of *variants* (parameter settings) times ``runs`` Monte Carlo replicates. Every
parameter is addressed by a dotted name into one of three dataclasses:

* ``scenario.<...>``: :class:`scenarios.sim.scenario.Scenario` (``scenario.cameras.0.rate_hz``,
  ``scenario.imu.gyro_bias_deg_h``, ``scenario.gps.outages_s``), units as in the scenario files;
* ``tuning.<...>``: :class:`nav.tuning.Tuning` in SI units (``tuning.gyro_bias.sigma`` [rad/s],
  ``tuning.gyro_bias.mode`` = "E" / "C" / "off", ``tuning.vector_white``);
* ``run.<...>``: :class:`RunConfig` (what one run does with the simulated flight: the time window,
  the initial errors, the vision error model of the simulated vectors).

A value is a number, string, boolean or array (set as is), or a table ``{times = k}`` (the base
value multiplied by k: ``{times = 0.1}`` is "a tenth of the base tuning").

File layout::

    [study]
    name = "atek-mistuned"
    scenario = "atek"              # library name or path (relative to the study file)
    tuning = "table3"              # library tuning (scenarios/library/tuning) or path
    seed = 2026                    # study seed: run seeds derive from (seed, replicate) only
    runs = 20                      # Monte Carlo replicates per variant
    max_runs = 1000                # more runs in total need --yes
    metrics = ["nees", "nis", "rms", "misalignment", "smoother"]

    [set]                          # fixed for every variant
    "run.t_end_s" = 430.0
    "tuning.gyro_white" = 1.454e-4

    [[variants]]                   # named settings (optional; default: one variant "base")
    name = "gyro-bias/10"
    "tuning.gyro_bias.sigma" = {times = 0.1}

    [grid]                         # cartesian product over all keys (optional)
    "scenario.cameras.0.rate_hz" = [1.0, 2.0, 4.0]

    [random]                       # random draws of the parameters (optional)
    draws = 8
    "tuning.vector_white" = {loguniform = [1e-4, 1e-2]}   # also uniform, normal, choice

The variants are ``variants x grid x random draws`` (each part defaulting to one empty setting).
Everything is checked when the file is loaded (before any work): unknown tables and keys, unknown
parameter names (tried on the base scenario / tuning / run config, with the valid names listed),
values of the wrong type; the resulting scenarios are validated like scenario files.
"""
from __future__ import annotations

import copy
import dataclasses
import itertools
import math
from scenarios.config.toml_file import parse_toml
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scenarios.errors import UserError

DEFAULT_METRICS = ("nees", "nis", "rms", "misalignment", "smoother")
TUNING_DIR = Path(__file__).resolve().parent.parent / "library" / "tuning"
STUDY_DIR = Path(__file__).resolve().parent.parent / "library" / "studies"
ROOTS = ("scenario", "tuning", "run")
DISTRIBUTIONS = ("uniform", "loguniform", "normal", "choice")


@dataclass
class RunConfig:
    """What one run does with a simulated flight (addressed as ``run.<name>``).

    Attributes
    ----------
    t_start_s, t_end_s : float
        Filter window in mission time [s] (default: the coast T+60..T+430, 003 table 2).
    metric_start_s : float
        Start of the window the metrics average over (default: ``t_start_s``).
    vectors : str
        "truth": true directions plus the vision error model (003 eqs. (33), (36)-(38) covariance of
        the visible limb arc, Gauss-Markov + white errors, eqs. (41)-(45)); "none": GPS/INS only.
    vector_model : str
        "cached": the predicted covariance of every frame is computed once per scenario variant
        with the nominal camera mounting and re-projected onto each run's true direction (see
        :mod:`scenarios.study.runner`); "exact": :func:`scenarios.sim.truth_vectors.flight_truth_vectors`
        per run (the true mounting; slower: the covariance is computed for every run).
    init : str
        "perturbed": the truth at ``t_start_s`` minus an error drawn with the ``init_*`` sigmas;
        "truth": the exact truth.
    init_att_sigma_deg, init_pos_sigma_m, init_vel_sigma_mps : float
        True initial errors (1 sigma per axis) of the "perturbed" start (003 §7.4: 2 deg).
    gm_fraction : float
        Share of the predicted vision covariance carried by the Gauss-Markov part (the rest white).
    correlation_time_s : float
        T_c of the simulated vector errors (003 §6.3: 20 s).
    white_sigma : float
        White vector error drawn per tangent axis on top of the vision error model; negative (the
        default): the tuning's ``vector_white``, i.e. exactly the white noise the filter is told.
    error_scale : float
        True vector errors are drawn with ``error_scale^2`` times the predicted covariance.
    report_scale : float
        The covariance handed to the filter with each vector is ``report_scale^2`` times the
        predicted one (``report_scale = 0.2``: vector noise told to the filter at 1/5 of the truth).
    sun_bloom : float
        Apparent Sun radius multiplier of the visible disc (:func:`vision.error_model.bloomed_alpha`;
        2 as ``scenarios.sim.truth_vectors.DEFAULT_SUN_BLOOM``).
    min_pixels : int
        Shortest visible limb arc [px] that yields a vector (:func:`vision.error_model.predict_vision`).
    smoother : bool
        Also run the RTS smoother (:func:`nav.smoother.rts_smooth`) and report its errors.
    edge_ref_m : float
        Edge height [m] the Earth vectors are fitted at (``vector_model = "exact"`` only): the
        vectors carry the error of a fit at this height instead of the scenario's true
        ``simulation.horizon_atmosphere_m``, and its sensitivity for the filter's edge-height
        state (:mod:`scenarios.sim.truth_vectors`); negative (the default): fitted at the truth,
        no edge fields.
    """
    t_start_s: float = 60.0
    t_end_s: float = 430.0
    metric_start_s: float = -1.0
    vectors: str = "truth"
    vector_model: str = "cached"
    init: str = "perturbed"
    init_att_sigma_deg: float = 2.0
    init_pos_sigma_m: float = 10.0
    init_vel_sigma_mps: float = 0.1
    gm_fraction: float = 1.0
    correlation_time_s: float = 20.0
    white_sigma: float = -1.0
    error_scale: float = 1.0
    report_scale: float = 1.0
    sun_bloom: float = 2.0
    min_pixels: int = 30
    smoother: bool = True
    edge_ref_m: float = -1.0

    def check(self, where: str) -> None:
        if not self.t_end_s > self.t_start_s >= 0:
            raise UserError(f"{where}: run.t_start_s = {self.t_start_s}, run.t_end_s = {self.t_end_s}: "
                            "expected 0 <= t_start_s < t_end_s")
        if self.vectors not in ("truth", "none"):
            raise UserError(f"{where}: run.vectors = {self.vectors!r}: expected 'truth' or 'none'")
        if self.vector_model not in ("cached", "exact"):
            raise UserError(f"{where}: run.vector_model = {self.vector_model!r}: expected 'cached' or 'exact'")
        if self.edge_ref_m >= 0 and self.vector_model != "exact":
            raise UserError(f"{where}: run.edge_ref_m = {self.edge_ref_m}: needs run.vector_model = 'exact'")
        if self.init not in ("perturbed", "truth"):
            raise UserError(f"{where}: run.init = {self.init!r}: expected 'perturbed' or 'truth'")
        if not 0.0 <= self.gm_fraction <= 1.0:
            raise UserError(f"{where}: run.gm_fraction = {self.gm_fraction}: expected in [0, 1]")
        for k in ("correlation_time_s", "error_scale", "report_scale", "sun_bloom"):
            if not getattr(self, k) > 0:
                raise UserError(f"{where}: run.{k} = {getattr(self, k)}: expected > 0")
        if self.sun_bloom < 1:
            raise UserError(f"{where}: run.sun_bloom = {self.sun_bloom}: expected >= 1")
        for k in ("init_att_sigma_deg", "init_pos_sigma_m", "init_vel_sigma_mps"):
            if not getattr(self, k) >= 0:
                raise UserError(f"{where}: run.{k} = {getattr(self, k)}: expected >= 0")

    @property
    def window_start_s(self) -> float:
        return self.t_start_s if self.metric_start_s < 0 else self.metric_start_s


@dataclass
class Variant:
    """One parameter setting: its index, a label and the dotted assignments (after ``[set]``)."""
    index: int
    label: str
    params: dict            #: dotted name -> value as given (numbers, strings, lists, {times=k})


@dataclass
class Study:
    """A parsed, validated study file."""
    name: str
    path: str
    text: str
    scenario: str            #: library name or resolved path
    tuning: str              #: resolved tuning file path
    seed: int
    runs: int
    max_runs: int
    metrics: tuple
    fixed: dict
    variants: list = field(default_factory=list)
    description: str = ""
    declared_runs: int = 0   #: variants x runs as declared (set even when too many to enumerate)

    @property
    def n_runs(self) -> int:
        return self.runs * len(self.variants)

    @property
    def varied(self) -> list[str]:
        """Dotted names that differ between variants (for comparison tables and plots)."""
        keys = []
        for v in self.variants:
            for k in v.params:
                if k not in keys and k not in self.fixed:
                    keys.append(k)
        return keys

    def run_specs(self) -> list["RunSpec"]:
        """Every run of the study: variant-major, replicate-minor (run index = position)."""
        out = []
        for v in self.variants:
            for r in range(self.runs):
                out.append(RunSpec(len(out), v.index, r, run_seed(self.seed, r), f"v{v.index:03d}-r{r:04d}"))
        return out


@dataclass(frozen=True)
class RunSpec:
    """One run: its index in the study, variant, replicate and the derived seed."""
    index: int
    variant: int
    replicate: int
    seed: int
    run_id: str


def run_seed(study_seed: int, replicate: int) -> int:
    """Seed of replicate r: ``SeedSequence(study_seed, spawn_key=(r,))`` -> 63-bit integer.

    Only (study seed, replicate) enter, never the executor, worker or order of execution. The
    variants share the seeds of their replicates (common random numbers): differences between
    variants are then due to the parameters, not to different draws.
    """
    ss = np.random.SeedSequence(int(study_seed), spawn_key=(int(replicate),))
    return int(ss.generate_state(2, dtype=np.uint32).view(np.uint64)[0] >> np.uint64(1))


# ------------------------------------------------------------------------------------------------
# Dotted parameters
# ------------------------------------------------------------------------------------------------
def _names_of(obj) -> list[str]:
    if dataclasses.is_dataclass(obj):
        return [f.name for f in dataclasses.fields(obj)]
    if isinstance(obj, list):
        return [str(i) for i in range(len(obj))]
    return []


def _get(obj, part: str, path: str):
    if isinstance(obj, list):
        try:
            return obj[int(part)]
        except (ValueError, IndexError):
            raise KeyError(f"{path}: index {part!r} out of range (0..{len(obj) - 1})") from None
    if dataclasses.is_dataclass(obj) and part in _names_of(obj):
        return getattr(obj, part)
    names = _names_of(obj)
    raise KeyError(f"{path}: unknown name {part!r}" + (f"; expected one of {names}" if names else
                                                       " (not a table: nothing below it)"))


def _with(obj, parts: list[str], value, path: str):
    """Copy of ``obj`` with the field at ``parts`` set to ``value(old)`` (frozen dataclasses too)."""
    head = parts[0]
    old = _get(obj, head, path)
    new = value(old) if len(parts) == 1 else _with(old, parts[1:], value, path)
    if isinstance(obj, list):
        out = list(obj)
        out[int(head)] = new
        return out
    return dataclasses.replace(obj, **{head: new})


def _resolve_value(spec, old, path: str):
    if isinstance(spec, dict):
        if set(spec) != {"times"}:
            raise UserError(f"{path} = {spec!r}: a table value must be {{times = k}} (scale the base value)")
        k = spec["times"]
        if isinstance(k, bool) or not isinstance(k, (int, float)) or isinstance(old, bool) \
                or not isinstance(old, (int, float)):
            raise UserError(f"{path} = {spec!r}: 'times' needs a number and a numeric base value "
                            f"(base is {old!r})")
        return type(old)(old * k) if isinstance(old, float) else old * k
    if isinstance(old, bool) != isinstance(spec, bool):
        raise UserError(f"{path} = {spec!r}: expected {type(old).__name__} like the base value {old!r}")
    if isinstance(old, (int, float)) and not isinstance(old, bool):
        if not isinstance(spec, (int, float)):
            raise UserError(f"{path} = {spec!r}: expected a number (base value {old!r})")
        return float(spec) if isinstance(old, float) else spec
    if isinstance(old, str) and not isinstance(spec, str):
        raise UserError(f"{path} = {spec!r}: expected a string (base value {old!r})")
    if isinstance(old, (list, tuple)):
        if not isinstance(spec, list):
            raise UserError(f"{path} = {spec!r}: expected an array (base value {old!r})")
        return type(old)(spec)
    if dataclasses.is_dataclass(old):
        raise UserError(f"{path}: is a table; set one of its fields: {_names_of(old)}")
    return spec


def apply_params(base: dict, params: dict, where: str = "<study>") -> dict:
    """``{"scenario": Scenario, "tuning": Tuning, "run": RunConfig}`` with ``params`` applied.

    The inputs are not modified. UserError naming ``where`` and the parameter on a bad name or value.
    """
    out = {k: copy.deepcopy(v) for k, v in base.items()}
    for path, spec in params.items():
        parts = path.split(".")
        if parts[0] not in ROOTS or len(parts) < 2:
            raise UserError(f"{where}: parameter {path!r}: expected a dotted name starting with one of "
                            f"{list(ROOTS)} (e.g. 'tuning.gyro_bias.sigma', 'scenario.cameras.0.rate_hz', "
                            f"'run.t_end_s')")
        try:
            out[parts[0]] = _with(out[parts[0]], parts[1:], lambda old: _resolve_value(spec, old, path), path)
        except KeyError as e:
            raise UserError(f"{where}: unknown parameter {e.args[0]}") from None
        except UserError as e:
            raise UserError(f"{where}: {e}") from None
    return out


def build_variant(study: Study, variant: Variant, base: dict | None = None) -> dict:
    """Scenario, tuning and run config of one variant, validated (fixed settings, then the variant's)."""
    from scenarios.sim.scenario import check_consistency

    base = base or load_base(study)
    where = f"{study.path}: variant {variant.label!r}"
    cfg = apply_params(base, {**study.fixed, **variant.params}, where)
    check_consistency(cfg["scenario"], where)
    cfg["run"].check(where)
    t = cfg["tuning"]
    for name in ("accel_bias", "accel_scale", "accel_misalignment", "gyro_bias", "gyro_scale",
                 "gyro_misalignment", "gyro_nonorthogonality", "camera_misalignment"):
        g = getattr(t, name)
        if g.mode not in ("E", "C", "off"):
            raise UserError(f"{where}: tuning.{name}.mode = {g.mode!r}: expected 'E', 'C' or 'off'")
        if not (g.sigma >= 0 and math.isfinite(g.sigma)):
            raise UserError(f"{where}: tuning.{name}.sigma = {g.sigma!r}: expected a finite number >= 0")
    if cfg["run"].t_end_s > cfg["scenario"].simulation.duration_s:
        raise UserError(f"{where}: run.t_end_s = {cfg['run'].t_end_s} exceeds scenario.simulation.duration_s")
    return cfg


def load_base(study: Study) -> dict:
    from scenarios.sim.scenario import load_scenario
    from scenarios.config.tuning import load_tuning

    try:
        tuning = load_tuning(study.tuning)
    except (ValueError, UserError) as e:
        raise UserError(f"{study.path}: study.tuning: {e}") from None
    return {"scenario": load_scenario(study.scenario), "tuning": tuning, "run": RunConfig()}


# ------------------------------------------------------------------------------------------------
# Parsing
# ------------------------------------------------------------------------------------------------
_STUDY_KEYS = {"name", "description", "scenario", "tuning", "seed", "runs", "max_runs", "metrics"}


def _label(params: dict) -> str:
    def fmt(v):
        if isinstance(v, dict):
            return f"x{v['times']:g}"
        if isinstance(v, float):
            return f"{v:.4g}"
        return str(v)
    return ", ".join(f"{k.split('.', 1)[1]}={fmt(v)}" for k, v in params.items()) or "base"


def _draw(spec, rng, path: str, where: str):
    if not (isinstance(spec, dict) and len(spec) == 1 and next(iter(spec)) in DISTRIBUTIONS):
        raise UserError(f"{where}: [random] {path!r} = {spec!r}: expected one of "
                        + ", ".join(f"{{{d} = [...]}}" for d in DISTRIBUTIONS))
    kind, arg = next(iter(spec.items()))
    if kind == "choice":
        if not isinstance(arg, list) or not arg:
            raise UserError(f"{where}: [random] {path!r}: choice needs a non-empty array")
        return arg[int(rng.integers(len(arg)))]
    if not (isinstance(arg, list) and len(arg) == 2 and all(isinstance(a, (int, float)) for a in arg)):
        raise UserError(f"{where}: [random] {path!r}: {kind} needs [a, b] numbers")
    a, b = float(arg[0]), float(arg[1])
    if kind == "uniform":
        return float(rng.uniform(a, b))
    if kind == "normal":
        return float(rng.normal(a, b))
    if not 0 < a < b:
        raise UserError(f"{where}: [random] {path!r}: loguniform needs 0 < a < b")
    return float(math.exp(rng.uniform(math.log(a), math.log(b))))


def _resolve_file(value: str, rel: Path, library: Path, what: str, where: str) -> str:
    cands = [library / f"{value}.toml", rel / value, Path(value)]
    for c in cands:
        if c.is_file():
            return str(c)
    raise UserError(f"{where}: study.{what} = {value!r}: no such file (tried {[str(c) for c in cands]})")


def study_from_text(text: str, path: str = "<study>") -> Study:
    """Parse and validate a study (TOML text). Every parameter is tried on the base configuration."""
    doc = parse_toml(text, path)
    known = {"study", "set", "variants", "grid", "random"}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise UserError(f"{path}: unknown table [{unknown[0]}]; expected {sorted(known)}")
    st = doc.get("study")
    if not isinstance(st, dict):
        raise UserError(f"{path}: missing table [study] (name, scenario, runs, ...)")
    bad = sorted(set(st) - _STUDY_KEYS)
    if bad:
        raise UserError(f"{path}: unknown key study.{bad[0]}; expected one of {sorted(_STUDY_KEYS)}")
    name = st.get("name")
    if not isinstance(name, str) or not name:
        raise UserError(f"{path}: study.name must be a non-empty string")
    rel = Path(path).parent
    scen = st.get("scenario", "atek")
    if not isinstance(scen, str):
        raise UserError(f"{path}: study.scenario must be a string (library name or path)")
    if scen.endswith(".toml") and not Path(scen).is_absolute() and (rel / scen).is_file():
        scen = str(rel / scen)
    tun = st.get("tuning", "table3")
    if not isinstance(tun, str):
        raise UserError(f"{path}: study.tuning must be a string (library name or path)")
    tun = _resolve_file(tun, rel, TUNING_DIR, "tuning", path)

    def integer(key, default, lo):
        v = st.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise UserError(f"{path}: study.{key} = {v!r}: expected an integer >= {lo}")
        return v

    seed = integer("seed", 0, 0)
    runs = integer("runs", 1, 1)
    max_runs = integer("max_runs", 1000, 1)
    metrics = st.get("metrics", list(DEFAULT_METRICS))
    if not isinstance(metrics, list) or any(m not in DEFAULT_METRICS for m in metrics):
        raise UserError(f"{path}: study.metrics = {metrics!r}: expected a list from {list(DEFAULT_METRICS)}")
    fixed = doc.get("set", {})
    if not isinstance(fixed, dict):
        raise UserError(f"{path}: [set] must be a table of dotted parameters")

    named = doc.get("variants", [{}]) or [{}]
    if not isinstance(named, list) or not all(isinstance(v, dict) for v in named):
        raise UserError(f"{path}: [[variants]] must be an array of tables")
    named_sets = []
    for i, v in enumerate(named):
        v = dict(v)
        lab = v.pop("name", None)
        if lab is not None and not isinstance(lab, str):
            raise UserError(f"{path}: variants[{i}].name must be a string")
        named_sets.append((lab, v))
    grid = doc.get("grid", {})
    if not isinstance(grid, dict):
        raise UserError(f"{path}: [grid] must be a table of dotted parameter = [values]")
    for k, vals in grid.items():
        if not isinstance(vals, list) or not vals:
            raise UserError(f"{path}: [grid] {k!r} = {vals!r}: expected a non-empty array of values")
    grid_sets = [dict(zip(grid, combo)) for combo in itertools.product(*grid.values())] if grid else [{}]
    rnd = dict(doc.get("random", {}))
    draws = rnd.pop("draws", 1 if rnd else 0)
    if isinstance(draws, bool) or not isinstance(draws, int) or draws < (1 if rnd else 0):
        raise UserError(f"{path}: random.draws = {draws!r}: expected a positive integer")
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(2 ** 31,)))
    rand_sets = [{k: _draw(s, rng, k, path) for k, s in rnd.items()} for _ in range(draws)] if rnd else [{}]

    n_variants = len(named_sets) * len(grid_sets) * len(rand_sets)
    study = Study(name, path, text, scen, tun, seed, runs, max_runs, tuple(metrics), dict(fixed), [],
                  str(st.get("description", "")))
    study.declared_runs = n_variants * runs
    if study.declared_runs > 100 * max_runs:  # too many to enumerate: the executor refuses it anyway
        return study
    variants = []
    for (lab, nv), gv, rv in itertools.product(named_sets, grid_sets, rand_sets):
        params = {**nv, **gv, **rv}
        label = ", ".join(x for x in (lab, _label({**gv, **rv}) if (gv or rv) else "") if x) or _label(params)
        variants.append(Variant(len(variants), label, params))
    study.variants = variants
    # every parameter name and value is checked now, on the base configuration
    base = load_base(study)
    for v in variants:
        build_variant(study, v, base)
    return study


def load_study(path: str | Path) -> Study:
    """Read a study file (a path, or the name of a file in ``scenarios/library/studies``)."""
    p = Path(path)
    if not p.is_file() and (STUDY_DIR / f"{path}.toml").is_file():
        p = STUDY_DIR / f"{path}.toml"
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{p}: study file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"{p}: cannot read study file ({e})") from None
    return study_from_text(text, str(p))


__all__ = ["RunConfig", "Variant", "Study", "RunSpec", "run_seed", "apply_params", "build_variant",
           "load_base", "study_from_text", "load_study", "DEFAULT_METRICS"]
