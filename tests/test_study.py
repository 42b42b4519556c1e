"""The study (``python -m equigym.study``): which runs its parts need, a report that pairs each
run with the base policy of its own seed and runs nothing itself, and (where Ray Tune is
installed) a smoke-sized study that stops at its deadline, resumes with the same command and,
restored once more, runs nothing again."""

from __future__ import annotations

import csv
import json
import math
import shutil

import pytest

from equigym import _core, study
from equigym.study import report as study_report


def test_a_cell_two_parts_need_is_run_once_and_jobs_are_seed_major():
    cells = study.cells_of(["table1", "dial"])
    names = [c.name for c in cells]
    assert names.count("lift") == 1 and names[:3] == ["lift", "stack", "square"]
    assert {c.dial for c in cells if c.dial is not None} == {0.6, 0.8, 1.0, 1.25, math.inf}
    only = study.cells_of(["table1", "dial"], only=["lift-scale0.6", "lift"])
    assert [c.name for c in only] == ["lift", "lift-scale0.6"]  # the parts' order, only those named
    jobs = study.jobs(study.cells_of(["controller"], methods=["dsrl"]))
    assert [(j["cell"], j["seed"]) for j in jobs[:3]] == [("lift", 0), ("lift-cartesian-nolimits", 0), ("lift", 1)]
    assert sum(j["cell"] == "lift" for j in jobs) == 5 and sum(j["cell"] != "lift" for j in jobs) == 3
    utd = study.cells_of(["critic"])[1]
    config = study.trial_config(utd, study.jobs([utd])[0], study.ROOT)
    assert config["utd"] == 30 and "utd" not in study.trial_config(cells[0], jobs[0], study.ROOT)
    square = study.CELLS["square"]
    assert study.trial_config(square, study.jobs([square])[0], study.ROOT)["edp_kernel"] == "fourier"
    # every cell names its kernel: the runtime's default is not what the cells begun before it ran
    assert study.trial_config(cells[0], jobs[0], study.ROOT)["edp_kernel"] == "dense"
    quick = study.cells_of(["dial"], quick=True)
    assert all(c.steps == 64 and c.seeds == (0,) for c in quick)


