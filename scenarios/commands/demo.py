"""``horizon-nav demo``: the main job on the built-in default scenario (what ``make demo`` runs)."""
from __future__ import annotations


from nav import timescales
from scenarios.commands import ephem

NAME = "demo"
HELP = "run the most complete pipeline available on the built-in ATEK scenario"


def add_arguments(p) -> None:
    p.add_argument("-o", "--output-dir", default="logs", help="where outputs go (default logs/)")


def run(args) -> int:
    t0 = timescales.parse_utc("2019-06-13T02:21:00Z")
    print("horizon-nav demo: the flight simulator and replay are not built yet; this demo shows the")
    print("foundation: where the Sun and Moon were for the ATEK/MAPHEUS-8 flight (003 §7).\n")
    for label, dt, h in (("lift-off, Esrange, ground", 0, 0.0), ("T+171 s, 230 km (003 §7.4 TRIAD epoch)", 171, 230e3)):
        print(f"== {label}")
        ephem.run(type("A", (), {"time": timescales.format_utc(t0 + dt * timescales.NS_PER_S), "lat": 67.89,
                                  "lon": 21.10, "height": h, "dut1": 0.0, "json": False})())
        print()
    return 0
