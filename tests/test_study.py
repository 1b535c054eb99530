"""Studies (scenarios/study): study files, resumable execution, executors, consistency verdicts.

The studies here are small (2-4 runs of the atek coast T+60..T+100/T+150 with the 20 Hz IMU); the
200-run study is docs/studies.md's measurement and ``atek-coast-mc`` in scenarios/library/studies.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from scenarios.errors import UserError
from scenarios.study.execute import finished_runs, run_study
from scenarios.study.metrics import mean_band, nees
from scenarios.study.studyfile import (RunConfig, apply_params, load_base, load_study, run_seed,
                                       study_from_text)

HEAD = """
[study]
name = "{name}"
scenario = "atek"
seed = {seed}
runs = {runs}
{extra}
[set]
"run.t_end_s" = {t_end}
"tuning.accel_white" = 4.903325e-4
"tuning.gyro_white" = 1.454441e-4
"tuning.vector_white" = 1.0e-4
"tuning.init_att_sigma" = 8.726646e-3
"run.init_att_sigma_deg" = 0.5
"""


def study_text(name="t", runs=2, t_end=100.0, extra="", body="", seed=5):
    """A small atek-coast study with the matched tuning (docs/studies.md), as TOML text."""
    return HEAD.format(name=name, runs=runs, t_end=t_end, extra=extra, seed=seed) + body


def write_study(tmp_path, **kw):
    p = tmp_path / f"{kw.get('name', 't')}.toml"
    p.write_text(study_text(**kw))
    return load_study(p)


# ------------------------------------------------------------------------------------------------
# study files
# ------------------------------------------------------------------------------------------------
def test_library_studies_load():
    """The example studies parse and every variant builds (names checked against the dataclasses)."""
    assert load_study("atek-coast-mc").n_runs == 200
    sim = load_study("atek-sim-mc")
    assert sim.n_runs == 200 and sim.tuning.endswith("atek-sim.toml")
    mis = load_study("atek-mistuned")
    assert [v.label for v in mis.variants][0] == "matched" and len(mis.variants) == 5
    sweep = load_study("atek-camera-sweep")
    assert len(sweep.variants) == 18 and "scenario.cameras.0.rate_hz" in sweep.varied


def test_apply_params_sets_dotted_fields_without_touching_the_base():
    base = load_base(study_from_text(study_text()))
    g0 = base["tuning"].gyro_bias.sigma
    cfg = apply_params(base, {"tuning.gyro_bias.sigma": {"times": 0.1}, "tuning.gyro_bias.mode": "E",
                              "scenario.cameras.1.rate_hz": 2.0, "scenario.gps.outages_s": [[100.0, 120.0]],
                              "run.t_end_s": 150.0})
    assert cfg["tuning"].gyro_bias.sigma == pytest.approx(0.1 * g0)
    assert cfg["tuning"].gyro_bias.mode == "E"
    assert cfg["scenario"].cameras[1].rate_hz == 2.0 and cfg["scenario"].cameras[0].rate_hz == 1.0
    assert cfg["scenario"].gps.outages_s == [[100.0, 120.0]]
    assert cfg["run"].t_end_s == 150.0
    assert base["tuning"].gyro_bias.sigma == g0 and base["scenario"].cameras[1].rate_hz == 1.0
    assert base["run"] == RunConfig()


@pytest.mark.parametrize("key, value, words", [
    ("tuning.gyro_bias.sigmaa", "1.0", ["sigmaa", "sigma", "mode"]),
    ("scenario.cameras.5.rate_hz", "2.0", ["index '5'"]),
    ("scenario.imu.rate", "2.0", ["'rate'", "rate_hz"]),
    ("filter.gain", "2.0", ["'filter.gain'", "scenario", "tuning", "run"]),
    ("tuning.gyro_bias.mode", "1.0", ["expected a string"]),
    ("scenario.imu.rate_hz", "7.0", ["must divide"]),
])
def test_bad_parameter_is_named(key, value, words):
    with pytest.raises(UserError) as e:
        study_from_text(study_text(body=f'[[variants]]\n"{key}" = {value}\n'), "bad.toml")
    msg = str(e.value)
    assert "bad.toml" in msg
    for w in words:
        assert w in msg, msg


def test_unknown_table_and_key():
    with pytest.raises(UserError, match=r"unknown table \[sweep\]"):
        study_from_text(study_text() + "[sweep]\nx = 1\n")
    with pytest.raises(UserError, match="unknown key study.run;"):
        study_from_text(study_text(extra="run = 3"))


def test_seeds_depend_on_study_seed_and_replicate_only():
    st = study_from_text(study_text(runs=3, body='[grid]\n"run.report_scale" = [1.0, 0.5]\n'))
    specs = st.run_specs()
    assert len(specs) == 6 and len({s.run_id for s in specs}) == 6
    # common random numbers: replicate r has the same seed in every variant
    assert [s.seed for s in specs[:3]] == [s.seed for s in specs[3:]]
    assert specs[1].seed == run_seed(5, 1) == int(np.random.SeedSequence(5, spawn_key=(1,)).generate_state(
        2, dtype=np.uint32).view(np.uint64)[0] >> np.uint64(1))
    assert len({s.seed for s in specs[:3]}) == 3


def test_random_draws_are_reproducible():
    body = '[random]\ndraws = 3\n"run.report_scale" = {loguniform = [0.2, 2.0]}\n"tuning.gyro_bias.mode" = {choice = ["E", "C"]}\n'
    a = study_from_text(study_text(body=body))
    b = study_from_text(study_text(body=body))
    assert [v.params for v in a.variants] == [v.params for v in b.variants]
    assert all(0.2 <= v.params["run.report_scale"] <= 2.0 for v in a.variants)


def test_chi_square_band():
    """mean_band against a direct Monte Carlo of the mean of N chi2(3) values (2.5 %/97.5 %)."""
    lo, hi = mean_band(3 * 50, 50)
    rng = np.random.default_rng(0)
    m = rng.chisquare(3, (20000, 50)).mean(1)
    assert np.mean(m < lo) == pytest.approx(0.025, abs=0.004)
    assert np.mean(m > hi) == pytest.approx(0.025, abs=0.004)
    e = rng.normal(size=(5, 3))
    P = np.tile(np.diag([1.0, 4.0, 9.0]), (5, 1, 1))
    assert np.allclose(nees(e, P), np.sum(e ** 2 / [1, 4, 9], 1))


# ------------------------------------------------------------------------------------------------
# bad input before any work
# ------------------------------------------------------------------------------------------------
def test_too_many_runs_need_yes(tmp_path):
    st = write_study(tmp_path, runs=50, extra="max_runs = 100",
                     body='[grid]\n"run.report_scale" = [1.0, 0.5, 0.2]\n')
    out = tmp_path / "out"
    with pytest.raises(UserError, match=r"150 runs .*max_runs = 100.*yes=True"):
        run_study(st, out, workers=0, progress=False)
    assert not out.exists()


def test_unreachable_scheduler(tmp_path):
    st = write_study(tmp_path)
    out = tmp_path / "out"
    with pytest.raises(UserError, match="tcp://127.0.0.1:9.*cannot reach"):
        run_study(st, out, scheduler="tcp://127.0.0.1:9", progress=False)
    assert not out.exists()


def test_cli_reports_bad_study(tmp_path, capsys):
    from scenarios.cli import main
    p = tmp_path / "bad.toml"
    p.write_text(study_text(body='[[variants]]\n"tuning.nope" = 1.0\n'))
    assert main(["study", str(p), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "nope" in err and "Traceback" not in err


def test_cli_names_its_options(tmp_path, capsys):
    """The library's messages name its parameters (``yes=True``, ``scheduler = ...``); the command
    re-words them as its options."""
    from scenarios.cli import main
    p = tmp_path / "big.toml"
    p.write_text(study_text(runs=50, extra="max_runs = 100", body='[grid]\n"run.report_scale" = [1.0, 0.5, 0.2]\n'))
    assert main(["study", str(p), "-o", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "pass --yes to run it anyway" in err and "yes=True" not in err
    p = tmp_path / "small.toml"
    p.write_text(study_text())
    assert main(["study", str(p), "-o", str(tmp_path / "o2"), "--scheduler", "tcp://127.0.0.1:9"]) == 2
    err = capsys.readouterr().err
    assert "--scheduler tcp://127.0.0.1:9: cannot reach" in err


# ------------------------------------------------------------------------------------------------
# execution: resume, executors, verdicts
# ------------------------------------------------------------------------------------------------
def _tables(out):
    return pd.read_parquet(out / "metrics.parquet"), pd.read_parquet(out / "series.parquet")


@pytest.fixture(scope="module")
def four_runs(tmp_path_factory):
    """A 4-run study (2 variants x 2 replicates, T+60..T+100), run inline in two halves (resume)."""
    tmp = tmp_path_factory.mktemp("study")
    st = write_study(tmp, name="four", runs=2, body='[grid]\n"run.report_scale" = [1.0, 0.5]\n')
    out = tmp / "inline"
    s1 = run_study(st, out, workers=0, max_runs=2, progress=False)
    assert s1["runs_done_now"] == 2 and s1["runs_remaining"] == 2
    assert not (out / "metrics.parquet").exists()
    first = {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.parquet")}
    s2 = run_study(st, out, workers=0, progress=False)
    return st, out, first, s2


def test_resume_skips_finished_runs(four_runs):
    st, out, first, s2 = four_runs
    assert s2["runs_done_now"] == 2 and s2["runs_skipped"] == 2 and s2["runs_remaining"] == 0
    # the first half's files were not rewritten
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.parquet") if p.name in first} == first
    assert finished_runs(out) == {s.run_id for s in st.run_specs()}
    met, ser = _tables(out)
    assert set(met.run_id) == {s.run_id for s in st.run_specs()}
    assert {"study", "run_id", "seed", "run.report_scale", "metric", "value"} <= set(met.columns)
    assert {"nees_att", "rms_att_deg", "nis_hor", "psi_c0_err_final_deg"} <= set(met.metric)
    assert {"nees_pos", "nees_att", "nis_gps_pos"} <= set(ser.quantity)
    assert (out / "study.toml").read_text() == st.text
    assert (out / "report.html").exists()


def test_process_pool_gives_identical_tables(four_runs, tmp_path):
    st, out, _, _ = four_runs
    s = run_study(st, tmp_path / "pool", workers=2, progress=False, report=False)
    assert s["runs_done_now"] == 4
    a, b = _tables(out), _tables(tmp_path / "pool")
    pd.testing.assert_frame_equal(a[0], b[0])
    pd.testing.assert_frame_equal(a[1], b[1])


def test_dask_local_cluster_gives_identical_tables(four_runs, tmp_path):
    from dask.distributed import Client, LocalCluster
    st, out, _, _ = four_runs
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None) as cl, \
            Client(cl) as client:
        s = run_study(st, tmp_path / "dask", client=client, progress=False, report=False)
    assert s["executor"] == "dask" and s["runs_done_now"] == 4
    a, b = _tables(out), _tables(tmp_path / "dask")
    pd.testing.assert_frame_equal(a[0], b[0])
    pd.testing.assert_frame_equal(a[1], b[1])


def test_mistuned_variant_is_flagged(tmp_path):
    """Camera misalignment told at 1/10 of the simulated 1 deg: the attitude errors are ~10 times
    the filter's sigma, NEES far above any band; the report and verdicts.json say so."""
    st = write_study(tmp_path, name="mis", runs=2, t_end=120.0,
                     body='[[variants]]\nname = "matched"\n[[variants]]\nname = "mis 1/10"\n'
                          '"tuning.camera_misalignment.sigma" = {times = 0.1}\n')
    out = tmp_path / "out"
    run_study(st, out, workers=2, progress=False)
    v = json.loads((out / "verdicts.json").read_text())
    assert v["mis 1/10"]["consistent"] is False
    assert "att NEES" in v["mis 1/10"]["text"] and "optimistic" in v["mis 1/10"]["text"]
    page = (out / "report.html").read_text()
    assert "INCONSISTENT" in page and "mis 1/10" in page
    # both readings of the attitude band in the summary; the optimistic variant's runs sit above
    # the band of one chi2(3) value far more often than the 2.5 % of a consistent filter
    assert "att in band, mean" in page and "att in band, per run" in page
    from scenarios.study.report import run_band_fraction
    ser = pd.read_parquet(out / "series.parquet")
    labels = pd.read_parquet(out / "metrics.parquet").drop_duplicates("variant").set_index("variant_label").variant
    assert run_band_fraction(ser, int(labels["mis 1/10"]))["all"]["above"] > 0.25
    assert run_band_fraction(ser, int(labels["matched"]))["all"]["above"] < 0.10
    met = pd.read_parquet(out / "metrics.parquet")
    att = met[met.metric == "nees_att"].groupby("variant_label").value.mean()
    assert att["mis 1/10"] > 5 * att["matched"]


