"""Observability report (``horizon-nav tune --report DIR``): per filter state, how much of its prior
variance the smoother removes over the flight, and which states the data barely observe.

For every state ``i`` of the layout (:func:`nav.error_state.build_layout`) and covariance epoch
``k`` the report compares the smoothed variance ``P_s[k, i]`` (:func:`nav.smoother.rts_smooth`)
with the *prior* variance ``P_0[k, i]``: the variance the same filter has at ``k`` without any
measurement update, i.e. its initial covariance carried by its own transitions and process noise

    P_0[0] = P(t_0),   P_0[k] = Phi_k P_0[k-1] Phi_k^T + Q_k,
    Q_k = P_prior[k] - Phi_k P_post[k-1] Phi_k^T

(``Q_k`` read back from the forward run's stored prior and posterior covariances, so that it is
exactly the process noise the filter added, including the Gauss-Markov driving noise of 003
eqs. (43)-(45)). For a constant state (biases, scale factors, misalignments, ``psi_c``, ``dt_c``,
a constant edge height) this is its initial (tuning) variance ``sigma0^2`` at every epoch; for
the navigation errors and the Gauss-Markov states it is their unaided growth.

The variance reduction of a state over the flight is

    r_i = 1 - (1 / T) integral  P_s(t, i) / P_0(t, i) dt

(time average by the trapezoidal rule over the covariance epochs). A state with ``r_i`` below
``low`` (default 0.10) is one the flight barely observes: if the tuning estimates it, it is a
candidate for Schmidt consideration (003 §6.3's choice of estimated "E" and considered "C"
states, made from the data). A considered state with ``r_i`` at or above ``high`` (default 0.5)
is one the data observe well: a candidate for estimation. The navigation block (dx, dv, psi) is
always estimated and never flagged.

A Schmidt filter does not update its considered states, so their smoothed variance would say
nothing about what the data could tell. The report's filter therefore runs with every group
estimated (:func:`scenarios.study.tune.estimated_everywhere`, the filter of the likelihood);
the E/C column is the base tuning's choice.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from nav.error_state import BlockTransition, build_layout
from nav.navigator import run
from nav.smoother import rts_smooth
from nav.tuning import G0, Tuning
from scenarios.study.tune import TuneInputs, estimated_everywhere

NS = 1_000_000_000
LOW = 0.10    #: below this reduction an estimated state is a candidate for consideration
HIGH = 0.50   #: at or above this reduction a considered state is a candidate for estimation
AXES = ("x", "y", "z")

#: display unit of a group (by name prefix): (unit, factor from SI)
UNITS = (("dx", "m", 1.0), ("dv", "m/s", 1.0), ("psi_c", "deg", math.degrees(1.0)), ("psi", "deg", math.degrees(1.0)),
         ("accel_bias", "mg", 1.0 / (1e-3 * G0)), ("gyro_bias", "deg/h", math.degrees(1.0) * 3600.0),
         ("accel_scale", "ppm", 1e6), ("gyro_scale", "ppm", 1e6),
         ("accel_misalignment", "mrad", 1e3), ("gyro_misalignment", "mrad", 1e3),
         ("gyro_nonorthogonality", "mrad", 1e3),
         ("dt_c", "ms", 1e3), ("zeta", "mrad", 1e3), ("h_e", "m", 1.0))


def display_unit(group: str) -> tuple:
    """``(unit, factor from SI)`` of the group's states in the report."""
    for prefix, unit, f in UNITS:
        if group == prefix or group.startswith(prefix + "_"):
            return unit, f
    return "", 1.0


