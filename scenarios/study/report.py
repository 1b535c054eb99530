"""Consistency and accuracy report of a finished study: static HTML with PNG plots (matplotlib Agg).

``OUT/report.html`` opens in any browser without the tool; the plots are in ``OUT/plots/``.
Per variant: the Monte Carlo averaged NEES of position, velocity, attitude (and the camera
misalignments) over time with the 95 % chi-square band of an N-run average (:func:`scenarios.
study.metrics.mean_band`), the NIS per measurement kind likewise, the RMS error against the
predicted sigma per state group, and the misalignment convergence (RMS error over the runs and
the mean 3-sigma). Across variants: the time-averaged NEES with its band and the accuracy
metrics against each varied parameter.

Verdict per variant (:func:`verdicts`): *consistent* when the time average of the MC-averaged
NEES of every group (pos, vel, att) lies inside the band; otherwise *inconsistent* with the group
and the direction: "optimistic" (NEES above the band: the filter's covariance is too small) or
"pessimistic" (below).
"""
from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np
import pandas as pd

from scenarios.atomic import atomic_output, atomic_write_text
from scenarios.study.metrics import mean_band

NEES_GROUPS = ("pos", "vel", "att")


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(fig, path: Path) -> str:
    atomic_output(path, lambda p: fig.savefig(p, dpi=90, format="png", bbox_inches="tight"))
    _plt().close(fig)
    return f"plots/{path.name}"


def mc_series(ser: pd.DataFrame, variant: int, quantity: str) -> pd.DataFrame:
    """Per 1-s epoch: MC mean of ``quantity`` over the runs of ``variant``, runs, dof sum, band."""
    s = ser[(ser.variant == variant) & (ser.quantity == quantity)]
    if s.empty:
        return pd.DataFrame(columns=["t_s", "mean", "runs", "dof", "lo", "hi", "rms"])
    g = s.groupby("t_s")
    if quantity.startswith("nis_"):
        # value is a per-bin mean of count = dof / d values: weight by the count
        d = 3.0 if quantity.startswith("nis_gps") else 2.0
        cnt = s.dof / d
        tmp = pd.DataFrame({"t_s": s.t_s, "w": s.value * cnt, "cnt": cnt, "dof": s.dof})
        a = tmp.groupby("t_s").sum()
        out = pd.DataFrame({"t_s": a.index, "mean": a.w / a.cnt, "runs": g.size().values, "dof": a.dof.values,
                            "count": a.cnt.values})
        lo, hi = mean_band(out.dof.values, out["count"].values)
    else:
        out = pd.DataFrame({"t_s": g.size().index, "mean": g.value.mean().values, "runs": g.size().values,
                            "dof": g.dof.sum().values, "rms": np.sqrt(g.value.apply(lambda v: np.mean(v ** 2))).values})
        lo, hi = mean_band(np.maximum(out.dof.values, 1e-9), out.runs.values)
    out["lo"], out["hi"] = lo, hi
    return out.reset_index(drop=True)


def band_fraction(ser: pd.DataFrame, variant: int, quantity: str = "nees_att", windows=()) -> dict:
    """Where the MC mean of ``quantity`` lies against its 95 % band (:func:`mc_series`, the band of
    an N-run mean of chi2(3) values, ``chi2(3N)/N``), over all its 1-s epochs and per window.

    Returns ``{"all": row, (t0, t1): row, ...}``, each row a dict with ``inside``, ``above``
    (optimistic: the filter's covariance too small) and ``below`` (pessimistic) as fractions of
    the epochs, ``mean`` the time average of the MC mean NEES, and ``epochs``."""
    m = mc_series(ser, variant, quantity)
    return _band_rows(m["mean"].to_numpy(float), m.t_s.to_numpy(float), m.lo.to_numpy(float), m.hi.to_numpy(float),
                      windows)


def run_band_fraction(ser: pd.DataFrame, variant: int, quantity: str = "nees_att", windows=()) -> dict:
    """Where each run's ``quantity`` lies against the 95 % band of one chi2(dof) value
    (``mean_band(dof, 1)``: [0.216, 9.35] for 3 dof), over all its run-epochs and per window: the
    single-run reading of the band, beside :func:`band_fraction`'s N-run mean.

    A consistent filter puts 95 % of its run-epochs inside and 2.5 % on either side, whatever N;
    the N-run mean's band narrows as 1/sqrt(N), so there a filter a few per cent cautious falls
    below it once N is large, and because one run's NEES stays correlated for minutes, the share
    of epochs inside varies strongly from one seed set to the next (docs/performance.md "The NEES
    band at 200 and 1000 runs"). Returns rows as :func:`band_fraction` (``inside``, ``above``,
    ``below`` fractions of the run-epochs, ``mean``, ``epochs``: run-epochs counted)."""
    s = ser[(ser.variant == variant) & (ser.quantity == quantity)]
    lo, hi = mean_band(np.maximum(s.dof.to_numpy(float), 1e-9), np.ones(len(s)))
    return _band_rows(s.value.to_numpy(float), s.t_s.to_numpy(float), lo, hi, windows)


