import math, time, sys, dataclasses
import numpy as np
sys.path.insert(0, ".")
from scenarios.sim.scenario import load_scenario
from scenarios.sim.simulate import simulate_flight
from scenarios.sim.truth_vectors import flight_truth_vectors
from nav.navigator import run
from nav.smoother import rts_smooth
from nav.tuning import Tuning, StateGroupTuning
from tests.test_navigator import flight_inputs, truth_init
t0 = time.time()
sc = load_scenario("atek-nav-grade")
sc = dataclasses.replace(sc, simulation=dataclasses.replace(sc.simulation, horizon_atmosphere_m=10e3))
dur = float(sys.argv[1]) if len(sys.argv) > 1 else 200.0
fl = simulate_flight(sc, seed=3, duration=dur)
print("sim", time.time() - t0)
fi = flight_inputs(fl, 60.0, seed=3)
tv = flight_truth_vectors(fl, edge_ref_m=45e3)
vd = tv.vector_data([c.k for c in fl.cameras])
m = vd.t_ns >= fi.imu.t_ns[fi.start_idx]
from nav.navigator import VectorData
vd = VectorData(vd.t_ns[m], vd.camera[m], vd.target[m], vd.e_c[m], vd.P_c[m], vd.dedge_c[m], vd.edge_ref_m[m])
g = vd.dedge_c[vd.target == "hor"]
print("vectors", len(vd.t_ns), "hor", (vd.target=="hor").sum(), "g deg/km median", np.degrees(np.median(np.linalg.norm(g, axis=1)))*1e3)
print("time", time.time() - t0)
for mode in ("E",):
    tun = Tuning().with_(edge_height=StateGroupTuning(mode, 20e3))
    t1 = time.time()
    res = run(fi.imu, truth_init(fi), tun, gps=fi.gps, vectors=vd, R_bc=fi.R_bc_nominal)
    sm = rts_smooth(res)
    lay = res.layout
    for c in range(2):
        i = lay[lay.edge_name(c)].start
        print(mode, c, "fwd", res.estimates[-1, i], np.sqrt(res.P_diag[-1, i]), "smooth", sm.estimates[0, i], np.sqrt(sm.P[0, i]), sm.estimates[len(sm.estimates)//2, i])
    print("run", time.time() - t1)
    acc = [x.accepted for x in res.innovations if x.kind == "hor"]
    print("hor accepted", np.mean(acc), len(acc))
