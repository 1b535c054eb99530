"""The ATEK flight rendered with Earth edges the front end does not assume, replayed end to end with
an edge-height state per camera (scenarios/study/atek_edge_flight.py): the figures against the
simulator's truth."""
from __future__ import annotations

import pytest

from nav.tuning import tuning_from_toml
from scenarios.study import atek_edge_flight as A
from scenarios.study.edge_mismatch import HEIGHTS_M, PROFILES


def test_study_tuning_estimates_the_edge_height(tmp_path):
    """The study's tuning is atek-sim.toml with the edge-height state estimated, every other
    setting as in atek-sim.toml (the edge Monte Carlo's filter)."""
    base = tuning_from_toml(A.TUNING.read_text(encoding="utf-8"))
    t = tuning_from_toml(A.tuning_file(tmp_path).read_text(encoding="utf-8"))
    assert tuning_from_toml(A.tuning_file(tmp_path, "threshold").read_text(encoding="utf-8")).edge_height_edge == "threshold"
    assert base.edge_height.mode == "off" and t.edge_height.mode == "E"
    assert t.edge_height.sigma == pytest.approx(20e3)   # the vision's limb-prior sigma
    assert t.with_(edge_height=base.edge_height) == base


def test_simulated_log_carries_the_payload_mask(tmp_path):
    """What the study renders is what `horizon-nav simulate --images` writes: the ATEK renderer
    draws the payload, and the log carries each camera's mask of it (without it the vision took
    the payload's edge for the horizon: 265 of 364 frames found on camera 2, errors to 1.3 deg)."""
    from scenarios.cli.simulate import rendered_images
    from scenarios.sim.render import payload_mask, scenario_render_options
    from scenarios.sim.scenario import load_scenario
    from scenarios.sim.simulate import simulate_flight

    fl = simulate_flight(load_scenario("atek"), 0, duration=2.0)
    opts = scenario_render_options(fl.scenario)
    assert opts.payload_mask is not None
    _, masks = rendered_images(fl, opts, progress=False)
    assert sorted(masks) == sorted(c.k for c in fl.cameras)
    for c in fl.cameras:
        m = masks[c.k]
        assert m.shape == (c.camera.height, c.camera.width) and 0 < m.mean() < 0.5
        assert (m == payload_mask(c.camera, opts.payload_mask)).all()


@pytest.fixture(scope="module")
def study_rows():
    return A.run_study()


@pytest.mark.slow
def test_atek_edge_flight_contains_before_learning(study_rows):
    """Issue 22 item 3 on the whole rendered ATEK flight (0-60 km, two limb profiles, front-end
    defaults), per camera and case: every case is replayed, and the per-frame 3-sigma
    containment with the height uncertainty the vision had is >= 0.97 (measured 0.99-1.00)."""
    assert len(study_rows) == 2 * len(HEIGHTS_M) * len(PROFILES)
    for r in study_rows:
        assert r["containment_prior"] >= 0.97, (r["case"], r["camera"])


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue 22 item 3 on the rendered ATEK flight: the learned limb-edge height "
                   "is 3.3-5.6 km from the fits' own on 4 of 20 camera-cases (all camera 2) and the nadir at it "
                   "0.07-0.48 deg RMS (limit 0.05) everywhere but the renderer's own 45 km edge; at the fits' own "
                   "height the limb-edge frames alone are at 0.05-0.38 deg (docs/vision.md)")
def test_atek_edge_flight_learns_the_edge(study_rows):
    """After learning: the smoothed edge height within 3 km of the height the frames' fits have,
    the nadir at it RMS <= 0.05 deg, containment >= 0.97, in every case."""
    for r in study_rows:
        tag = (r["case"], r["camera"])
        assert abs(r["edge_smoothed_km"] - r["edge_truth_km"]) <= 3.0, (tag, r)
        assert r["nadir_rms_deg"] <= 0.05 and r["containment"] >= 0.97, (tag, r)