@dataclass
class ObservabilityReport:
    """Per-epoch variances (K, n) and per-state results (n,) of the report (module docstring)."""
    t_s: np.ndarray              #: (K,) covariance epochs, seconds from the first
    t0_ns: int                   #: the first epoch
    names: list                  #: (n,) state names, e.g. ``gyro_bias_z``, ``psi_c_1_x``, ``h_e_0``
    groups: list                 #: (n,) group of each state
    modes: list                  #: (n,) "E" or "C" in the base tuning
    P_prior: np.ndarray          #: (K, n) variance without measurement updates
    P_forward: np.ndarray        #: (K, n) forward filter variance
    P_smoothed: np.ndarray       #: (K, n) smoothed variance
    reduction: np.ndarray        #: (n,) 1 - time average of P_smoothed / P_prior
    low: float = LOW
    high: float = HIGH
    notes: list = field(default_factory=list)

    def flag(self, i: int) -> str:
        """``"consider"``, ``"estimate"`` or ``""`` for state ``i``."""
        if self.groups[i] in ("dx", "dv", "psi"):
            return ""
        if self.modes[i] == "E" and self.reduction[i] < self.low:
            return "consider"
        if self.modes[i] == "C" and self.reduction[i] >= self.high:
            return "estimate"
        return ""

    def flagged(self, kind: str) -> list:
        return [n for i, n in enumerate(self.names) if self.flag(i) == kind]

    def rows(self) -> list:
        """One dict per state: name, group, mode, unit, prior and smoothed sigma at the end,
        reduction, flag."""
        out = []
        for i, (n, g, m) in enumerate(zip(self.names, self.groups, self.modes)):
            unit, f = display_unit(g)
            out.append({"state": n, "group": g, "mode": m, "unit": unit,
                        "sigma0": f * math.sqrt(self.P_prior[0, i]),
                        "sigma_prior_end": f * math.sqrt(self.P_prior[-1, i]),
                        "sigma_smoothed_end": f * math.sqrt(self.P_smoothed[-1, i]),
                        "reduction": float(self.reduction[i]), "flag": self.flag(i)})
        return out

    def csv(self) -> str:
        keys = list(self.rows()[0])
        lines = [",".join(keys)]
        for r in self.rows():
            lines.append(",".join(f"{r[k]:.6g}" if isinstance(r[k], float) else str(r[k]) for k in keys))
        return "\n".join(lines) + "\n"

    def summary(self) -> str:
        c, e = self.flagged("consider"), self.flagged("estimate")
        return (f"observability: {len(self.names)} states over {self.t_s[-1]:.0f} s; "
                f"reduction < {100 * self.low:.0f} % (candidates for consideration): {', '.join(c) or 'none'}; "
                f"considered with reduction >= {100 * self.high:.0f} % (candidates for estimation): "
                f"{', '.join(e) or 'none'}")


def prior_variances(store, P_full) -> np.ndarray:
    """(K, n) diagonal of the covariance propagated without measurement updates (module docstring),
    from a forward run's :class:`nav.navigator.SmootherStore` and ``NavResult.P_full``."""
    K, n = store.d.shape
    out = np.empty((K, n))
    P0 = np.array(store.P_prior[0], float)
    post = store.P_prior[0] if store.post[0] < 0 else P_full[store.post[0]]
    out[0] = np.diag(P0)
    for k in range(1, K):
        tr = BlockTransition(store.A[k], store.d[k])
        Q = store.P_prior[k] - tr.apply(np.asarray(post, float))
        P0 = tr.apply(P0) + Q
        P0 = 0.5 * (P0 + P0.T)
        out[k] = np.diag(P0)
        post = store.P_prior[k] if store.post[k] < 0 else P_full[store.post[k]]
    return out


def variance_reduction(t_s, P_smoothed, P_prior) -> np.ndarray:
    """``1 - (1/T) integral P_smoothed / P_prior dt`` per state (trapezoidal rule)."""
    ratio = np.asarray(P_smoothed, float) / np.asarray(P_prior, float)
    t = np.asarray(t_s, float)
    if t.size < 2 or t[-1] <= t[0]:
        return 1.0 - ratio.mean(axis=0)
    return 1.0 - np.trapezoid(ratio, t, axis=0) / (t[-1] - t[0])


def state_names(layout) -> tuple:
    """``(names, groups)`` of every state of the layout in state order."""
    names, groups = [], []
    for g in layout.groups:
        size = g.slice.stop - g.slice.start
        for j in range(size):
            names.append(g.name if size == 1 else f"{g.name}_{AXES[j]}")
            groups.append(g.name)
    return names, groups