def _fake_run(root, cell, method, seed, rates):
    d = cell.out(root) / cell.task / method / f"seed{seed}"
    d.mkdir(parents=True)
    steps = [cell.steps * k // (len(rates) - 1) for k in range(len(rates))]  # the last at the budget
    with open(d / "log.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["env_steps", "success_rate", "mean_q", "seconds"])
        w.writerows([s, r, -1.0, 1.0] for s, r in zip(steps, rates))
    with open(d / "train.csv", "w", newline="") as f:  # training starts after the first evaluation
        w = csv.writer(f)
        w.writerow(["env_steps", "alpha"])
        w.writerows([s, 0.1 if k == 0 else 0.2] for k, s in enumerate(steps))
    meta = {"method": method, "task": cell.task, "seed": seed, "policy": cell.policy_path(), "agent": "rust"}
    meta |= {"eval_every": cell.eval_every, "eval_episodes": 10, "joint_limits": True}
    (d / "run.json").write_text(json.dumps(meta))


def test_the_report_pairs_each_run_with_its_own_seeds_base_and_runs_nothing(tmp_path, monkeypatch):
    cell = study.CELLS["lift"]
    _fake_run(tmp_path, cell, "dsrl", 0, [0.5, 0.9, 0.6, 0.7, 0.8])  # final 0.7, peak 0.9
    _fake_run(tmp_path, cell, "dsrl", 1, [0.5, 0.4, 0.3, 0.3, 0.3])  # final 0.3, peak 0.4
    _fake_run(tmp_path, cell, "equi", 0, [0.5, 0.5])  # the budget not reached yet: not counted
    log = cell.out(tmp_path) / "lift" / "equi" / "seed0" / "log.csv"
    log.write_text(log.read_text().replace(f"{cell.steps},", f"{cell.steps // 2},"))
    base = {0: 0.6, 1: 0.4}

    def evaluate_base(task, *, seed, scale, episodes, policy, edp_kernel, env, threads):
        assert edp_kernel == "dense", "a run.json that names no kernel ran dense"
        rate = base[seed] * scale
        return {
            "seed": seed,
            "scale": scale,
            "successes": round(rate * episodes),
            "episodes": episodes,
            "success_rate": rate,
        }

    monkeypatch.setattr(_core, "evaluate_base", evaluate_base)
    study.run_controls([cell], tmp_path, threads=1)
    monkeypatch.setattr(_core, "evaluate_base", lambda *a, **k: pytest.fail("the report evaluated"))
    data = study_report.load_cell(cell, tmp_path)
    assert [r["figures"]["peak"] for r in data["runs"]["dsrl"]] == [0.9, 0.4] and "equi" not in data["runs"]
    assert study_report.gains(data, "dsrl") == pytest.approx([0.7 - 0.6, 0.3 - 0.4])
    report = study_report.write(tmp_path)
    # the Lift row of the final table: the base 0.5 +- 0.1 over two seeds, DSRL 0.5 +- 0.2
    assert (
        f"| Lift ({cell.steps:,} steps) | 0.500 +- 0.100 (2) [0.617] | 0.250 +- 0.050 (2) (s = 0.5) | 0.500 +- 0.200 (2) |"
        in report
    )
    assert "0.650 +- 0.250 (2) [0.808]" in report  # peak, beside the paper's
    # pooled: 7 + 8 + 6 + 3 + 3 + 3 successes of 60 final episodes
    assert "| Lift | DSRL | 0.500 +- 0.000 (2) | 0.500 [" in report
    for figure in ("success.png", "mean_q.png", "dial.png"):
        assert (tmp_path / figure).stat().st_size > 0


def test_a_smoke_study_pauses_at_its_deadline_and_the_same_command_resumes_it(tmp_path):
    pytest.importorskip("ray.tune", reason="the sweep extra (Ray Tune) is not installed")
    argv = ["run", "--parts", "controller", "--methods", "dsrl", "--quick", "--cpus", "1", "--out", str(tmp_path)]
    study.main([*argv, "--hours", "1e-9"])  # past its deadline before the first interval
    assert not list(tmp_path.glob("runs/*/*/*/seed0/log.csv"))
    study.main([*argv, "--hours", "1", "--whole-runs"])  # the runs fit in the hour: they start
    cell = study.CELLS["lift-cartesian-nolimits"]
    log = cell.out(tmp_path) / "lift-nolimits-cartesian" / "dsrl" / "seed0" / "log.csv"
    assert [int(r["env_steps"]) for r in csv.DictReader(open(log))][-2:] == [32, 64]
    before = log.read_text()
    experiment = tmp_path / "tune" / "study-controller-dsrl"
    trials = sorted(p.name for p in experiment.iterdir() if p.is_dir())
    study.main(argv)
    assert log.read_text() == before
    assert sorted(p.name for p in experiment.iterdir() if p.is_dir()) == trials  # Tuner.restore
    controls = json.loads((cell.out(tmp_path) / "controls.json").read_text())
    assert len(controls) == 3  # N(0, I), N(0, 0.5^2 I), w = 0 for seed 0
    # Without Tune's state and the runs' checkpoints (as committed logs are), a fresh experiment
    # past its deadline: the finished runs return at once, rerun nothing and are not paused
    shutil.rmtree(tmp_path / "tune")
    for checkpoint in tmp_path.glob("runs/**/checkpoint.bin"):
        checkpoint.unlink()
    study.main([*argv, "--hours", "1e-9"])
    assert log.read_text() == before
    record = json.loads((tmp_path / "study.json").read_text())
    assert [(i["trials"], i["paused"]) for i in record["invocations"]] == [(2, 2), (2, 0), (2, 0), (2, 0)]


def test_the_claims_read_gains_and_q_by_the_two_standard_error_rule():
    def run(seed, final, q):
        return {"seed": seed, "figures": {"final": final, "peak": final}, "trained_q": q}

    empty = {name: {"cell": c, "runs": {}, "controls": {}, "breaking": None} for name, c in study.CELLS.items()}
    base = {1.0: {s: {"success_rate": 0.5} for s in range(3)}}
    lift = {
        "cell": study.CELLS["lift"],
        "controls": base,
        "breaking": {"replay_failure": 0.036},
        "runs": {
            # +0.10, +0.12, +0.08: more than two s.e. above 0; a mean Q above 0 once trained
            "equi": [run(0, 0.60, [-1.0, 0.5]), run(1, 0.62, [-2.0]), run(2, 0.58, [-3.0])],
            # +0.10, -0.10, 0.00: no clear gain; Equi - Approx = 0.00, 0.22, 0.08
            "approx": [run(0, 0.60, [-1.0]), run(1, 0.40, [-1.0]), run(2, 0.50, [-1.0])],
            "dsrl": [run(0, 0.45, [-1.0])],  # one seed: too few to read
        },
    }
    square = {**empty["square"], "controls": base, "runs": {"equi": [run(0, 0.40, [-1.0])]}}
    sb3 = {**empty["lift-sb3"], "runs": {"dsrl": [run(0, 0.5, [-0.5, 40.0, 30.0])]}}  # DSRL's protocol, SB3
    lines = "\n".join(study_report.claims({**empty, "lift": lift, "square": square, "lift-sb3": sb3}))
    assert "| Lift | -0.050 (1) | 0.100 +- 0.012 (3) up | 0.000 +- 0.058 (3) none | improved by Equi-DSRL |" in lines
    assert "| Stack D1 | - | - | - | not run yet |" in lines
    assert "| Square D2 | - | -0.100 (1) | - | too few seeds yet |" in lines
    # highest and final mean Q over seeds: (0.5 - 2 - 3) / 3, one run above 0
    assert "| Lift | Equi-DSRL | 1 of 3 | -1.5 +- 1.0 (3) | -1.5 +- 1.0 (3) |" in lines
    assert "| Lift | Approx-Equi-DSRL | 0 of 3 |" in lines
    assert "| Lift, SB3 + escnn, DSRL's protocol | DSRL | 1 of 1 | 40.0 (1) | 30.0 (1) |" in lines
    assert "| Lift | 0.036 | 0.100 +- 0.064 (3) | none | 0.100 +- 0.012 (3) | 0.000 +- 0.058 (3) |" in lines


def test_the_bases_own_peak_is_the_expected_best_of_as_many_noisy_evaluations():
    np = pytest.importorskip("numpy")
    assert study_report.expected_peak(0.5, 50, 1) == pytest.approx(0.5)
    assert study_report.expected_peak(1.0, 50, 8) == pytest.approx(1.0)
    draws = np.random.default_rng(0).binomial(50, 0.864, size=(200_000, 8)).max(axis=1) / 50
    assert study_report.expected_peak(0.864, 50, 8) == pytest.approx(draws.mean(), abs=1e-3)
    assert study_report.expected_peak(0.864, 50, 8) > 0.864 + 0.05  # what a peak over 8 evaluations adds


def test_whole_runs_needs_a_deadline():
    with pytest.raises(SystemExit):
        study.main(["run", "--parts", "controller", "--quick", "--whole-runs"])


def test_the_plan_counts_what_each_run_still_lacks(tmp_path):
    cell = study.CELLS["square"]

    def summary(method, seed, steps, checkpoint=False, kernel=cell.edp_kernel, per_step=0.1):
        d = cell.out(tmp_path) / cell.task / method / f"seed{seed}"
        d.mkdir(parents=True)
        (d / "log.csv").write_text("env_steps,success_rate,mean_q,seconds\n")
        (d / "summary.json").write_text(json.dumps({"env_steps": steps, "seconds": per_step * steps}))
        (d / "run.json").write_text(json.dumps({} if kernel == "dense" else {"edp_kernel": kernel}))
        if checkpoint:
            (d / "checkpoint.bin").write_bytes(b"")

    assert cell.edp_kernel == "fourier"
    summary("dsrl", 0, cell.steps // 4, checkpoint=True)  # a quarter of the way, resumable here
    summary("approx", 0, cell.steps // 2)  # half-way on a machine that kept its checkpoint: starts over
    summary("equi", 0, cell.steps)  # finished
    summary("equi", 1, cell.steps // 8, kernel="dense", per_step=0.5)  # the other kernel's clock does not count
    [b] = study.budget([cell], tmp_path)
    runs = len(cell.methods) * len(cell.seeds)
    assert b["done"] == 1 and b["runs"] == runs
    assert b["core_h_per_run"] == pytest.approx(0.1 * cell.steps / 3600)  # the runs' own clocks
    assert b["core_h_left"] == pytest.approx((runs - 1 - 0.25) * b["core_h_per_run"])
