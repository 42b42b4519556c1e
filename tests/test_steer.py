"""The steering experiment runner: a run logs evaluations, a killed run resumes where it stopped
(model and replay buffer), the base policy is measured once, and the report writes Table 1 and plots."""

import csv
import json

import pytest

pytest.importorskip("torch")
pytest.importorskip("escnn")
pytest.importorskip("stable_baselines3")

from baselines import steer  # noqa: E402
from equigym.steer import controls, read_run, resume_steps, run_steps  # noqa: E402
from equigym.steer.sweep_report import write_report  # noqa: E402

TINY = {"name": "tiny", "width": 16, "layers": 1, "utd": 1, "batch": 16, "n_envs": 2, "warmup": 8, "ent_init": 1.0}


def rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("method", ["dsrl", "equi", "approx", "sac"])
def test_run_logs_resumes_and_reports(method, tmp_path):
    out = tmp_path / "runs"
    run_dir = steer.run(method, "lift", 0, 64, out, TINY, eval_every=32, eval_episodes=1, progress=False)
    first = rows(run_dir / "log.csv")
    # The first evaluation follows the first vector step (2 envs x a 4-action chunk, or one raw
    # action each for SAC), then one every 32 env steps.
    first_step = 2 if method == "sac" else 8
    assert [int(r["env_steps"]) for r in first] == [first_step, 32, 64]
    assert (run_dir / "checkpoint" / "model.zip").exists() and (run_dir / "checkpoint" / "replay.pkl").exists()
    # The Rust runner's layout: summary.json says how far the run got, and equigym.steer reads it
    assert run_steps(run_dir) == 64 and resume_steps(run_dir) == 64
    # and its run.json names what the control arms are evaluated from (EDP, episodes), as the Rust one does
    assert controls(read_run(run_dir)["meta"], [0], compute=False) == {1.0: [], 0.5: [], 0.0: []}
    meta = json.loads((run_dir / "run.json").read_text())
    assert meta["method"] == method and meta["params_actor"] > 0
    # the EDP's kernel, named as the Rust runner names it (the runtime's default, Fourier)
    assert meta.get("edp_kernel") == (None if method == "sac" else "fourier")
    # "Killed" after 64 steps; asking for 128 continues from the checkpoint, replay buffer included.
    steer.run(method, "lift", 0, 128, out, TINY, eval_every=32, eval_episodes=1, progress=False)
    second = rows(run_dir / "log.csv")
    assert len(second) > len(first)
    steps = [int(r["env_steps"]) for r in second]
    assert steps == sorted(steps) and steps[-1] >= 128 - 8
    assert steps[len(first)] > steps[len(first) - 1]  # no restart from zero
    assert run_steps(run_dir) >= 128
    intervals = [s // 32 for s in steps]
    assert len(set(intervals)) == len(intervals)  # one evaluation per interval, across the resume too
    seconds = [float(r["seconds"]) for r in second]
    assert seconds[len(first)] >= seconds[len(first) - 1]  # the run's clock continues
    # The learner's state beside every evaluation, in the Rust agents' columns.
    train = rows(run_dir / "train.csv")
    assert list(train[0]) == steer.TRAIN_COLUMNS and [r["env_steps"] for r in train] == [str(s) for s in steps]
    # Base policy success is cached per task folder and appears in the report.
    rate = steer.base_success("lift", out, episodes=2)
    assert 0.0 <= rate <= 1.0 and json.loads((out / "lift" / "base.json").read_text())["edp_kernel"] == "fourier"
    text = write_report(out, tmp_path / "report")
    # The report has the method's row.
    assert "| lift | " in text and (tmp_path / "report" / "lift.png").exists()
    label = {"dsrl": "DSRL", "equi": "Equi-DSRL", "approx": "Approx-Equi-DSRL", "sac": "SAC (raw actions)"}[method]
    assert label in text


def test_report_labels_both_agents_and_shows_single_seeds_without_an_error_bar(tmp_path):
    """Rust and SB3 runs side by side: the SB3 columns say so, and a single seed has no +- term."""
    for agent, seeds in (("rust", (0, 1)), ("sb3", (0,))):
        for s in seeds:
            d = tmp_path / agent / "lift" / "equi" / f"seed{s}"
            d.mkdir(parents=True)
            meta = {"method": "equi", **({"agent": "rust"} if agent == "rust" else {})}
            (d / "run.json").write_text(json.dumps(meta))
            (d / "log.csv").write_text(
                f"env_steps,success_rate,mean_q,seconds\n0,0.5,-1.0,1\n16,{0.6 + 0.1 * s},-2.0,2\n"
            )
    text = write_report([tmp_path / "rust", tmp_path / "sb3"], tmp_path / "report")
    assert "| Equi-DSRL (SB3) | Equi-DSRL (Rust) |" in text
    assert "0.600 (1 seed, 16 steps)" in text and "0.650 +- 0.050 (2 seeds, 16 steps)" in text
    assert "nan" not in text


def test_the_sb3_runner_reads_the_presets_from_their_rust_home():
    from equigym import _core
    from equigym.errors import InvalidInputError

    assert steer.PRESETS["cpu"] == {
        "width": 64,
        "layers": 3,
        "utd": 4,
        "batch": 256,
        "n_envs": 4,
        "warmup": 1000,
        "ent_init": 0.2,
    }
    assert steer.PRESETS["paper"]["utd_square"] == 20 and steer.PRESETS["paper"]["width"] == 2048
    with pytest.raises(InvalidInputError, match="preset must be"):
        _core.steer_preset("gpu")


def test_stats_share_one_statistic_and_one_text_form():
    """mean +- s.e. is numpy's sample standard deviation over sqrt(n), in every table's one text
    form; a pooled rate carries a Wilson interval around it."""
    import numpy as np

    from equigym.steer.stats import format_mean_se, format_pooled, mean_se

    xs = [0.25, 0.5, 0.75, 0.9]
    m, se = mean_se(xs)
    assert m == pytest.approx(np.mean(xs))
    assert se == pytest.approx(np.std(xs, ddof=1) / np.sqrt(len(xs)))
    assert format_mean_se(xs) == f"{np.mean(xs):.3f} +- {se:.3f}"
    assert format_mean_se(xs, 1, count=True) == f"{m:.1f} +- {se:.1f} (4)"
    assert format_mean_se([0.5]) == "0.500"
    assert format_mean_se([]) == "-"
    text = format_pooled(30, 60)
    low, high = (float(x) for x in text.split("[")[1].rstrip("]").split(", "))
    assert text.startswith("30/60 = 0.500 [") and low < 0.5 < high and high - low < 0.3
    assert format_pooled(30, 60, counts=False) == text.removeprefix("30/60 = ")
    assert format_pooled(0, 0) == "-"


def test_mcnemar_is_the_exact_two_sided_sign_test_on_discordant_starts():
    """Only the starts that end differently count; p is twice the binomial tail at 1/2 (1 of 10
    discordant starts one way: 2 * (1 + 10) / 2^10), the same either way round, 1 without any."""
    pytest.importorskip("scipy")
    from equigym.steer.stats import mcnemar_p

    assert mcnemar_p(1, 9) == pytest.approx(2 * 11 / 1024)
    assert mcnemar_p(9, 1) == pytest.approx(mcnemar_p(1, 9))
    assert mcnemar_p(0, 5) == pytest.approx(2 / 32)
    assert mcnemar_p(4, 4) == 1.0
    assert mcnemar_p(0, 0) == 1.0