def test_white_vector_noise_is_drawn_as_told(tmp_path):
    """Matched by construction: with ``run.white_sigma`` < 0 (default) the runner draws the
    tuning's ``vector_white`` per tangent axis on top of the Gauss-Markov vision error, from its own
    stream (the GM draws are unchanged). With ~120 vectors (T+60..T+100) of 2 tangent axes, n ~ 240
    samples, the sample sigma of the added error has a relative standard error of 1/sqrt(2 n) ~ 4.5 %:
    within 20 % of the told one (4.4 standard errors)."""
    from scenarios.sim import simulate as S
    from scenarios.study.runner import cached_truth, simulated_vectors, white_sigma
    from scenarios.study.studyfile import build_variant
    st = write_study(tmp_path, t_end=100.0)
    cfg = build_variant(st, st.variants[0])
    sc, tun, rc = cfg["scenario"], cfg["tuning"].with_(vector_white=1e-3), cfg["run"]
    assert rc.white_sigma < 0 and white_sigma(rc, tun) == 1e-3
    tr = cached_truth(sc, rc.t_end_s)
    cams = S.simulate_cameras(sc, tr, 11)
    a = simulated_vectors(sc, tr, cams, 11, rc, white=0.0)
    b = simulated_vectors(sc, tr, cams, 11, rc, white=white_sigma(rc, tun))
    assert np.array_equal(a.t_ns, b.t_ns) and np.array_equal(a.P_c, b.P_c) and len(a.t_ns) > 100
    d = b.e_c - a.e_c
    along = np.einsum("ki,ki->k", d, a.e_c)
    assert np.max(np.abs(along)) < 1e-5            # tangent to the sphere (second order: ~sigma^2)
    sig = np.sqrt(np.mean(np.sum(d ** 2, 1)) / 2)   # per tangent axis
    assert abs(sig / 1e-3 - 1) < 0.2, sig


