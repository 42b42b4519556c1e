"""Equivariant Diffusion Policy (EDP): a state-based C_N-equivariant noise predictor, trained
with DDPM on scripted demonstrations and exported for the Rust runtime.

    python -m baselines.edp train --demos data/lift_3.hdf5 --out assets/edp/lift.safetensors
    python -m baselines.edp train --demos ... --plain          # non-equivariant MLP, similar size
    python -m baselines.edp eval --policy assets/edp/lift.safetensors --episodes 100

Model: input = [normalised observation fields, noisy normalised action chunk, timestep embedding]
in their representations (rho0 / rho1 blocks, the embedding trivial), escnn ``Linear`` layers on
``no_base_space(cyclic_group(N))`` with regular-representation hidden fields and ReLU, output =
the predicted noise in the chunk's representation. DDPM with 100 steps (squared-cosine
schedule), epsilon prediction; sampling is deterministic DDIM (5 steps by default) without
clipping (elementwise clipping would break equivariance). Normalisation commutes with the group:
each rho1 pair is divided by one shared scale with no offset; rho0 values are min-max scaled.

Export: ``module.export()`` gives plain linear layers; the permutation into escnn's block order
is folded into the first and last weights, so the file holds a plain MLP in the task's natural
field order (safetensors tensors ``layer{i}.weight/bias``, ``alphas_cumprod``, ``time_embedding``,
``obs_offset/scale``, ``action_offset/scale``; metadata: task, layouts, chunk length, steps).
"""

from __future__ import annotations

import argparse
import collections
import copy
import csv
import functools
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

try:
    import torch
    import torch.nn as tnn
except ImportError as exc:  # pragma: no cover
    raise ImportError("baselines.edp needs torch: pip install 'equigym[train]'") from exc

from baselines.equivariant import block_types
from equigym.demos import load as load_demos
from equigym.symmetry import Symmetry

FORMAT = "equigym-edp-1"
#: Line of docs/edp.md after which the text is hand-written and kept by ``report``.
REPORT_MARKER = "<!-- generated above by `python -m baselines.edp report`; written by hand below -->"
#: Episodes of the base-success figure (pinned starts ``_core.EVAL_SEED + k``).
EVAL_EPISODES = 200


@dataclass
class EDPConfig:
    task: str = "lift"
    chunk_len: int = 4
    group_order: int = 8
    equivariant: bool = True
    #: Hidden width: regular fields per layer (x N dims) for the EDP; plain width is matched.
    hidden_fields: int = 32
    hidden_layers: int = 3
    time_dim: int = 16
    num_train_timesteps: int = 100
    ddim_steps: int = 5
    batch_size: int = 256
    steps: int = 4000
    lr: float = 1e-3
    weight_decay: float = 1e-6
    ema_decay: float = 0.995
    seed: int = 0
    #: Observations the policy conditions on: 1 = o_t; 2 = o_t and its change o_t - o_{t-1}
    #: over the last control step (the arm lags its commands and o_t holds no velocities).
    obs_history: int = 1
    variant: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)


# -- schedule and embedding ---------------------------------------------------------------
def cosine_alphas_cumprod(T: int, s: float = 0.008) -> np.ndarray:
    """The squared-cosine schedule (betas capped at 0.999), as alphas_cumprod."""

    def abar(t: float) -> float:
        return math.cos((t / T + s) / (1 + s) * math.pi / 2) ** 2

    betas = np.array([min(1 - abar(i + 1) / abar(i), 0.999) for i in range(T)])
    return np.cumprod(1.0 - betas)


def time_embedding_table(T: int, dim: int) -> np.ndarray:
    """Sinusoidal embedding of t = 0..T-1 (rows); stored in the export so Rust uses the same."""
    half = dim // 2
    freqs = np.exp(-math.log(10000.0) * np.arange(half) / max(half - 1, 1))
    args = np.arange(T)[:, None] * freqs[None, :]
    return np.concatenate([np.sin(args), np.cos(args)], axis=1)


def ddim_timesteps(T: int, steps: int) -> list[int]:
    ratio = T // steps
    return [i * ratio for i in range(steps)][::-1]


# -- normalisation that commutes with the group --------------------------------------------
def fit_normalizer(x: np.ndarray, blocks: list[tuple[int, list[int]]]) -> tuple[np.ndarray, np.ndarray]:
    """(offset, scale) per dimension: rho1 pairs share one scale (max norm) and no offset;
    rho0 values map [min, max] to [-1, 1]."""
    offset = np.zeros(x.shape[1])
    scale = np.ones(x.shape[1])
    for freq, idx in blocks:
        if freq == 0:
            (i,) = idx
            lo, hi = x[:, i].min(), x[:, i].max()
            offset[i] = 0.5 * (lo + hi)
            scale[i] = max(0.5 * (hi - lo), 1e-3)
        else:
            s = np.linalg.norm(x[:, idx], axis=1).max()
            scale[idx] = max(s, 1e-3)
    return offset, scale


