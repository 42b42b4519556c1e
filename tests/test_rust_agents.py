"""The Rust steering agents from Python: gradients of every layer kind and of the SAC losses
against an independent PyTorch implementation (float64), and the run entry point (log layout,
thread independence, resume)."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from equigym import _core, steer
from equigym.steer import run_env

torch = pytest.importorskip("torch")


# -- an independent PyTorch rebuild of the networks from their description --------------------
def dft_matrix(order: int = 8) -> torch.Tensor:
    """The orthonormal real DFT: rows rho0, rho4, then (cos, -sin) of frequencies 1, 2, 3."""
    a = torch.arange(order, dtype=torch.float64)
    th = 2 * math.pi * a / order
    rows = [torch.ones(order, dtype=torch.float64) / math.sqrt(order), (-1.0) ** a / math.sqrt(order)]
    for w in (1, 2, 3):
        rows += [torch.cos(w * th) * math.sqrt(2 / order), -torch.sin(w * th) * math.sqrt(2 / order)]
    return torch.stack([r.to(torch.float64) for r in rows])


def net_forward(spec: dict, p: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    for L in spec["layers"]:
        k = L["kind"]
        if k == "dense":
            n_in, n_out, w, b = L["n_in"], L["n_out"], L["w"], L["b"]
            x = x @ p[w : w + n_in * n_out].view(n_in, n_out) + p[b : b + n_out]
        elif k == "equi":
            n_in, n_out, w = L["n_in"], L["n_out"], L["w"]
            entries = torch.tensor(L["entries"], dtype=torch.long)
            vals = p[w + torch.tensor(L["pidx"], dtype=torch.long)] * torch.tensor(L["coefs"], dtype=torch.float64)
            W = torch.zeros(n_in * n_out, dtype=torch.float64).index_add(0, entries, vals)
            bias_p = p[w + L["n_weights"] + torch.tensor(L["bias_pidx"], dtype=torch.long)]
            bias = torch.zeros(n_out, dtype=torch.float64).index_add(
                0, torch.tensor(L["bias_out"], dtype=torch.long), bias_p
            )
            if L["plain"] is not None:
                pw, pb = L["plain"]
                W = W + p[pw : pw + n_in * n_out]
                bias = bias + p[pb : pb + n_out]
            x = x @ W.view(n_in, n_out) + bias
        elif k == "norm":
            f, o, g, s = L["fields"], L["order"], L["g"], L["s"]
            gain, shift = p[g : g + f].repeat_interleave(o), p[s : s + f].repeat_interleave(o)
            x = torch.nn.functional.layer_norm(x, (f * o,), gain, shift, eps=1e-5)
        elif k == "tanh":
            x = torch.tanh(x)
        elif k == "relu":
            x = torch.relu(x)
        elif k == "pool_head":
            f, o, w, b = L["fields"], L["order"], L["w"], L["b"]
            q = x.view(len(x), f, o).max(dim=2).values @ p[w : w + f] + p[b]
            if L["plain"] is not None:
                pw, pb = L["plain"]
                q = q + x @ p[pw : pw + f * o] + p[pb]
            x = q.unsqueeze(1)
        elif k == "circulant":
            fi, fo, w, b = L["f_in"], L["f_out"], L["w"], L["b"]
            T = dft_matrix()
            n = fi * fo
            blk = [p[w + i * n : w + (i + 1) * n].view(fi, fo) for i in range(8)]
            xh = x.view(len(x), fi, 8) @ T.T  # (B, F_in, 8 components)
            out = [xh[..., 0] @ blk[0], xh[..., 1] @ blk[1]]
            for j in range(3):
                A, Bm = blk[2 + 2 * j], blk[3 + 2 * j]
                re, im = xh[..., 2 + 2 * j], xh[..., 3 + 2 * j]
                out += [re @ A - im @ Bm, re @ Bm + im @ A]  # (A + iB)(re + i im)
            yh = torch.stack(out, dim=2)  # (B, F_out, 8)
            x = ((yh @ T) + p[b : b + fo].unsqueeze(1)).reshape(len(x), fo * 8)
        else:
            raise AssertionError(k)
    return x


def squash(case: dict, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    if case["radial"] is None:  # SB3's tanh squash
        a = torch.tanh(u)
        return a, torch.log(1 - a**2 + 1e-6).sum(dim=1)
    from baselines.agents import _radial_squash  # the SB3 Equi-DSRL actor's own formula

    pairs, singles = case["radial"]
    return _radial_squash(
        u, torch.tensor(pairs, dtype=torch.long).reshape(-1, 2), torch.tensor(singles, dtype=torch.long)
    )


def actor_sample(case: dict, p: torch.Tensor, obs: torch.Tensor, eps: torch.Tensor):
    d = case["latent_dim"]
    out = net_forward(case["actor"], p, obs)
    mean = out[:, :d]
    lo, hi = case["log_std_range"]
    log_std = out[:, torch.tensor(case["log_std_index"])].clamp(lo, hi)
    std = log_std.exp()
    u = mean + std * eps
    a, logdet = squash(case, u)
    logp = torch.distributions.Normal(mean, std).log_prob(u).sum(dim=1) - logdet
    return a, logp


@pytest.mark.parametrize("method", ["dsrl", "equi", "approx"])
def test_sac_gradients_match_pytorch(method):
    if method != "dsrl":
        pytest.importorskip("stable_baselines3")  # baselines.agents holds the SB3 actor's radial squash
    c = _core.steer_gradcase(method, "lift", seed=1, rows=6)
    B, od, ad = c["rows"], c["obs_dim"], c["latent_dim"]
    t = lambda k, *shape: torch.tensor(c[k], dtype=torch.float64).view(*shape)  # noqa: E731
    obs, act, next_obs = t("obs", B, od), t("act", B, ad), t("next_obs", B, od)
    reward, done, eps1, eps2 = t("reward", B), t("done", B), t("eps1", B, ad), t("eps2", B, ad)
    pa = torch.tensor(c["actor"]["params"], dtype=torch.float64, requires_grad=True)
    pcs = [torch.tensor(cr["params"], dtype=torch.float64, requires_grad=True) for cr in c["critics"]]
    la = torch.tensor(c["log_alpha"], dtype=torch.float64, requires_grad=True)
    alpha = la.detach().exp()
    q = lambda k, o, a: net_forward(c["critics"][k], pcs[k], torch.cat([o, a], dim=1)).squeeze(1)  # noqa: E731
    # soft target (target critics = the critics, no gradient)
    with torch.no_grad():
        a2, logp2 = actor_sample(c, pa, next_obs, eps2)
        y = reward + (1 - done) * c["gamma"] * (torch.minimum(q(0, next_obs, a2), q(1, next_obs, a2)) - alpha * logp2)
    np.testing.assert_allclose(y.numpy(), c["y"], rtol=1e-10, atol=1e-10)
    # critic losses
    for k in range(2):
        loss = 0.5 * ((q(k, obs, act) - y) ** 2).mean()
        (g,) = torch.autograd.grad(loss, pcs[k])
        assert math.isclose(loss.item(), c["critic_losses"][k], rel_tol=1e-10)
        np.testing.assert_allclose(
            g.numpy(), c["critic_grads"][k], rtol=1e-7, atol=1e-10, err_msg=f"{method} critic {k}"
        )
    # actor loss through both critics
    a1, logp1 = actor_sample(c, pa, obs, eps1)
    np.testing.assert_allclose(logp1.detach().numpy(), c["logp"], rtol=1e-9, atol=1e-9)
    loss = (alpha * logp1 - torch.minimum(q(0, obs, a1), q(1, obs, a1))).mean()
    (g,) = torch.autograd.grad(loss, pa)
    assert math.isclose(loss.item(), c["actor_loss"], rel_tol=1e-9)
    np.testing.assert_allclose(g.numpy(), c["actor_grad"], rtol=1e-7, atol=1e-10, err_msg=f"{method} actor")
    # entropy coefficient
    aloss = -(la * (logp1.detach() + 0.0)).mean()
    (ga,) = torch.autograd.grad(aloss, la)
    assert math.isclose(ga.item(), c["alpha_grad"], rel_tol=1e-9)


# -- the run entry point ---------------------------------------------------------------------
SHORT = dict(eval_every=64, eval_episodes=2, env={"horizon": 32}, progress=False)


def read(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_run_writes_the_sb3_log_layout_and_is_thread_independent_and_resumable(tmp_path):
    one = steer.run("equi", "lift", 0, 128, tmp_path / "a", threads=1, **SHORT)
    two = steer.run("equi", "lift", 0, 128, tmp_path / "b", threads=2, **SHORT)
    strip = lambda rows: [r[:3] for r in rows]  # noqa: E731  (without seconds)
    assert strip(one["rows"]) == strip(two["rows"]) and one["params_hash"] == two["params_hash"]
    run_dir = tmp_path / "a" / "lift" / "equi" / "seed0"
    rows = read(run_dir / "log.csv")
    assert list(rows[0]) == ["env_steps", "success_rate", "mean_q", "seconds"]
    assert [int(r["env_steps"]) for r in rows] == [16, 64, 128]
    meta = json.loads((run_dir / "run.json").read_text())
    assert meta["agent"] == "rust" and meta["method"] == "equi" and meta["fields"] == 24
    # The learner's state at each evaluation: same columns as the SB3 runs', one row per
    # evaluation, the same for any thread count (drawn from its own stream).
    train = read(run_dir / "train.csv")
    columns = ["env_steps", "alpha", "entropy", "edge_fraction", "critic_loss", "target_q", "policy_q", "prior_kl"]
    assert list(train[0]) == columns
    assert [r["env_steps"] for r in train] == [r["env_steps"] for r in rows]
    assert all(math.isclose(float(r["alpha"]), 0.2, rel_tol=1e-6) for r in train)  # no gradient step yet
    assert all(math.isfinite(float(r["entropy"])) and 0 <= float(r["edge_fraction"]) <= 1 for r in train)
    # the untrained actor is narrower than the EDP's noise and off-centre: a KL of 10-20 nats
    # over the 40-d latent (a KL is never below zero)
    assert all(5 < float(r["prior_kl"]) < 40 for r in train)
    assert train == read(tmp_path / "b" / "lift" / "equi" / "seed0" / "train.csv")
    table = steer.diagnose([str(run_dir)])
    assert "policy entropy" in table and f"| 128 | {float(rows[-1]['success_rate']):.2f} |" in table
    # Started again with more steps it extends the run; with the same steps it only reloads.
    again = steer.run("equi", "lift", 0, 128, tmp_path / "a", threads=1, **SHORT)
    assert strip(again["rows"]) == strip(one["rows"]) and again["params_hash"] == one["params_hash"]
    longer = steer.run("equi", "lift", 0, 192, tmp_path / "a", threads=1, **SHORT)
    assert strip(longer["rows"])[:3] == strip(one["rows"]) and len(longer["rows"]) == 4
    assert read(run_dir / "train.csv")[:3] == train and len(read(run_dir / "train.csv")) == 4


def test_bad_arguments_raise_value_errors(tmp_path):
    with pytest.raises(ValueError, match="method"):
        _core.steer_run("ppo", "lift", 0, 16, str(tmp_path))
    with pytest.raises(ValueError, match="preset"):
        _core.steer_run("dsrl", "lift", 0, 16, str(tmp_path), preset="gpu")
    with pytest.raises(ValueError, match="controller"):
        _core.steer_run("dsrl", "lift", 0, 16, str(tmp_path), env={"controller": "torque"})
    # a target entropy the 40-d actor cannot reach (at most 27.3 nats) would grow alpha without end
    with pytest.raises(ValueError, match="out of reach"):
        _core.steer_run("dsrl", "lift", 0, 16, str(tmp_path), target_entropy=27.5)
    with pytest.raises(ValueError, match="replaces the target entropy"):
        _core.steer_run("dsrl", "lift", 0, 16, str(tmp_path), target_entropy=5.0, prior_kl=4.0)
    with pytest.raises(ValueError, match="positive"):
        _core.steer_run("dsrl", "lift", 0, 16, str(tmp_path), prior_kl=0.0)
    assert not any(tmp_path.iterdir())  # refused before anything is written


def test_main_job_steers_with_the_rust_agents(tmp_path, capsys):
    """The README's main job (baselines.headline) runs the Rust agents with the named recipe by
    default: the runs are Rust runs with the recipe's options, logged at each evaluation, and the
    printed table puts them beside the base and narrow-noise controls with intervals."""
    from baselines import headline

    argv = ["--steps", "128", "--eval-every", "64", "--eval-episodes", "2", "--seeds", "0", "1"]
    headline.main([*argv, "--workers", "2", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    for seed in (0, 1):
        run_dir = tmp_path / "lift" / "dsrl" / f"seed{seed}"
        meta = json.loads((run_dir / "run.json").read_text())
        assert meta["agent"] == "rust" and meta["eval_episodes"] == 2
        assert {k: meta[k] for k in steer.RECIPES["na-tos-h20"]} == steer.RECIPES["na-tos-h20"]
        assert [int(r["env_steps"]) for r in read(run_dir / "log.csv")][-2:] == [64, 128]
    lines = printed.splitlines()
    assert any(line.startswith("| base policy, N(0, I) | 2 |") for line in lines)
    assert any(line.startswith("| narrow-noise base, N(0, 0.5^2 I) | 2 |") for line in lines)
    final = next(line for line in lines if "target_entropy=20.0, edp_kernel=fourier), final" in line)
    finals = [read(tmp_path / "lift" / "dsrl" / f"seed{s}" / "log.csv")[-3:] for s in (0, 1)]
    wins = sum(round(float(r["success_rate"]) * 2) for rows in finals for r in rows)
    assert f"{wins}/12 = " in final
    assert (tmp_path / "report" / "lift.png").exists()
    assert (tmp_path / "report" / "compare.md").read_text().strip() in printed
    # The report says where the runs' time went, from their summary.json.
    summaries = [json.loads((tmp_path / "lift" / "dsrl" / f"seed{s}" / "summary.json").read_text()) for s in (0, 1)]
    assert all(x["eval_env_steps"] > 0 for x in summaries)
    table = (tmp_path / "report" / "table.md").read_text()
    row = next(line for line in table.splitlines() if line.startswith("| lift | DSRL (Rust) | 2 |"))
    assert row.split("|")[7].strip() == f"{sum(x['eval_env_steps'] for x in summaries) / 2:,.0f}"


@pytest.mark.parametrize(
    ("edp_kernel", "final", "params_hash"),
    [
        ("fourier", (6000, 1.0, 11.224593162536621), "45af11a46ca5f28d"),
        ("dense", (6000, 0.5, 9.470488548278809), "ab87929257f452c6"),
    ],
)
def test_a_6k_step_equi_run_matches_its_recorded_weights(tmp_path, edp_kernel, final, params_hash):
    """A longer golden than agents/tests/runs.rs (384 env steps, blessed on an AMD EPYC): 6,000
    env steps of Equi-DSRL on Lift, 2,000 gradient steps, through the release build. The final
    weights' hash and the last mean Q were first recorded on an Intel Xeon with AVX-512 and
    reproduced on an AMD EPYC; re-blessed when the shipped Lift EDP became the 16k-step one
    (docs/edp.md), and on an AMD EPYC when the patched rapier began to reuse the arm's mass matrix
    across a physics step's substeps (vendor/rapier3d/PATCH.md), and when the IK began to stop a
    stalled solve early (envs/src/robot/kinematics.rs). The EDP's dense kernel still gives that
    record, as every run recorded before the Fourier kernel became the default replays on it; the
    default's figures were recorded on an AMD EPYC. The same run with the full evaluation protocol
    gives the same hash, since evaluations draw from their own streams. A machine that gives other
    bits here breaks the README's promise that the main job prints the same figures everywhere
    (docs/steering.md, "Reproducibility across machines")."""
    s = _core.steer_run("equi", "lift", 0, 6000, str(tmp_path), eval_every=6000, eval_episodes=2, edp_kernel=edp_kernel)
    assert s["grad_steps"] == 2000
    assert [(r[0], r[1], r[2]) for r in s["rows"]] == [(16, 1.0, -0.7359681129455566), final]
    assert s["params_hash"] == params_hash


def test_summarize_counts_the_peak_only_once_training_started():
    # Evaluations at 0 and 4k are the warm-up's (entropy coefficient still at its start value):
    # their 0.9 is not a learned peak. Final is the mean of the last three.
    log = [
        {"env_steps": str(k), "success_rate": str(v)} for k, v in [(0, 0.6), (4, 0.9), (6, 0.5), (8, 0.7), (10, 0.3)]
    ]
    train = {str(k): {"alpha": a} for k, a in [(0, "0.2"), (4, "0.2"), (6, "0.1"), (8, "0.09"), (10, "0.08")]}
    s = steer.summarize(log, train)
    assert s["untrained"] == 0.6 and s["peak"] == 0.7
    assert abs(s["final"] - 0.5) < 1e-12


def test_compare_puts_runs_beside_their_controls_on_the_same_starts(tmp_path):
    """``equigym.steer compare``: a run group's untrained and final rows are counted from its
    log (final = the last three evaluations, pooled), and the control rows are the base policy
    evaluated with the runs' own settings and seeds (cached: a second call evaluates nothing)."""
    from equigym.assets import asset_path

    policy = str(asset_path("edp", "lift.safetensors"))
    dirs = []
    for seed, rates in ((0, [0.5, 0.25, 0.75, 1.0, 0.5]), (1, [0.25, 0.5, 0.5, 0.75, 0.75])):
        d = tmp_path / "runs" / f"seed{seed}"
        d.mkdir(parents=True)
        meta = {"method": "dsrl", "task": "lift", "seed": seed, "policy": policy, "noise_aliased": True}
        (d / "run.json").write_text(json.dumps({**meta, "eval_episodes": 4, "horizon": 60}))
        rows = "".join(f"{16 + 2000 * i},{r},0.0,1.0\n" for i, r in enumerate(rates))
        (d / "log.csv").write_text("env_steps,success_rate,mean_q,seconds\n" + rows)
        dirs.append(str(d))
    out = tmp_path / "cmp" / "compare.md"
    text = steer.compare(dirs, (1.0, 0.0), str(out))
    final = next(line for line in text.splitlines() if "noise_aliased), final" in line)
    # Seed 0: 3 + 4 + 2 of 12, seed 1: 2 + 3 + 3 of 12.
    assert "17/24 = 0.708" in final and "0.75, 0.67" in final
    untrained = next(line for line in text.splitlines() if "untrained actor" in line)
    assert "3/8 = 0.375" in untrained
    # The runs' run.json names no kernel: they ran dense, and so do their controls.
    kw = dict(episodes=4, env={"horizon": 60}, policy=policy, edp_kernel="dense")
    base = [_core.evaluate_base("lift", seed=s, **kw) for s in (0, 1)]
    wins = sum(b["successes"] for b in base)
    base_row = next(line for line in text.splitlines() if line.startswith("| base policy"))
    assert f"{wins}/8 = " in base_row
    zero_row = next(line for line in text.splitlines() if "0^2 I" in line)
    assert "| 1 |" in zero_row, "a noiseless base is one evaluation, not one per seed"
    cached = json.loads((out.parent / "controls.json").read_text())
    assert len(cached) == 3
    (out.parent / "controls.json").write_text(json.dumps({k: {**v, "successes": 0} for k, v in cached.items()}))
    again = steer.compare(dirs, (1.0, 0.0), str(out))
    assert "| 0/8 = 0.000" in next(line for line in again.splitlines() if line.startswith("| base policy"))
    # Read as they stood at 4,016 env steps: the first three evaluations are the final ones.
    cut = steer.compare(dirs, (1.0,), str(out), at=4016)
    assert "11/24 = 0.458" in next(line for line in cut.splitlines() if "noise_aliased), final (4,016" in line)
    with pytest.raises(ValueError, match="no evaluation"):
        steer.compare(dirs, (1.0,), None, at=10)