def _interrupt_study(st, tmp_path, jobs: str):
    """Run the study CLI, send SIGINT once a run has finished; returns (out, finished files with
    their mtimes, returncode, stderr)."""
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    study = tmp_path / "four.toml"
    study.write_text(st.text)
    out = tmp_path / "interrupted"
    cmd = [sys.executable, "-m", "scenarios.cli", "study", str(study), "-o", str(out), "-j", jobs,
           "--no-progress", "--yes"]
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if len(list((out / "runs").glob("*.parquet"))) >= 1:
            break
        time.sleep(0.05)
    sent = proc.poll() is None
    if sent:
        proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert sent, f"the study finished before it could be interrupted: {err}"
    done = {p.name: p.stat().st_mtime_ns for p in (out / "runs").glob("*.parquet")}
    assert not list((out / "runs").glob(".*.tmp")), "a partial run file was left behind"
    return out, done, proc.returncode, err


def test_sigint_then_resume_gives_the_same_table(four_runs, tmp_path):
    """A real interruption: the CLI is stopped with SIGINT once some runs have finished (in-process
    executor, -j 0). It finishes the run under way, starts no other, exits with 130 and no
    traceback; the restart skips the finished runs and the final table equals the uninterrupted
    one (four_runs)."""
    st, out_ref, _, _ = four_runs
    out, done, code, err = _interrupt_study(st, tmp_path, "0")
    assert 1 <= len(done) < 8, "expected an interrupted study with some runs finished"
    assert len(done) % 2 == 0, "a run is finished when both its files exist: the run under way finishes"
    assert not (out / "metrics.parquet").exists()
    assert code == 130 and "Traceback" not in err
    assert "finishing the runs under way" in err and "interrupted" in err.splitlines()[-1]
    _resume_equals(st, out, out_ref, done)


def test_sigint_on_a_process_pool_finishes_the_runs_under_way(four_runs, tmp_path):
    """SIGINT to the study CLI on a 2-process pool (-j 2): the workers ignore it (no run dies
    half-way), the parent waits for the runs under way, exits with 130 and no traceback; the
    resumed study equals the uninterrupted one."""
    st, out_ref, _, _ = four_runs
    out, done, code, err = _interrupt_study(st, tmp_path, "2")
    assert 2 <= len(done) <= 8 and len(done) % 2 == 0
    assert not (out / "metrics.parquet").exists()
    assert code == 130 and "Traceback" not in err and "finishing the runs under way" in err
    _resume_equals(st, out, out_ref, done)


def _resume_equals(st, out, out_ref, done):
    s = run_study(st, out, workers=0, progress=False)
    assert s["runs_skipped"] >= 1 and s["runs_remaining"] == 0
    # finished runs were not redone
    assert {k: v for k, v in ((p.name, p.stat().st_mtime_ns) for p in (out / "runs").glob("*.parquet"))
            if k in done} == done
    a, b = _tables(out_ref), _tables(out)
    pd.testing.assert_frame_equal(a[0], b[0])
    pd.testing.assert_frame_equal(a[1], b[1])