def observability(inputs: TuneInputs, base: Tuning, *, low: float = LOW, high: float = HIGH) -> ObservabilityReport:
    """The observability report of the flight ``inputs`` under the tuning ``base`` (module
    docstring): one forward run with every group estimated, the RTS smoother, the prior
    propagation. The run re-opens no camera misalignment (`nav.recovery`): a re-opening adds
    variance that is the recovery's, not the flight's information."""
    if not 0.0 <= low <= high <= 1.0:
        raise ValueError(f"observability thresholds: expected 0 <= low <= high <= 1, got low={low}, high={high}")
    res = run(inputs.imu, inputs.init, replace(estimated_everywhere(base), recovery_gated_vectors=0),
              gps=inputs.gps, vectors=inputs.vectors,
              R_bc=inputs.R_bc, lever_b=inputs.lever_b, store_for_smoother=True, unaided=False)
    sm = rts_smooth(res)
    P0 = prior_variances(res.store, res.P_full)
    t_s = (np.asarray(sm.t_ns, np.int64) - int(sm.t_ns[0])) / NS
    names, groups = state_names(res.layout)
    base_layout = build_layout(base, len(inputs.R_bc))
    modes = ["E" if e else "C" for e in base_layout.estimated_mask]
    notes = ([f"{len(res.recoveries)} re-initialisations from GPS in the report's run ("
              + ", ".join(sorted({r[1] for r in res.recoveries})) + ")"] if res.recoveries else [])
    return ObservabilityReport(t_s, int(sm.t_ns[0]), names, groups, modes, P0, np.asarray(res.P_diag, float),
                               np.asarray(sm.P, float), variance_reduction(t_s, sm.P, P0), low, high, notes)


# ------------------------------------------------------------------------------------------------
# output: CSV, HTML, PNG
# ------------------------------------------------------------------------------------------------

def _html(rep: ObservabilityReport, pngs: list) -> str:
    import html
    rows = rep.rows()
    keys = list(rows[0])
    head = "".join(f"<th>{k}</th>" for k in keys)
    body = []
    for r in rows:
        cls = {"consider": ' class="consider"', "estimate": ' class="estimate"'}.get(r["flag"], "")
        cells = "".join(f"<td>{r[k]:.4g}</td>" if isinstance(r[k], float) else f"<td>{html.escape(str(r[k]))}</td>"
                        for k in keys)
        body.append(f"<tr{cls}>{cells}</tr>")
    figs = "".join(f'<h3>{html.escape(p.stem)}</h3><img src="{html.escape(p.name)}">' for p in pngs)
    notes = "".join(f"<p>{html.escape(n)}</p>" for n in rep.notes)
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>Observability</title><style>"
            "body{font-family:sans-serif}td,th{padding:2px 8px;text-align:right}"
            "tr.consider{background:#fdd}tr.estimate{background:#dfd}</style></head><body>"
            "<h1>Observability: variance reduction by the smoother</h1>"
            f"<p>reduction = 1 - time average of P_smoothed / P_prior (P_prior: the filter's covariance without "
            f"measurement updates). Red: estimated, reduction &lt; {100 * rep.low:.0f} % (candidate for "
            f"consideration); green: considered, reduction &ge; {100 * rep.high:.0f} % (candidate for "
            f"estimation).</p><p>{html.escape(rep.summary())}</p>{notes}"
            f"<table><tr>{head}</tr>{''.join(body)}</table>{figs}</body></html>\n")


def _plot_group(rep: ObservabilityReport, group: str, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    idx = [i for i, g in enumerate(rep.groups) if g == group]
    unit, f = display_unit(group)
    fig, ax = plt.subplots(figsize=(8, 4))
    for c, i in enumerate(idx):
        col = f"C{c}"
        ax.plot(rep.t_s, f * np.sqrt(rep.P_forward[:, i]), color=col, lw=0.8, ls="--")
        ax.plot(rep.t_s, f * np.sqrt(rep.P_smoothed[:, i]), color=col, lw=1.5,
                label=f"{rep.names[i]} ({100 * rep.reduction[i]:.0f} %)")
        ax.plot(rep.t_s, f * np.sqrt(rep.P_prior[:, i]), color=col, lw=0.6, ls=":")
    ax.set_xlabel("time from the first epoch [s]")
    ax.set_ylabel(f"1-sigma [{unit}]" if unit else "1-sigma")
    ax.set_title(f"{group}: smoothed (solid), forward (dashed), without updates (dotted)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=90)
    plt.close(fig)


def write_report(rep: ObservabilityReport, directory) -> list:
    """Write ``observability.csv``, one ``sigma_<group>.png`` per group and ``observability.html``
    into ``directory`` (created), each atomically. Returns the paths."""
    from scenarios.atomic import atomic_output, atomic_write_text
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    out = [atomic_write_text(d / "observability.csv", rep.csv())]
    pngs = []
    for g in dict.fromkeys(rep.groups):
        pngs.append(atomic_output(d / f"sigma_{g}.png", lambda tmp, g=g: _plot_group(rep, g, tmp)))
    out += pngs
    out.append(atomic_write_text(d / "observability.html", _html(rep, pngs)))
    return out