# -- networks ------------------------------------------------------------------------------
class EquivariantNoiseNet(tnn.Module):
    """escnn MLP: [obs, x_t, time embedding] -> epsilon, equivariant to C_N."""

    def __init__(self, obs_blocks, chunk_blocks, time_dim: int, hidden_fields: int, hidden_layers: int, order: int):
        super().__init__()
        from escnn import group, gspaces
        from escnn import nn as enn

        gs = gspaces.no_base_space(group.cyclic_group(order))
        obs_reps, obs_perm = block_types(gs, obs_blocks)
        out_reps, chunk_perm = block_types(gs, chunk_blocks)
        in_reps = obs_reps + out_reps + [gs.trivial_repr] * time_dim
        # Natural order -> block order (each rho1 pair contiguous); the time embedding is trivial.
        perm_in = obs_perm + [len(obs_perm) + i for i in chunk_perm]
        perm_in += list(range(len(perm_in), len(perm_in) + time_dim))
        self.register_buffer("perm_in", torch.tensor(perm_in))
        self.perm_out = chunk_perm
        self.register_buffer("inv_out", torch.tensor(np.argsort(self.perm_out)))
        self.in_type = enn.FieldType(gs, in_reps)
        hidden = enn.FieldType(gs, hidden_fields * [gs.regular_repr])
        layers: list[Any] = [enn.Linear(self.in_type, hidden), enn.ReLU(hidden)]
        for _ in range(hidden_layers - 1):
            layers += [enn.Linear(hidden, hidden), enn.ReLU(hidden)]
        layers.append(enn.Linear(hidden, enn.FieldType(gs, out_reps)))
        self.net = enn.SequentialModule(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.net(self.in_type(x[:, self.perm_in])).tensor
        return y[:, self.inv_out]

    def export_linear(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Plain (weight, bias) per layer in natural order, from escnn's export."""
        was_training = self.training
        self.eval()
        seq = self.net.export()
        self.train(was_training)
        lin = [m for m in seq if isinstance(m, tnn.Linear)]
        out = [(m.weight.detach().double().numpy().copy(), m.bias.detach().double().numpy().copy()) for m in lin]
        w0, b0 = out[0]
        w0n = np.zeros_like(w0)
        w0n[:, self.perm_in.numpy()] = w0
        out[0] = (w0n, b0)
        wl, bl = out[-1]
        wln, bln = np.zeros_like(wl), np.zeros_like(bl)
        wln[self.perm_out, :] = wl
        bln[self.perm_out] = bl
        out[-1] = (wln, bln)
        return out


class PlainNoiseNet(tnn.Module):
    """A plain MLP with the same inputs and outputs (the non-equivariant comparison)."""

    def __init__(self, in_dim: int, out_dim: int, width: int, hidden_layers: int):
        super().__init__()
        layers: list[tnn.Module] = [tnn.Linear(in_dim, width), tnn.ReLU()]
        for _ in range(hidden_layers - 1):
            layers += [tnn.Linear(width, width), tnn.ReLU()]
        layers.append(tnn.Linear(width, out_dim))
        self.net = tnn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)

    def export_linear(self) -> list[tuple[np.ndarray, np.ndarray]]:
        return [
            (m.weight.detach().double().numpy().copy(), m.bias.detach().double().numpy().copy())
            for m in self.net
            if isinstance(m, tnn.Linear)
        ]


def count_params(m: tnn.Module) -> int:
    return sum(p.numel() for p in m.parameters() if p.requires_grad)


def conditioning_blocks(sym: Symmetry, history: int) -> list[tuple[int, list[int]]]:
    """The representation blocks of the policy's conditioning: the observation's, once per
    observation in the history (a change of observation transforms as the observation)."""
    dim = sym.dim("observation")
    return [(f, [i + k * dim for i in idx]) for k in range(history) for f, idx in sym.blocks("observation")]


def conditioning(obs: np.ndarray, prev: np.ndarray | None, history: int) -> np.ndarray:
    """The policy's input for observations ``obs`` (batch x obs_dim) and those one control step
    before (``prev``; None or equal to ``obs`` at an episode's first step)."""
    if history == 1:
        return obs
    if history != 2:
        raise ValueError(f"obs_history must be 1 or 2, got {history}")
    return np.concatenate([obs, obs - (obs if prev is None else prev)], axis=-1)


def build_net(cfg: EDPConfig, sym: Symmetry) -> tnn.Module:
    obs_blocks, chunk_blocks = conditioning_blocks(sym, cfg.obs_history), sym.blocks("chunk")
    in_dim = cfg.obs_history * sym.dim("observation") + sym.dim("chunk") + cfg.time_dim
    equi = EquivariantNoiseNet(
        obs_blocks, chunk_blocks, cfg.time_dim, cfg.hidden_fields, cfg.hidden_layers, cfg.group_order
    )
    if cfg.equivariant:
        return equi
    # Match the parameter count: solve for the plain width.
    target = count_params(equi)
    L, i, o = cfg.hidden_layers, in_dim, sym.dim("chunk")
    a, b, c = L - 1, i + o + L, o - target
    width = int((-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)) if a > 0 else max(8, (target - o) // (i + o + 1))
    return PlainNoiseNet(in_dim, o, max(width, 8), L)


# -- data ----------------------------------------------------------------------------------
def chunk_dataset(demos: list[dict[str, Any]], chunk_len: int, history: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(conditioning_t, actions[t : t + chunk_len]) pairs; chunks past the end repeat the last
    action; the conditioning is ``conditioning`` of o_t and o_{t-1} (o_0 at t = 0)."""
    obs, chunks = [], []
    for d in demos:
        a = d["actions"]
        T = len(a)
        o = np.asarray(d["obs"], dtype=np.float64)
        cond = conditioning(o, np.concatenate([o[:1], o[:-1]]), history)
        for t in range(T):
            idx = np.minimum(np.arange(t, t + chunk_len), T - 1)
            obs.append(cond[t])
            chunks.append(a[idx].reshape(-1))
    return np.asarray(obs, dtype=np.float64), np.asarray(chunks, dtype=np.float64)


# -- training ------------------------------------------------------------------------------
def _demo_digest(path: str | Path) -> str:
    """Content hash of the demo file: a checkpoint resumes only on the data it was trained on."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def train(
    cfg: EDPConfig,
    demo_path: str | Path,
    out: str | Path,
    progress: bool = True,
    threads: int = 1,
    resume: bool = True,
    checkpoint_every: int = 1000,
    stop_after: int | None = None,
) -> dict[str, Any]:
    """Train and export. Every 1000 steps the full training state (weights, EMA, AdamW and
    scheduler state, torch RNG, loss history) goes to ``<out>.ckpt``; with ``resume`` a
    checkpoint of the same config and demo file is continued, and the resumed run ends with
    bitwise the weights of an uninterrupted one (single thread, same machine). ``stop_after``
    ends this call after that many steps, checkpointed, without exporting (for time-limited
    jobs); it returns ``{"stopped_at": step}``."""
    # Small networks: one thread is fastest, and several OpenMP threads on a loaded machine
    # spin-wait each other into a crawl.
    torch.set_num_threads(threads)
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    data = load_demos(demo_path)
    if data["task"] != cfg.task:
        cfg.task = data["task"]
    cfg.variant = data["env_args"].get("env_kwargs", {}).get("variant")
    sym = Symmetry(cfg.task, group=f"C{cfg.group_order}", chunk_len=cfg.chunk_len)
    obs, chunks = chunk_dataset(data["demos"], cfg.chunk_len, cfg.obs_history)
    obs_off, obs_scale = fit_normalizer(obs, conditioning_blocks(sym, cfg.obs_history))
    act_off, act_scale = fit_normalizer(chunks.reshape(-1, 10), sym.blocks("action"))
    act_off, act_scale = np.tile(act_off, cfg.chunk_len), np.tile(act_scale, cfg.chunk_len)
    x_obs = torch.tensor((obs - obs_off) / obs_scale, dtype=torch.float32)
    x_act = torch.tensor((chunks - act_off) / act_scale, dtype=torch.float32)
    abar = torch.tensor(cosine_alphas_cumprod(cfg.num_train_timesteps), dtype=torch.float32)
    temb = torch.tensor(time_embedding_table(cfg.num_train_timesteps, cfg.time_dim), dtype=torch.float32)

    net = build_net(cfg, sym)
    ema = copy.deepcopy(net)
    for p in ema.parameters():
        p.requires_grad_(False)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.steps)
    n = len(x_obs)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    log_path = out.with_suffix(".loss.csv")
    ckpt_path = out.with_suffix(".ckpt")
    digest = _demo_digest(demo_path)
    losses: list[float] = []
    start = 0
    seconds_before = 0.0
    if resume and ckpt_path.exists():
        ckpt = torch.load(ckpt_path, weights_only=False)
        if ckpt.get("config") == asdict(cfg) and ckpt.get("demos_sha256") == digest and "opt" in ckpt:
            net.load_state_dict(ckpt["net"])
            ema.load_state_dict(ckpt["ema"])
            opt.load_state_dict(ckpt["opt"])
            sched.load_state_dict(ckpt["sched"])
            torch.set_rng_state(ckpt["rng"])
            losses = list(ckpt["losses"])
            start = int(ckpt["step"])
            seconds_before = float(ckpt.get("seconds", 0.0))
            if progress:
                print(f"resuming {ckpt_path} at step {start}")
    try:
        from tqdm import trange

        steps = trange(start, cfg.steps, desc=f"EDP {cfg.task}", disable=not progress)
    except ImportError:  # pragma: no cover
        steps = range(start, cfg.steps)
    t0 = time.time()
    for step in steps:
        idx = torch.randint(0, n, (min(cfg.batch_size, max(n, 1) * 4),))
        o, a = x_obs[idx], x_act[idx]
        t = torch.randint(0, cfg.num_train_timesteps, (len(idx),))
        eps = torch.randn_like(a)
        ab = abar[t][:, None]
        xt = ab.sqrt() * a + (1 - ab).sqrt() * eps
        pred = net(torch.cat([o, xt, temb[t]], dim=1))
        loss = torch.mean((pred - eps) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        with torch.no_grad():
            for pe, p in zip(ema.parameters(), net.parameters()):
                pe.mul_(cfg.ema_decay).add_(p.detach(), alpha=1 - cfg.ema_decay)
        losses.append(float(loss))
        if hasattr(steps, "set_postfix") and step % 50 == 0:
            steps.set_postfix(loss=f"{np.mean(losses[-50:]):.4f}")
        stopping = stop_after is not None and step + 1 - start >= stop_after
        if (step + 1) % checkpoint_every == 0 or step + 1 == cfg.steps or stopping:
            state = {
                "config": asdict(cfg),
                "demos_sha256": digest,
                "net": net.state_dict(),
                "ema": ema.state_dict(),
                "opt": opt.state_dict(),
                "sched": sched.state_dict(),
                "rng": torch.get_rng_state(),
                "losses": losses,
                "step": step + 1,
                "seconds": seconds_before + time.time() - t0,
            }
            torch.save(state, ckpt_path.with_suffix(".ckpt.tmp"))
            os.replace(ckpt_path.with_suffix(".ckpt.tmp"), ckpt_path)
        if stopping and step + 1 < cfg.steps:
            return {"stopped_at": step + 1}
    seconds = seconds_before + time.time() - t0
    with open(log_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["step", "loss"])
        w.writerows(enumerate(losses))
    _plot_loss(losses, out.with_suffix(".loss.png"))
    layers = ema.export_linear()
    export(
        out,
        cfg,
        sym,
        layers,
        obs_off,
        obs_scale,
        act_off,
        act_scale,
        params=count_params(net),
        demos=len(data["demos"]),
        final_loss=float(np.mean(losses[-100:])),
        train_seconds=round(seconds),
    )
    return {
        "path": str(out),
        "params": count_params(net),
        "samples": n,
        "seconds": seconds,
        "final_loss": float(np.mean(losses[-100:])),
    }


def _plot_loss(losses: list[float], path: Path) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover
        return
    fig, ax = plt.subplots(figsize=(5, 3))
    k = max(1, len(losses) // 200)
    smooth = np.convolve(losses, np.ones(k) / k, mode="valid")
    ax.plot(smooth)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("noise MSE")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def export(out, cfg: EDPConfig, sym: Symmetry, layers, obs_off, obs_scale, act_off, act_scale, **meta: Any) -> None:
    from safetensors.numpy import save_file

    tensors = {
        "alphas_cumprod": cosine_alphas_cumprod(cfg.num_train_timesteps).astype(np.float64),
        "time_embedding": time_embedding_table(cfg.num_train_timesteps, cfg.time_dim).astype(np.float64),
        "obs_offset": np.asarray(obs_off, dtype=np.float64),
        "obs_scale": np.asarray(obs_scale, dtype=np.float64),
        "action_offset": np.asarray(act_off, dtype=np.float64),
        "action_scale": np.asarray(act_scale, dtype=np.float64),
    }
    for i, (w, b) in enumerate(layers):
        tensors[f"layer{i}.weight"] = w.astype(np.float32)
        tensors[f"layer{i}.bias"] = b.astype(np.float32)
    metadata = {
        "format": FORMAT,
        "task": cfg.task,
        "variant": cfg.variant or "",
        "chunk_len": str(cfg.chunk_len),
        "obs_history": str(cfg.obs_history),
        "num_layers": str(len(layers)),
        "activation": "relu",
        "num_train_timesteps": str(cfg.num_train_timesteps),
        "ddim_steps": str(cfg.ddim_steps),
        "group": f"C{cfg.group_order}" if cfg.equivariant else "none",
        "observation_layout": json.dumps(sym.layout("observation"), default=lambda f: f.__dict__),
        "config": json.dumps(asdict(cfg)),
        **{k: str(v) for k, v in meta.items()},
    }
    save_file(tensors, str(out), metadata=metadata)


# -- reference sampler (float64, the same maths as the Rust runtime) ---------------------------
class ExportedPolicy:
    """The exported file run in numpy/torch: for parity tests and speed comparisons."""

    def __init__(self, path: str | Path, dtype: torch.dtype = torch.float64):
        from safetensors import safe_open
        from safetensors.numpy import load_file

        t = load_file(str(path))
        with safe_open(str(path), "np") as f:
            self.meta = f.metadata()
        n = int(self.meta["num_layers"])
        self.layers = [
            (torch.tensor(t[f"layer{i}.weight"], dtype=dtype), torch.tensor(t[f"layer{i}.bias"], dtype=dtype))
            for i in range(n)
        ]
        self.abar = t["alphas_cumprod"]
        self.temb = torch.tensor(t["time_embedding"], dtype=dtype)
        self.obs_off, self.obs_scale = (torch.tensor(t[k], dtype=dtype) for k in ("obs_offset", "obs_scale"))
        self.act_off, self.act_scale = (torch.tensor(t[k], dtype=dtype) for k in ("action_offset", "action_scale"))
        self.dtype = dtype
        self.T = int(self.meta["num_train_timesteps"])

    def mlp(self, x: torch.Tensor) -> torch.Tensor:
        for i, (w, b) in enumerate(self.layers):
            x = x @ w.T + b
            if i + 1 < len(self.layers):
                x = torch.relu(x)
        return x

    @torch.no_grad()
    def sample(self, obs: np.ndarray, w: np.ndarray, steps: int = 5) -> np.ndarray:
        o = (torch.as_tensor(obs, dtype=self.dtype) - self.obs_off) / self.obs_scale
        x = torch.as_tensor(w, dtype=self.dtype).clone()
        ts = ddim_timesteps(self.T, steps)
        for k, t in enumerate(ts):
            prev = ts[k + 1] if k + 1 < len(ts) else -1
            ab, ab_prev = float(self.abar[t]), (float(self.abar[prev]) if prev >= 0 else 1.0)
            eps = self.mlp(torch.cat([o, x, self.temb[t].expand(len(x), -1)], dim=1))
            x0 = (x - math.sqrt(1 - ab) * eps) / math.sqrt(ab)
            x = math.sqrt(ab_prev) * x0 + math.sqrt(1 - ab_prev) * eps
        return (x * self.act_scale + self.act_off).numpy()


def evaluate(
    policy_path: str | Path,
    episodes: int = EVAL_EPISODES,
    seed: int = 0,
    scale: float = 1.0,
    threads: int = 1,
    **env_kwargs: Any,
) -> dict[str, Any]:
    """The base policy's success ('before steering') on the pinned evaluation starts
    (``_core.EVAL_SEED + k``, the starts every steering run is evaluated on; the demos come from
    seeds below 1000): latent noise N(0, scale^2 I) clipped to the bound, an episode succeeds if
    any step does. The policy's own reset variant is used. Returns ``_core.evaluate_base``'s
    dict (successes, episodes, success_rate, Wilson 95 % ``low`` / ``high``, per-episode
    ``outcomes``)."""
    from safetensors import safe_open

    from equigym import _core

    with safe_open(str(policy_path), "np") as f:
        meta = f.metadata()
    task = meta["task"]
    env_kwargs.setdefault("variant", meta.get("variant") or None)
    return _core.evaluate_base(
        task, policy=str(policy_path), episodes=episodes, seed=seed, scale=scale, threads=threads, env=env_kwargs
    )


def format_rate(res: dict[str, Any]) -> str:
    """``k/n = p [low, high]`` (Wilson 95 %)."""
    return f"{res['successes']}/{res['episodes']} = {res['success_rate']:.3f} [{res['low']:.3f}, {res['high']:.3f}]"


#: The benchmark's columns (chunks/s): the Rust runtime on its default kernel (the C8 hidden
#: layers in the Fourier basis) and on the dense one (the file's matrices), both with a float32
#: network, and the same MLP + DDIM in PyTorch.
BENCH_RUST = "rust (default kernel)"
BENCH_RUST_DENSE = "rust (dense kernel)"
BENCH_TORCH32 = "pytorch (float32)"
BENCH_TORCH64 = "pytorch (float64)"


def benchmark(
    policy_path: str | Path, batches: tuple[int, ...] = (1, 256), seconds: float = 2.0
) -> list[dict[str, Any]]:
    """Chunks per second of the Rust runtime (float32 network, on its default Fourier kernel and on
    the dense one, the file's own matrices) and of the same MLP + DDIM in PyTorch (float32 and
    float64), side by side, on this machine's threads."""
    from equigym import _core

    rust = _core.DiffusionPolicy(str(policy_path))
    dense = _core.DiffusionPolicy(str(policy_path), kernel="dense")
    rows = []
    for b in batches:
        rng = np.random.default_rng(0)
        obs = rng.normal(size=(b, rust.obs_dim)) * 0.05
        w = rng.normal(size=(b, rust.action_dim))
        entries = {
            BENCH_RUST: functools.partial(rust.sample, obs, w),
            BENCH_RUST_DENSE: functools.partial(dense.sample, obs, w),
        }
        for name, dt in ((BENCH_TORCH32, torch.float32), (BENCH_TORCH64, torch.float64)):
            entries[name] = functools.partial(ExportedPolicy(policy_path, dt).sample, obs, w)
        row: dict[str, Any] = {"batch": b}
        for name, fn in entries.items():
            fn()
            n, t0 = 0, time.perf_counter()
            while time.perf_counter() - t0 < seconds:
                fn()
                n += 1
            row[name] = n * b / (time.perf_counter() - t0)
        rows.append(row)
    return rows


def predictability(
    demo_path: str | Path, histories: tuple[int, ...] = (0, 1), folds: int = 5, features: int = 1024, seed: int = 0
) -> list[dict[str, Any]]:
    """Is the demo action a function of the observation? Per history length h, regress the action
    a_t on [o_t, o_t - o_{t-1}, ..., o_{t-h+1} - o_{t-h}] (ridge regression on random ReLU
    features: a smooth regressor with no training loop) and report the held-out squared error
    per action dimension, divided by that dimension's variance (1: no better than the mean), with
    demos held out whole (``folds`` groups). If a step of history lowers it, the action depends
    on motion the observation does not show (the arm lags its commands), or on the expert's
    hidden timers; what remains is multimodality or noise. Hand-written because it is ten lines
    of numpy, not a model to fit well."""
    data = load_demos(demo_path)
    demos = data["demos"]
    if len(demos) < folds:
        raise ValueError(f"{len(demos)} demos cannot be split into {folds} held-out groups")
    rows = []
    for h in histories:
        X, Y, G = [], [], []
        for i, d in enumerate(demos):
            o, a = np.asarray(d["obs"], dtype=np.float64), np.asarray(d["actions"], dtype=np.float64)
            for t in range(len(a)):
                parts = [o[t]] + [o[max(t - j, 0)] - o[max(t - j - 1, 0)] for j in range(h)]
                X.append(np.concatenate(parts))
                Y.append(a[t])
                G.append(i)
        X, Y, G = np.asarray(X), np.asarray(Y), np.asarray(G)
        X = (X - X.mean(0)) / (X.std(0) + 1e-9)
        rng = np.random.default_rng(seed)
        H = np.maximum(
            X @ rng.normal(size=(X.shape[1], features)) / math.sqrt(X.shape[1]) + rng.normal(size=features), 0
        )
        err = np.zeros_like(Y)
        for f in range(folds):
            train_rows, test_rows = G % folds != f, G % folds == f
            A = H[train_rows]
            beta = np.linalg.solve(A.T @ A + 0.1 * len(A) * np.eye(features), A.T @ Y[train_rows])
            err[test_rows] = H[test_rows] @ beta - Y[test_rows]
        nmse = (err**2).mean(0) / (Y.var(0) + 1e-12)
        rows.append({"history": h, "samples": len(Y), "nmse": [float(v) for v in nmse]})
    return rows


def expert_under_noise(
    task: str, episodes: int, noise: float, corr: float = 0.9, variant: str | None = None
) -> dict[str, Any]:
    """The scripted expert with its commands executed under DART's execution noise (the demos'
    ``--execution-noise``), on starts 0..episodes-1: successes, and for each failure the phases
    it went through (how robust the demonstrated behaviour is to a policy's own errors)."""
    from equigym import _core
    from equigym.demos import ExecutionNoise

    env = _core.Env(task, variant=variant)
    expert = _core.Expert(task)
    successes, paths = 0, []
    for start in range(episodes):
        env.reset(start)
        expert.reset(env, start)
        exec_noise = ExecutionNoise(start, noise, corr)
        phases: list[str] = []
        for _ in range(env.horizon):
            a = expert.act(env)
            if not phases or phases[-1] != expert.phase:
                phases.append(expert.phase)
            _, _, _, truncated, info = env.step(exec_noise.apply(a))
            if info["success"] or truncated:
                break
        if info["success"]:
            successes += 1
        else:
            paths.append(" ".join(phases))
    low, high = _core.wilson(successes, episodes)
    ends = collections.Counter(p.split()[-1] for p in paths)
    return {
        "task": task,
        "noise": noise,
        "episodes": episodes,
        "successes": successes,
        "low": low,
        "high": high,
        "failed_in_phase": dict(ends.most_common()),
        "failure_paths": dict(collections.Counter(paths).most_common(8)),
    }


#: Height (m) above its rest height at which a carried object counts as lifted.
LIFTED = 0.01
#: Commanded gripper width (m) above which a loss of grasp counts as the policy opening the
#: hand: halfway between the experts' grasp command (0 for the cubes, 0.8 cm for the nut's
#: handle) and fully open (8 cm). (The Square screen's ring-grasp rows, whose expert commanded
#: 6 cm, were counted at 7 cm.)
OPENED_WIDTH = {"lift": 0.04, "stack": 0.04, "square": 0.044}
#: The experts' grasp width command (m), per task (open is the gripper's full 8 cm).
GRASP_WIDTH = {"lift": 0.0, "stack": 0.0, "square": 0.008}
#: Distance (m) from the place target within which a loss counts as "over the target".
OVER_TARGET = 0.03
#: The carried object's height and its horizontal distance to the place target, per task.
_FAILURE_TERMS = {
    "stack": ("cubeA_height", "cubes_xy_distance"),
    "lift": ("cube_height", None),
    "square": ("nut_height", "nut_peg_xy_distance"),
}


#: The carried object's and the place target's position fields, per task with a place target.
_CARRY_FIELDS = {"stack": ("cubeA_pos", "cubeB_pos"), "square": ("nut_pos", "peg_pos")}
#: Height (m) above its start at which an object counts as carried (the lift itself is vertical).
CARRIED = 0.05


def toward_target(obs: np.ndarray, actions: np.ndarray, fields: dict[str, int], task: str) -> tuple[int, int]:
    """Does the hand carry the object towards the place target? Over one episode's steps
    (``obs[t]`` the observation ``actions[t]`` was chosen at; ``fields`` each field's start),
    those where the object is more than ``CARRIED`` above its start height and more than
    ``OVER_TARGET`` from the target horizontally and the command moves the hand more than 3 mm
    horizontally: how many point within 30 degrees of the object-to-target direction, of how
    many. The same count on demos and on a policy's rollouts says whether it knows where to go."""
    if task not in _CARRY_FIELDS or len(obs) == 0:
        return 0, 0
    obj_f, target_f = (fields[n] for n in _CARRY_FIELDS[task])
    grip_f = fields["gripper_pos"]
    obj, target, grip = obs[:, obj_f : obj_f + 3], obs[:, target_f : target_f + 3], obs[:, grip_f : grip_f + 3]
    to_target = target[:, :2] - obj[:, :2]
    command = actions[:, :2] - grip[:, :2]
    dist, moved = np.linalg.norm(to_target, axis=1), np.linalg.norm(command, axis=1)
    rows = (obj[:, 2] > obj[0, 2] + CARRIED) & (dist > OVER_TARGET) & (moved > 0.003)
    cos = np.einsum("ij,ij->i", to_target[rows], command[rows]) / (dist[rows] * moved[rows])
    return int((cos > math.cos(math.radians(30))).sum()), int(rows.sum())


def _field_starts(task: str) -> dict[str, int]:
    """Where each observation field of ``task`` starts."""
    from equigym import _core

    return {f["name"]: f["start"] for f in _core.TaskSymmetry(task).layout("observation")}


def demos_toward_target(demo_path: str | Path) -> dict[str, Any]:
    """``toward_target`` over every demo of a file (the reference for a policy's rollouts)."""
    data = load_demos(demo_path)
    fields = _field_starts(data["task"])
    hits = total = 0
    for d in data["demos"]:
        h, n = toward_target(np.asarray(d["obs"]), np.asarray(d["actions"]), fields, data["task"])
        hits, total = hits + h, total + n
    return {"demos": str(demo_path), "toward_target": hits, "carry_steps": total, "fraction": hits / max(total, 1)}


#: First start of the validation starts (``VALIDATION_SEED + k``): disjoint from the demos (seeds
#: below 1000), the pinned evaluation starts (``EVAL_SEED + k``) and the steerability
#: diagnostic's (3,000,000 + k), so that choosing among trained policies on them leaves the
#: evaluation starts unbiased.
VALIDATION_SEED = 5_000_000


def failures(
    policy_path: str | Path,
    episodes: int = 60,
    seed: int = 0,
    ddim_steps: int | None = None,
    first_start: int | None = None,
    snap_gripper: bool = False,
) -> dict[str, Any]:
    """How the base policy fails, episode by episode, on the pinned evaluation starts: each
    episode runs to success or the horizon and is one of ``success``, ``never lifted``, ``held
    at horizon`` (lifted and still grasped at the end), ``opened away`` / ``opened over target``
    (its last loss of a lifted object was on a step whose chunk commanded the hand open, away
    from or over the place target), ``slipped`` (lost while commanded closed); Square also has ``on target, not let go`` (the nut sits on the peg
    at the horizon but the hand has not left it). The latent noise is N(0, I) clipped to the
    bound, drawn from ``seed`` (the same distribution as ``eval``, not the same draws); the
    policy's conditioning (``obs_history``) is built here, so history policies run too.
    ``successes_after_a_drop`` counts successes that regrasped after a drop, ``reached_target``
    the episodes that held the lifted object within ``OVER_TARGET`` of the place target at some
    step (Lift has no place target: 0), ``carry_steps`` / ``toward_target`` the carrying steps
    and those whose command heads for the target (``toward_target``). ``first_start``
    (default ``EVAL_SEED``) moves the starts, e.g. to the validation starts ``VALIDATION_SEED``.
    ``snap_gripper`` executes each width command as the expert's grasp width or fully open,
    split at ``OPENED_WIDTH`` (a test of whether in-between commands lose the object)."""
    from equigym import _core

    pol = _core.DiffusionPolicy(str(policy_path))
    task = pol.task
    if task not in _FAILURE_TERMS:
        raise ValueError(f"failures knows {sorted(_FAILURE_TERMS)}, not {task}")
    height_term, target_term = _FAILURE_TERMS[task]
    meta = pol.metadata
    envs = [_core.Env(task, variant=meta.get("variant") or None) for _ in range(episodes)]
    first = _core.EVAL_SEED if first_start is None else first_start
    obs = np.stack([e.reset(first + k) for k, e in enumerate(envs)])
    prev = obs.copy()
    history = int(meta.get("obs_history", "1"))
    rng = np.random.default_rng(seed)
    bound = 1.5
    steps = ddim_steps or pol.default_ddim_steps
    live = np.ones(episodes, bool)
    outcome: list[str | None] = [None] * episodes
    lifted = np.zeros(episodes, bool)
    grasped = np.zeros(episodes, bool)
    on_target = np.zeros(episodes, bool)
    reached = np.zeros(episodes, bool)
    seen: list[list[np.ndarray]] = [[] for _ in range(episodes)]
    commanded: list[list[np.ndarray]] = [[] for _ in range(episodes)]
    # The most recent loss of a lifted object (an episode goes on after one: the policy may
    # regrasp), and the number of drops (losses away from the target or while closed).
    last_loss: list[str | None] = [None] * episodes
    losses = np.zeros(episodes, int)
    loss_where: list[tuple[float, float] | None] = [None] * episodes
    horizon = envs[0].horizon
    open_width = envs[0].spec.max_gripper_width
    t = 0
    while live.any() and t < horizon:
        idx = np.flatnonzero(live)
        w = np.clip(rng.standard_normal((len(idx), pol.action_dim)), -bound, bound)
        cond = conditioning(obs[idx], prev[idx], history)
        chunks = pol.sample(cond, w, steps).reshape(len(idx), pol.chunk_len, 10)
        for j, i in enumerate(idx):
            for a in chunks[j]:
                if snap_gripper:
                    a = a.copy()
                    a[9] = GRASP_WIDTH[task] if a[9] < OPENED_WIDTH[task] else open_width
                prev[i] = obs[i]
                seen[i].append(obs[i].copy())
                commanded[i].append(np.asarray(a, dtype=np.float64))
                o, _, _, truncated, info = envs[i].step(a)
                obs[i] = o
                g = info["grasped"] > 0.5
                if grasped[i] and not g and lifted[i]:
                    far = target_term is None or info[target_term] > OVER_TARGET
                    if a[9] > OPENED_WIDTH[task]:
                        last_loss[i] = "opened away" if far else "opened over target"
                    else:
                        last_loss[i] = "slipped"
                    losses[i] += last_loss[i] != "opened over target"
                    loss_where[i] = (info[target_term] if target_term else float("nan"), info[height_term])
                    lifted[i] = False
                grasped[i] = g
                on_target[i] = info.get("on_peg", 0.0) > 0.5
                lifted[i] |= g and info[height_term] > LIFTED
                reached[i] |= bool(lifted[i] and target_term and info[target_term] <= OVER_TARGET)
                if info["success"]:
                    outcome[i] = "success"
                if outcome[i] is not None or truncated:
                    live[i] = False
                    break
        t += pol.chunk_len
    for i in range(episodes):
        if outcome[i] is not None:
            continue
        if on_target[i]:
            outcome[i] = "on target, not let go"
        elif grasped[i] and lifted[i]:
            outcome[i] = "held at horizon"
        else:
            outcome[i] = last_loss[i] or "never lifted"
    counts = {k: outcome.count(k) for k in FAILURE_KINDS if k in outcome}
    low, high = _core.wilson(counts.get("success", 0), episodes)
    fields = _field_starts(task)
    carry = [toward_target(np.asarray(o), np.asarray(a), fields, task) for o, a in zip(seen, commanded) if o]
    toward, carry_steps = sum(h for h, _ in carry), sum(n for _, n in carry)
    return {
        "task": task,
        "first_start": first,
        "episodes": episodes,
        "success_rate": counts.get("success", 0) / episodes,
        "low": low,
        "high": high,
        "counts": counts,
        "successes_after_a_drop": int(sum(o == "success" and n > 0 for o, n in zip(outcome, losses))),
        "snap_gripper": snap_gripper,
        "reached_target": int(reached.sum()),
        # Steps carrying the object (see ``toward_target``) and those heading for the target.
        "carry_steps": carry_steps,
        "toward_target": toward,
        "outcomes": outcome,
        # Per episode: the place target's horizontal distance and the object's height (m) at its
        # last loss (None if it was never lost).
        "last_loss_at": loss_where,
    }


#: The outcomes ``failures`` tells apart.
FAILURE_KINDS = (
    "success",
    "never lifted",
    "opened away",
    "opened over target",
    "slipped",
    "held at horizon",
    "on target, not let go",
)


def _eval_seed() -> int:
    from equigym import _core

    return int(_core.EVAL_SEED)


def report(out: str | Path, episodes: int = EVAL_EPISODES, seconds: float = 2.0, threads: int = 1) -> str:
    """Evaluate every shipped policy (assets/edp/<task>.safetensors) and benchmark the runtime;
    write a Markdown table to ``out`` and return it."""
    import platform

    from equigym.assets import asset_dir

    lines = [
        "# Shipped equivariant diffusion policies",
        "",
        f"Generated by `python -m baselines.edp report --episodes {episodes}` ({platform.machine()}, "
        f"torch {torch.__version__}, {torch.get_num_threads()} torch thread(s), load average "
        f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs at the start: timings on a busy machine are low).",
        "",
        "Base-policy success ('before steering'): latent noise w ~ N(0, I) clipped to +-1.5, deterministic "
        f"DDIM with 5 steps, on the {episodes} pinned evaluation starts (seeds {_eval_seed()} + k, the starts "
        "every steering run is evaluated on; the demos are recorded from seeds below 1000), an episode succeeds "
        "if any step does; Wilson 95 % intervals.",
        "",
        "| task | demos | group | parameters | training steps | final loss | base success |",
        "|---|---:|---|---:|---:|---:|---:|",
    ]
    bench_rows = []
    for task in ("lift", "stack", "square"):
        path = asset_dir("edp") / f"{task}.safetensors"
        if not path.exists():
            lines.append(f"| {task} | - | - | - | - | - | not shipped yet |")
            continue
        from safetensors import safe_open

        with safe_open(str(path), "np") as f:
            meta = f.metadata()
        cfg = json.loads(meta.get("config", "{}"))
        variant = meta.get("variant") or None
        res = evaluate(path, episodes, threads=threads)
        lines.append(
            f"| {task} {variant or ''} | {meta.get('demos', '?')} | {meta.get('group')} | {meta.get('params', '?')} "
            f"| {cfg.get('steps', '?')} | {float(meta.get('final_loss', 'nan')):.4f} | {format_rate(res)} |"
        )
        if not bench_rows:
            bench_rows = benchmark(path, seconds=seconds)
            bench_task = task
    if bench_rows:
        lines += [
            "",
            f"Inference speed ({bench_task} policy, chunks per second, one thread each; the same MLP and DDIM: "
            "Rust `DiffusionPolicy.sample` on its default kernel (the C8 hidden layers in the Fourier basis) and "
            "on the dense one (the file's matrices), and PyTorch on the exported layers):",
            "",
            "| batch | " + " | ".join(k for k in bench_rows[0] if k != "batch") + " |",
            "|---:|" + "---:|" * (len(bench_rows[0]) - 1),
        ]
        for row in bench_rows:
            lines.append(
                f"| {row['batch']} | " + " | ".join(f"{v:,.0f}" for k, v in row.items() if k != "batch") + " |"
            )
    text = "\n".join(lines) + "\n"
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    # What follows the marker is written by hand (how the policies got here) and kept.
    kept = out.read_text().split(REPORT_MARKER, 1)[1] if out.exists() and REPORT_MARKER in out.read_text() else "\n"
    out.write_text(text + "\n" + REPORT_MARKER + kept)
    return text


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train", help="train an EDP on a demo file and export it")
    t.add_argument("--demos", required=True)
    t.add_argument("--out", required=True)
    t.add_argument("--plain", action="store_true", help="non-equivariant MLP of similar size")
    t.add_argument("--steps", type=int, default=EDPConfig.steps)
    t.add_argument("--hidden-fields", type=int, default=EDPConfig.hidden_fields)
    t.add_argument("--hidden-layers", type=int, default=EDPConfig.hidden_layers)
    t.add_argument("--batch-size", type=int, default=EDPConfig.batch_size)
    t.add_argument("--lr", type=float, default=EDPConfig.lr)
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--obs-history", type=int, choices=(1, 2), default=EDPConfig.obs_history)
    t.add_argument("--fresh", action="store_true", help="ignore a matching <out>.ckpt instead of resuming it")
    e = sub.add_parser("eval", help="base-policy success (w ~ N(0, scale^2 I)) on the pinned evaluation starts")
    e.add_argument("--policy", required=True)
    e.add_argument("--episodes", type=int, default=EVAL_EPISODES)
    e.add_argument("--seed", type=int, default=0, help="seed of the noise streams")
    e.add_argument("--scale", type=float, default=1.0, help="noise scale s (narrow-noise controls: s < 1)")
    e.add_argument("--threads", type=int, default=1, help="threads (results do not depend on it)")
    e.add_argument("--controller", choices=("joint", "cartesian"), default=None)
    b = sub.add_parser("bench", help="chunks/s of the Rust runtime vs PyTorch, batch 1 and 256")
    b.add_argument("--policy", required=True)
    b.add_argument("--seconds", type=float, default=2.0)
    r = sub.add_parser("report", help="evaluate and benchmark the shipped policies into a Markdown file")
    r.add_argument("--out", default="docs/edp.md")
    r.add_argument("--episodes", type=int, default=EVAL_EPISODES)
    r.add_argument("--threads", type=int, default=1, help="evaluation threads (results do not depend on it)")
    xn = sub.add_parser(
        "expert-noise", help="the scripted expert under DART's execution noise: success, failing phases"
    )
    xn.add_argument("--task", required=True)
    xn.add_argument("--variant", default=None)
    xn.add_argument("--episodes", type=int, default=80)
    xn.add_argument("--noise", type=float, default=0.005)
    cd = sub.add_parser("carry-direction", help="how often the demos' carrying commands head for the place target")
    cd.add_argument("--demos", required=True)
    q = sub.add_parser("predictability", help="held-out error of the demo action regressed on the observation")
    q.add_argument("--demos", required=True)
    q.add_argument("--histories", nargs="+", type=int, default=[0, 1, 2])
    f = sub.add_parser("failures", help="how the base policy loses the object (Lift, Stack), pinned starts")
    f.add_argument("--policy", required=True)
    f.add_argument("--episodes", type=int, default=60)
    f.add_argument("--seed", type=int, default=0)
    f.add_argument("--ddim-steps", type=int, default=None)
    f.add_argument(
        "--validation", action="store_true", help=f"on the validation starts ({VALIDATION_SEED} + k), for model choice"
    )
    f.add_argument("--snap-gripper", action="store_true", help="execute width commands as grasp or open only")
    a = p.parse_args(argv)
    if a.cmd == "failures":
        res = failures(
            a.policy, a.episodes, a.seed, a.ddim_steps, VALIDATION_SEED if a.validation else None, a.snap_gripper
        )
        print(json.dumps({k: v for k, v in res.items() if k not in ("outcomes", "last_loss_at")}))
    elif a.cmd == "expert-noise":
        print(json.dumps(expert_under_noise(a.task, a.episodes, a.noise, variant=a.variant)))
    elif a.cmd == "carry-direction":
        print(json.dumps(demos_toward_target(a.demos)))
    elif a.cmd == "predictability":
        for row in predictability(a.demos, tuple(a.histories)):
            print(json.dumps({**row, "nmse": [round(v, 4) for v in row["nmse"]]}))
    elif a.cmd == "report":
        torch.set_num_threads(1)
        print(report(a.out, a.episodes, threads=a.threads))
    elif a.cmd == "eval":
        res = evaluate(a.policy, a.episodes, a.seed, a.scale, a.threads, controller=a.controller)
        print(json.dumps({k: v for k, v in res.items() if k != "outcomes"}))
    elif a.cmd == "bench":
        torch.set_num_threads(1)
        for row in benchmark(a.policy, seconds=a.seconds):
            print(json.dumps({k: (round(v, 1) if isinstance(v, float) else v) for k, v in row.items()}))
    elif a.cmd == "train":
        cfg = EDPConfig(
            equivariant=not a.plain,
            steps=a.steps,
            hidden_fields=a.hidden_fields,
            hidden_layers=a.hidden_layers,
            batch_size=a.batch_size,
            lr=a.lr,
            seed=a.seed,
            obs_history=a.obs_history,
        )
        print(json.dumps(train(cfg, a.demos, a.out, resume=not a.fresh)))


if __name__ == "__main__":
    main()