def _band_rows(v, t, lo, hi, windows) -> dict:
    """The rows of :func:`band_fraction` and :func:`run_band_fraction`: values ``v`` at times
    ``t`` [s] against their bands ``lo``..``hi``, over all of them and per window (t0, t1)."""
    out = {}
    for key in ["all", *windows]:
        w = np.ones(len(v), bool) if key == "all" else (t >= key[0]) & (t < key[1])
        n = max(int(w.sum()), 1)
        out[key] = {"inside": float(np.sum((v >= lo) & (v <= hi) & w) / n), "above": float(np.sum((v > hi) & w) / n),
                    "below": float(np.sum((v < lo) & w) / n), "mean": float(v[w].mean()) if w.any() else float("nan"),
                    "epochs": int(w.sum())}
    return out


def verdicts(ser: pd.DataFrame, variants) -> dict:
    """variant -> {"consistent": bool, "groups": {g: (time-avg NEES, lo, hi, status)}, "text": str}."""
    out = {}
    for v in variants:
        groups = {}
        for g in NEES_GROUPS:
            m = mc_series(ser, v, f"nees_{g}")
            if m.empty:
                continue
            n = int(m.runs.max())
            lo, hi = mean_band(3 * n, n)
            avg = float(m["mean"].mean())
            status = "inside" if lo <= avg <= hi else ("optimistic" if avg > hi else "pessimistic")
            groups[g] = (avg, float(lo), float(hi), status, n)
        bad = [f"{g} NEES {a:.2f} {st} (band {lo:.2f}..{hi:.2f})" for g, (a, lo, hi, st, _) in groups.items()
               if st != "inside"]
        ok = bool(groups) and not bad
        out[v] = {"consistent": ok, "groups": groups,
                  "text": "CONSISTENT: NEES of " + ", ".join(groups) + " inside the 95 % band" if ok
                  else "INCONSISTENT: " + "; ".join(bad) if bad else "no NEES series"}
    return out


def _fmt(x) -> str:
    if isinstance(x, (float, np.floating)):
        return "nan" if not np.isfinite(x) else f"{x:.4g}"
    return html.escape(str(x))


def _table(df: pd.DataFrame) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in df.columns)
    rows = "".join("<tr>" + "".join(f"<td>{_fmt(v)}</td>" for v in r) + "</tr>" for r in df.itertuples(index=False))
    return f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"