def test_main_job_refuses_a_rust_only_recipe_for_the_sb3_agents(tmp_path):
    from baselines import headline

    with pytest.raises(SystemExit):
        headline.main(["--agents", "sb3", "--recipe", "na-tos-h20", "--out", str(tmp_path)])
    assert not any(tmp_path.iterdir()), "nothing ran"


def test_the_edp_kernel_is_fourier_by_default_and_a_dense_run_replays_the_records(tmp_path, monkeypatch):
    """The default kernel is the Fourier one and run.json names it; a dense run's names none (as
    every run recorded before the Fourier kernel), a checkpoint of one kernel never resumes on the
    other, and a run's control arms evaluate the base on the run's kernel (their cache keyed by it,
    a file that names none read as dense)."""
    dense = steer.run("dsrl", "stack", 0, 64, tmp_path, edp_kernel="dense", **SHORT)
    run_dir = Path(dense["run_dir"])
    dense_meta = {**json.loads((run_dir / "run.json").read_text()), "eval_episodes": 2}
    assert "edp_kernel" not in dense_meta
    with pytest.raises(ValueError, match="checkpoint"):
        steer.run("dsrl", "stack", 0, 128, tmp_path, **SHORT)
    with pytest.raises(ValueError, match="kernel must be"):
        steer.run("dsrl", "stack", 0, 64, tmp_path / "x", edp_kernel="fft", **SHORT)
    fourier = steer.run("dsrl", "stack", 0, 64, tmp_path / "f", **SHORT)
    named = steer.run("dsrl", "stack", 0, 64, tmp_path / "g", edp_kernel="fourier", **SHORT)
    assert fourier["params_hash"] == named["params_hash"] and fourier["rows"][-1][:3] == named["rows"][-1][:3]
    meta = json.loads((Path(fourier["run_dir"]) / "run.json").read_text())
    assert meta["edp_kernel"] == "fourier"
    meta = {**meta, "eval_episodes": 2}
    cache = tmp_path / "controls.json"
    got = steer.controls(meta, [0], (1.0,), cache)[1.0][0]
    want = _core.evaluate_base(
        "stack", seed=0, episodes=2, policy=meta["policy"], edp_kernel="fourier", env=run_env(meta)
    )
    assert got == want
    assert all('"edp_kernel": "fourier"' in key for key in json.loads(cache.read_text()))
    # A run.json that names no kernel ran dense: its controls are evaluated dense, under a key
    # without the kernel (the committed caches' keys).
    asked = []
    monkeypatch.setattr(_core, "evaluate_base", lambda task, **kw: asked.append(kw) or {"success_rate": 0.0})
    steer.controls(dense_meta, [0], (1.0,), cache)
    assert [kw["edp_kernel"] for kw in asked] == ["dense"]
    assert sum("edp_kernel" not in key for key in json.loads(cache.read_text())) == 1
