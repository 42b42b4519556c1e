"""The steering sweep (``python -m equigym.steer sweep``): job order, the wall-time record of a
resumed sweep, and (where Ray Tune is installed, the ``sweep`` extra) a whole sweep that a
second invocation with ``--resume`` restores without running anything again."""

from __future__ import annotations

import csv
import json
import time

import pytest

from equigym import steer


def test_jobs_are_seed_major_across_both_agents():
    jobs = steer.sweep_jobs(["dsrl", "equi"], [0, 1], ["equi"], [1, 2])
    assert [(j["agent"], j["method"], j["seed"]) for j in jobs] == [
        ("rust", "dsrl", 0),
        ("rust", "equi", 0),
        ("rust", "dsrl", 1),
        ("rust", "equi", 1),
        ("sb3", "equi", 1),
        ("sb3", "equi", 2),
    ]


def test_the_record_adds_up_invocations_and_run_clocks(tmp_path):
    for agent, seconds in (("rust", 12.5), ("sb3", 30.0)):
        d = tmp_path / agent / "lift" / "equi" / "seed0"
        d.mkdir(parents=True)
        (d / "log.csv").write_text(f"env_steps,success_rate,mean_q,seconds\n16,0.5,-1.0,1.0\n32,0.5,-1.0,{seconds}\n")
    path, clocks = tmp_path / "sweep.json", steer.run_clocks(tmp_path)
    steer.record_invocation(path, {"started": "t-1", "wall_seconds": 7.0}, start=True)
    steer.record_invocation(path, {"started": "t0"}, start=True, fresh=True, totals=clocks)  # a new sweep
    steer.record_invocation(path, {"wall_seconds": 100.0}, start=False, totals=clocks)
    steer.record_invocation(path, {"started": "t1"}, start=True, totals=clocks)  # resumed, then killed
    record = json.loads(path.read_text())
    assert [i["started"] for i in record["invocations"]] == ["t0", "t1"]
    assert record["wall_seconds"] == 100.0
    assert record["runs"] == 2 and record["run_seconds"] == 42.5


def test_a_ray_sweep_runs_every_trial_and_a_resumed_one_adds_nothing(tmp_path):
    pytest.importorskip("ray.tune", reason="the sweep extra (Ray Tune) is not installed")
    argv = ["sweep", "--methods", "dsrl", "--seeds", "0", "--steps", "64", "--eval-every", "32"]
    argv += ["--eval-episodes", "2", "--cpus", "1", "--out", str(tmp_path)]
    steer.main(argv)
    log = tmp_path / "rust" / "lift" / "dsrl" / "seed0" / "log.csv"
    with open(log) as f:
        rows = list(csv.DictReader(f))
    assert [int(r["env_steps"]) for r in rows][-2:] == [32, 64]
    before = log.read_text()
    experiment = tmp_path / "tune" / "steer"
    trials = sorted(p.name for p in experiment.iterdir() if p.is_dir())
    steer.main([*argv, "--resume"])
    assert log.read_text() == before  # restored as finished: nothing evaluated twice
    # Tuner.restore, not a fresh Tuner over the agents' checkpoints: a fresh one would have made
    # a new trial directory (and its own trial ids) beside the first.
    assert sorted(p.name for p in experiment.iterdir() if p.is_dir()) == trials
    record = json.loads((tmp_path / "sweep.json").read_text())
    assert len(record["invocations"]) == 2 and all("wall_seconds" in i for i in record["invocations"])
    assert [i["restored"] for i in record["invocations"]] == [False, True]
    assert record["runs"] == 1


def test_a_grid_is_every_combination_of_run_options():
    grid = steer.parse_grid(["target_entropy=5,10", "noise_aliased=0,1"])
    assert grid == [
        {"target_entropy": 5.0, "noise_aliased": False},
        {"target_entropy": 5.0, "noise_aliased": True},
        {"target_entropy": 10.0, "noise_aliased": False},
        {"target_entropy": 10.0, "noise_aliased": True},
    ]
    assert [steer.config_label(c) for c in grid[:2]] == ["target_entropy-5.0", "target_entropy-5.0_noise_aliased"]
    assert steer.parse_grid(["prior_kl=none,4"]) == [{"prior_kl": None}, {"prior_kl": 4.0}]
    for bad in (["entropy=5"], ["noise_aliased=2"], ["prior_kl=four"], ["prior_kl="]):
        with pytest.raises(SystemExit):
            steer.parse_grid(bad)


def test_an_asha_screen_runs_each_configuration_in_its_own_directory(tmp_path):
    pytest.importorskip("ray.tune", reason="the sweep extra (Ray Tune) is not installed")
    argv = ["screen", "--task", "lift", "--grid", "prior_kl=none,3", "--recipe", "na-tos-h20"]
    argv += ["--steps", "64", "--eval-every", "32", "--grace", "32", "--eval-episodes", "2", "--cpus", "1"]
    steer.main([*argv, "--out", str(tmp_path)])
    runs = sorted(p.relative_to(tmp_path).parts[0] for p in tmp_path.glob("*/lift/dsrl/seed0"))
    # the grid's prior replaces the recipe's target entropy; the recipe's switches stay
    # none keeps the recipe's target entropy; a budget replaces it; the recipe's switches stay
    assert runs == [
        "noise_aliased_terminate_on_success_target_entropy-20.0",
        "prior_kl-3.0_noise_aliased_terminate_on_success",
    ]
    for d in tmp_path.glob("*/lift/dsrl/seed0"):
        meta = json.loads((d / "run.json").read_text())
        assert meta["noise_aliased"] and meta["terminate_on_success"]
        assert ("prior_kl" in meta) != ("target_entropy" in meta)
        with open(d / "log.csv") as f:
            assert [int(r["env_steps"]) for r in csv.DictReader(f)][-1] in (32, 64)
    table = (tmp_path / "screen.md").read_text()
    assert table.count("| seed0 |") == 2


def test_a_trial_that_cannot_finish_by_its_deadline_does_not_start(tmp_path):
    pytest.importorskip("ray.tune", reason="the sweep extra (Ray Tune) is not installed")
    c = {"agent": "rust", "method": "dsrl", "task": "lift", "seed": 0, "steps": 64, "out": str(tmp_path)}
    c |= {"preset": "cpu", "env": {}, "eval_every": 32, "eval_episodes": 2, "policy": None, "ent_init": None}
    # 64 env steps at a minute each do not fit in the ten minutes left: refused before any step
    with pytest.raises(steer.Paused, match="not started"):
        steer.run_trial({**c, "deadline": time.time() + 600, "cost_per_step": 60.0})
    assert not list(tmp_path.iterdir())
    # a run that resumes half-way here needs half as long: 32 steps x 10 s fit in 10 minutes
    d = tmp_path / "lift" / "dsrl" / "seed0"
    d.mkdir(parents=True)
    (d / "summary.json").write_text(json.dumps({"env_steps": 32, "seconds": 1.0}))
    assert steer.resume_steps(d) == 0  # no checkpoint here: it would start over
    with pytest.raises(steer.Paused, match="not started"):
        steer.run_trial({**c, "deadline": time.time() + 600, "cost_per_step": 10.0})
    (d / "checkpoint.bin").write_bytes(b"")
    assert steer.resume_steps(d) == 32
    with pytest.raises(Exception) as started:  # it starts, and reads the (empty) checkpoint
        steer.run_trial({**c, "deadline": time.time() + 600, "cost_per_step": 10.0})
    assert not isinstance(started.value, steer.Paused) and "checkpoint" in str(started.value).lower()