def write_report(out_dir) -> Path:
    """Write ``OUT/report.html`` and ``OUT/plots/*.png`` from ``metrics.parquet`` / ``series.parquet``."""
    plt = _plt()
    out_dir = Path(out_dir)
    plots = out_dir / "plots"
    plots.mkdir(exist_ok=True)
    met = pd.read_parquet(out_dir / "metrics.parquet")
    ser = pd.read_parquet(out_dir / "series.parquet")
    study_text = (out_dir / "study.toml").read_text(encoding="utf-8") if (out_dir / "study.toml").exists() else ""
    timing = json.loads((out_dir / "timing.json").read_text()) if (out_dir / "timing.json").exists() else {}
    name = str(met.study.iloc[0]) if len(met) else "study"
    labels = met.drop_duplicates("variant").set_index("variant").variant_label.to_dict()
    variants = sorted(labels)
    fixed_cols = {"study", "run_id", "run_index", "variant", "variant_label", "replicate", "seed", "metric", "value"}
    params = [c for c in met.columns if c not in fixed_cols]
    ver = verdicts(ser, variants)
    wide = met.pivot_table(index=["variant", "run_id"], columns="metric", values="value").reset_index()
    body = [f"<h1>Study {html.escape(name)}</h1>",
            f"<p>{len(variants)} variant(s), {met.run_id.nunique()} runs. "
            + (f"Wall time {timing.get('wall_s', float('nan')):.1f} s, {timing.get('runs_per_minute') or float('nan'):.1f} "
               f"runs/min on {timing.get('workers')} {timing.get('executor')} worker(s)." if timing else "")
            + "</p>",
            "<p>NEES: Monte Carlo average over the runs at the first filter epoch of every second, "
            "95 % band chi2(3N)/N for N runs; a variant is consistent when the time average of each "
            "group's averaged NEES lies inside the band (scenarios/study/report.py). 'att in band, mean': "
            "the share of the 1-s epochs whose averaged attitude NEES lies in that band; 'att in band, "
            "per run': the share of the runs' epochs whose own NEES lies in the band of one chi2(3) value "
            "(0.216..9.35), with the shares above and below it. A consistent filter's expected share is 0.95 "
            "under both; the first scatters from one seed set to the next when the runs' NEES is "
            "correlated over time, and narrows with N (docs/performance.md).</p>"]
    # summary table
    rows = []
    for v in variants:
        r = {"variant": v, "label": labels[v], "verdict": "consistent" if ver[v]["consistent"] else "INCONSISTENT"}
        for g, (a, lo, hi, st, n) in ver[v]["groups"].items():
            r[f"NEES {g}"] = a
        r["band"] = (f"{next(iter(ver[v]['groups'].values()))[1]:.2f}..{next(iter(ver[v]['groups'].values()))[2]:.2f}"
                     if ver[v]["groups"] else "")
        if "att" in ver[v]["groups"]:
            b, rb = band_fraction(ser, v)["all"], run_band_fraction(ser, v)["all"]
            r["att in band, mean"] = b["inside"]
            r["att in band, per run (above / below)"] = f"{rb['inside']:.3f} ({rb['above']:.3f} / {rb['below']:.3f})"
        w = wide[wide.variant == v]
        for k in ("ratio_pos", "ratio_vel", "ratio_att", "rms_att_deg", "att_3sigma_final_deg",
                  "rms_att_smoothed_deg", "psi_c0_err_final_deg"):
            if k in w:
                r[k] = float(np.sqrt(np.mean(w[k] ** 2))) if k.startswith("rms") else float(w[k].mean())
        rows.append(r)
    body.append("<h2>Summary per variant</h2>" + _table(pd.DataFrame(rows)))
    body.append("<ul>" + "".join(f"<li><b>{html.escape(labels[v])}</b>: {html.escape(ver[v]['text'])}</li>"
                                 for v in variants) + "</ul>")
    # comparison across variants
    if len(variants) > 1:
        fig, axs = plt.subplots(1, len(NEES_GROUPS), figsize=(4.2 * len(NEES_GROUPS), 3.4), squeeze=False)
        for ax, g in zip(axs[0], NEES_GROUPS):
            vals = [ver[v]["groups"].get(g, (np.nan, np.nan, np.nan, "", 0)) for v in variants]
            x = np.arange(len(variants))
            col = ["tab:green" if s[3] == "inside" else "tab:red" for s in vals]
            ax.bar(x, [s[0] for s in vals], color=col)
            ax.errorbar(x, [(s[1] + s[2]) / 2 for s in vals], yerr=[(s[2] - s[1]) / 2 for s in vals], fmt="none",
                        ecolor="k", capsize=4, label="95 % band")
            ax.set_yscale("log"); ax.set_title(f"time-averaged NEES {g}")
            ax.set_xticks(x, [labels[v][:18] for v in variants], rotation=30, ha="right", fontsize=7)
        axs[0][0].legend(fontsize=7)
        body.append("<h2>Comparison of variants</h2>"
                    f"<img src='{_save(fig, plots / 'compare_nees.png')}'>")
        for p in params:
            vals = met.drop_duplicates("variant").set_index("variant")[p]
            num = pd.to_numeric(vals, errors="coerce")
            keys = [k for k in ("nees_att", "rms_att_deg", "ratio_att", "rms_pos_m") if k in wide]
            fig, axs = plt.subplots(1, len(keys), figsize=(4.0 * len(keys), 3.2), squeeze=False)
            for ax, k in zip(axs[0], keys):
                per = wide.groupby("variant")[k]
                m, s = per.mean(), per.std().fillna(0) / np.sqrt(per.size())
                if num.notna().all():
                    o = np.argsort(num.values)
                    ax.errorbar(num.values[o], m.reindex(vals.index).values[o], yerr=s.reindex(vals.index).values[o],
                                marker="o", capsize=3)
                    ax.set_xlabel(p)
                else:
                    ax.bar(range(len(vals)), m.reindex(vals.index).values)
                    ax.set_xticks(range(len(vals)), [str(x)[:12] for x in vals.values], rotation=30, fontsize=7)
                ax.set_title(f"{k} (mean +- s.e.)", fontsize=9)
            body.append(f"<h3>Against {html.escape(p)}</h3><img src='{_save(fig, plots / ('param_' + p.replace('.', '_') + '.png'))}'>")
    # per-variant plots
    for v in variants:
        body.append(f"<h2>Variant {v}: {html.escape(labels[v])}</h2><p>{html.escape(ver[v]['text'])}</p>")
        qs = [q for q in ("nees_pos", "nees_vel", "nees_att", "nees_psi_c0", "nees_psi_c1") if (ser.quantity == q).any()]
        if qs:
            fig, axs = plt.subplots(1, len(qs), figsize=(3.6 * len(qs), 3.0), squeeze=False)
            for ax, q in zip(axs[0], qs):
                m = mc_series(ser, v, q)
                ax.semilogy(m.t_s, m["mean"], lw=0.8, label="MC mean")
                ax.plot(m.t_s, m.lo, "k--", lw=0.7); ax.plot(m.t_s, m.hi, "k--", lw=0.7, label="95 % band")
                ax.set_title(q.replace("nees_", "NEES "), fontsize=9); ax.set_xlabel("T+ [s]")
            axs[0][0].legend(fontsize=7)
            body.append(f"<img src='{_save(fig, plots / f'nees_v{v:03d}.png')}'>")
        qs = sorted(q for q in ser.quantity.unique() if q.startswith("nis_"))
        if qs:
            fig, axs = plt.subplots(1, len(qs), figsize=(3.6 * len(qs), 3.0), squeeze=False)
            for ax, q in zip(axs[0], qs):
                m = mc_series(ser, v, q)
                ax.semilogy(m.t_s, m["mean"], lw=0.8)
                ax.plot(m.t_s, m.lo, "k--", lw=0.7); ax.plot(m.t_s, m.hi, "k--", lw=0.7)
                ax.set_title(q.replace("nis_", "NIS "), fontsize=9); ax.set_xlabel("T+ [s]")
            body.append(f"<img src='{_save(fig, plots / f'nis_v{v:03d}.png')}'>")
        groups = [g for g in ("pos_m", "vel_m_s", "att_deg") if (ser.quantity == f"err_{g}").any()]
        if groups:
            fig, axs = plt.subplots(1, len(groups) + 1, figsize=(3.6 * (len(groups) + 1), 3.0), squeeze=False)
            for ax, g in zip(axs[0], groups):
                e = mc_series(ser, v, f"err_{g}")
                s = mc_series(ser, v, f"sigma_{g}")
                ax.plot(e.t_s, e.rms, lw=0.8, label="RMS error")
                ax.plot(s.t_s, np.sqrt(s.rms ** 2), "k--", lw=0.8, label="predicted sigma")
                ax.set_yscale("log"); ax.set_title(g.replace("_", " [", 1) + "]", fontsize=9); ax.set_xlabel("T+ [s]")
            axs[0][0].legend(fontsize=7)
            ax = axs[0][-1]
            w = wide[wide.variant == v]
            ks = [k for k in ("ratio_pos", "ratio_vel", "ratio_att") if k in w]
            ax.bar(range(len(ks)), [w[k].mean() for k in ks]); ax.axhline(1.0, color="k", lw=0.8)
            ax.set_xticks(range(len(ks)), [k[6:] for k in ks]); ax.set_title("RMS error / predicted sigma", fontsize=9)
            body.append(f"<img src='{_save(fig, plots / f'rms_v{v:03d}.png')}'>")
        cams = sorted(q[len("err_psi_c"):-len("_deg")] for q in ser.quantity.unique() if q.startswith("err_psi_c"))
        if cams:
            fig, ax = plt.subplots(figsize=(5.5, 3.2))
            for c in cams:
                e = mc_series(ser, v, f"err_psi_c{c}_deg")
                s = mc_series(ser, v, f"sigma3_psi_c{c}_deg")
                ax.plot(e.t_s, e.rms, lw=0.9, label=f"camera {c}: RMS |error|")
                ax.plot(s.t_s, s["mean"], "--", lw=0.9, label=f"camera {c}: mean 3-sigma (max axis)")
            ax.set_xlabel("T+ [s]"); ax.set_ylabel("deg"); ax.set_title("camera misalignment convergence", fontsize=9)
            ax.legend(fontsize=7)
            body.append(f"<img src='{_save(fig, plots / f'misalignment_v{v:03d}.png')}'>")
    body.append("<h2>Study file</h2><pre>" + html.escape(study_text) + "</pre>")
    css = ("body{font-family:sans-serif;max-width:1400px;margin:1em auto}table{border-collapse:collapse;font-size:12px}"
           "td,th{border:1px solid #bbb;padding:2px 6px}img{max-width:100%}pre{background:#f4f4f4;padding:6px}")
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(name)}</title>"
            f"<style>{css}</style></head><body>" + "\n".join(body) + "</body></html>")
    atomic_write_text(out_dir / "verdicts.json", json.dumps(
        {labels[v]: {"consistent": ver[v]["consistent"], "text": ver[v]["text"]} for v in variants}, indent=1))
    return atomic_write_text(out_dir / "report.html", page)
