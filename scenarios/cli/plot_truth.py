"""``horizon-nav plot-truth SCENARIO -o fig.png``: height, speed, attitude, body rates and specific
force of a simulated flight, laid out like 003 figs. 30, 31, 34 and 35 (grey: RCS firing)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nav import earth
from nav.rotation import quat_to_matrix
from scenarios.errors import UserError
from scenarios.sim.scenario import G0, load_scenario
from scenarios.sim.truth import Truth, simulate_truth

NAME = "plot-truth"
HELP = "plot the simulated truth of a scenario (height, speed, attitude, body rates, specific force) to a PNG"


def add_arguments(p) -> None:
    p.add_argument("scenario", help="library scenario name or .toml file")
    p.add_argument("-o", "--output", required=True, help="output PNG")
    p.add_argument("--duration", type=float, default=None, help="simulated time [s] (default: the scenario's)")


def _shade(ax, t, on):
    """Grey spans where ``on`` is True (RCS firing, 003 figs. 31, 34, 35)."""
    d = np.diff(np.r_[0, on.astype(int), 0])
    for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)):
        ax.axvspan(t[a], t[min(b, len(t) - 1)], color="0.85", lw=0)


def plot_truth(tr: Truth, path: Path, title: str = "", coast=(60.0, 430.0)) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lat, lon, h = tr.geodetic()
    speed = np.linalg.norm(tr.v_e, axis=1)
    step = max(1, len(tr.t) // 20000)
    s = slice(None, None, step)
    t = tr.t[s]
    c = (t >= coast[0]) & (t <= min(coast[1], t[-1]))
    R_eb = quat_to_matrix(tr.q_eb[s][c])
    R_ne = np.swapaxes(earth.R_en(lat[s][c], lon[s][c]), -1, -2)
    R_nb = R_ne @ R_eb
    elev = np.degrees(-np.arcsin(np.clip(R_nb[:, 2, 0], -1, 1)))
    azim = np.degrees(np.arctan2(R_nb[:, 1, 0], R_nb[:, 0, 0]))
    roll = np.degrees(np.arctan2(R_nb[:, 2, 1], R_nb[:, 2, 2]))
    rcs = np.any(tr.rcs[s][c] != 0, axis=1)
    tc = t[c]
    fig, axes = plt.subplots(3, 2, figsize=(13, 10), constrained_layout=True)
    ax = axes[0, 0]
    ax.plot(t, h[s] / 1e3, "C0")
    ax.set_ylabel("height [km]", color="C0")
    ax2 = ax.twinx()
    ax2.plot(t, speed[s] / 1e3, "C1")
    ax2.set_ylabel("speed [km/s]", color="C1")
    ax.set_title("height and speed (003 fig. 30)")
    ax = axes[0, 1]
    ax.plot(t, np.degrees(tr.omega_ib_b[s, 0]) / 360.0, "C0")
    ax.set_ylabel("roll rate [Hz]")
    ax.set_title("spin about x_b (ascent), yo-yo despin")
    ax.set_xlim(0, min(70.0, t[-1]))
    ax = axes[1, 0]
    _shade(ax, tc, rcs)
    for v, lab in ((roll, "roll"), (azim, "azimuth"), (elev, "elevation")):
        ax.plot(tc, v, label=lab)
    ax.set_ylabel("angle [deg]")
    ax.legend(loc="best")
    ax.set_title("roll, azimuth, elevation in the coast (003 fig. 31)")
    ax = axes[1, 1]
    _shade(ax, tc, rcs)
    for j, lab in enumerate("xyz"):
        ax.plot(tc, np.degrees(tr.omega_ib_b[s][c, j]), label=f"{lab}_b")
    ax.set_ylabel("body rate [deg/s]")
    ax.legend(loc="best")
    ax.set_title("body rates in the coast (003 fig. 35)")
    ax = axes[2, 0]
    _shade(ax, tc, rcs)
    for j, lab in enumerate("xyz"):
        ax.plot(tc, tr.f_b[s][c, j] / G0 * 1e3, label=f"{lab}_b")
    ax.set_ylabel("specific force [mg]")
    ax.set_ylim(-10, 10)
    ax.legend(loc="best")
    ax.set_title("specific force in the coast (003 fig. 34; drag at the ends)")
    ax = axes[2, 1]
    ax.plot(t, np.linalg.norm(tr.f_b[s], axis=1) / G0, "C3")
    ax.set_ylabel("|specific force| [g]")
    ax.set_title("specific force, whole flight")
    for a in axes.ravel():
        a.set_xlabel("T+ [s]")
        a.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def run(args) -> int:
    out = Path(args.output)
    if out.suffix.lower() != ".png":
        raise UserError(f"-o {out}: expected a .png file name")
    sc = load_scenario(args.scenario)
    tr = simulate_truth(sc, args.duration)
    plot_truth(tr, out, title=f"{sc.name}: simulated truth", coast=(sc.spin.motor_separation_s, sc.rcs.end_s))
    print(out)
    return 0
