"""Steering agents for the latent-action MDP, as stable-baselines3 SAC policies.

- ``dsrl``: SB3 SAC with MLP actor and twin critics (Tanh, LayerNorm after each linear layer),
  the DSRL recipe.
- ``equi``: Equi-DSRL: a C_N-equivariant actor (means in the latent's representation, one shared
  log-std per rho1 pair and per rho0 value) and C_N-invariant twin critics (regular hidden fields,
  group pooling), built with escnn; every hidden linear layer is followed by a field-tied
  LayerNorm (one gain and shift per regular field) and Tanh, the DSRL recipe made equivariant. The bounded action stays exactly equivariant with a radial
  squash per rho1 pair, a = tanh(|u|) u / |u| (``squash="radial"``, default), whose log-det
  log(1 - tanh^2 |u|) + log(tanh|u| / |u|) corrects the log-probability; ``squash="tanh"`` keeps
  the elementwise tanh (equivariant for C4 only).
- ``approx``: Approx-Equi-DSRL (residual pathway priors): every layer is an equivariant layer plus
  a parallel plain layer, summed; weight decay 1e-5 on the equivariant path, 1e-2 on the plain one.

SB3 stores actions scaled to [-1, 1]; the latent box is symmetric, so that scaling is a single
factor that commutes with the group.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn as nn
from gymnasium import spaces
from stable_baselines3.common.policies import BaseModel, BasePolicy
from stable_baselines3.sac.policies import Actor, SACPolicy

from baselines.equivariant import block_types
from equigym.symmetry import Symmetry

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


# -- plain MLP with LayerNorm (DSRL) ---------------------------------------------------------
def ln_mlp(in_dim: int, widths: list[int], activation: type[nn.Module] = nn.Tanh) -> nn.Sequential:
    layers: list[nn.Module] = []
    for w in widths:
        layers += [nn.Linear(in_dim, w), nn.LayerNorm(w), activation()]
        in_dim = w
    return nn.Sequential(*layers)


class LayerNormSACPolicy(SACPolicy):
    """SB3's SAC policy with LayerNorm after every hidden linear layer (actor and critics)."""

    def make_actor(self, features_extractor=None) -> Actor:
        actor = super().make_actor(features_extractor)
        actor.latent_pi = ln_mlp(actor.features_dim, list(self.actor_kwargs["net_arch"]), self.activation_fn).to(
            self.device
        )
        return actor

    def make_critic(self, features_extractor=None):
        critic = super().make_critic(features_extractor)
        qf_in = critic.features_extractor.features_dim + get_action_dim(self.action_space)
        arch = list(self.critic_kwargs["net_arch"])
        for i in range(len(critic.q_networks)):
            net = nn.Sequential(ln_mlp(qf_in, arch, self.activation_fn), nn.Linear(arch[-1], 1)).to(self.device)
            critic.q_networks[i] = net
            critic.add_module(f"qf{i}", net)
        return critic


def get_action_dim(space: spaces.Box) -> int:
    return int(np.prod(space.shape))


# -- equivariant building blocks -------------------------------------------------------------
class _Group:
    """escnn field types for a task's observation and latent blocks."""

    def __init__(self, sym: Symmetry):
        from escnn import group, gspaces
        from escnn import nn as enn

        self.enn = enn
        self.order = sym.order
        self.gs = gspaces.no_base_space(group.cyclic_group(sym.order))
        self.obs_blocks, self.lat_blocks = sym.blocks("observation"), sym.blocks("latent")
        self.obs_reps, self.obs_perm = block_types(self.gs, self.obs_blocks)
        self.lat_reps, self.lat_perm = block_types(self.gs, self.lat_blocks)

    def regular(self, fields: int):
        return self.enn.FieldType(self.gs, fields * [self.gs.regular_repr])


EQUI_INITS = ("escnn", "torch")


def _torch_default_scale(linear) -> None:
    """Scale an escnn Linear's basis coefficients so that its expanded matrix has the RMS of
    ``torch.nn.Linear``'s default initialisation, U(+-1/sqrt(fan_in)), i.e. 1/sqrt(3 fan_in).

    escnn's own scheme (generalised He) gives the 192 -> 192 and 192 -> head layers of the cpu
    preset an RMS of about 0.072 where that is 0.042; the Rust agents start from PyTorch's
    scale. Hidden layers are followed by a LayerNorm, so what this changes is the actor head's
    (mean and log-std) and the first layers' scale."""
    with torch.no_grad():
        matrix, _ = linear.expand_parameters()
        rms = matrix.pow(2).mean().sqrt()
        linear.weights.mul_(1.0 / math.sqrt(3 * linear.in_type.size) / rms)


class _ResidualLinear(nn.Module):
    """An escnn Linear plus (for RPP) a parallel plain Linear on the same tensors, summed.
    ``init``: ``"escnn"`` (escnn's generalised He initialisation) or ``"torch"`` (the same
    coefficients scaled to PyTorch's default RMS, see ``_torch_default_scale``)."""

    def __init__(self, g: _Group, in_type, out_type, residual: bool, init: str = "escnn"):
        super().__init__()
        if init not in EQUI_INITS:
            raise ValueError(f"init must be one of {EQUI_INITS}, got {init!r}")
        self.equi = g.enn.Linear(in_type, out_type)
        if init == "torch":
            _torch_default_scale(self.equi)
        self.plain = nn.Linear(in_type.size, out_type.size) if residual else None
        self.out_type = out_type

    def forward(self, x):
        y = self.equi(x)
        if self.plain is not None:
            y = self.out_type(y.tensor + self.plain(x.tensor))
        return y


class _FieldNorm(nn.Module):
    """LayerNorm over all units of a row of regular fields with one gain and one shift per field.

    The row's mean and variance are invariant under the cyclic shifts within fields and a tied
    gain and shift commute with them, so the layer is exactly equivariant (DSRL's LayerNorm made
    equivariant; the Rust agents' ``Layer::Norm``)."""

    def __init__(self, ftype, order: int):
        super().__init__()
        self.out_type, self.order = ftype, order
        fields = ftype.size // order
        self.weight = nn.Parameter(torch.ones(fields))
        self.bias = nn.Parameter(torch.zeros(fields))

    def forward(self, x):
        t = x.tensor
        gain, shift = self.weight.repeat_interleave(self.order), self.bias.repeat_interleave(self.order)
        return self.out_type(nn.functional.layer_norm(t, (t.shape[-1],), gain, shift, eps=1e-5))


@dataclass(frozen=True)
class EquiArch:
    """The shape of the equivariant actor and critics, given once to the policy and shared by
    both: the symmetry, regular fields per hidden layer, hidden layers, RPP (``residual``) and
    the weight initialisation (``escnn`` or ``torch``)."""

    symmetry: Symmetry
    hidden_fields: int
    layers: int
    residual: bool = False
    init: str = "escnn"


class _EquiTrunk(nn.Module):
    """in_type -> [Linear + field-tied LayerNorm + Tanh] x layers on regular fields (escnn,
    optionally RPP)."""

    def __init__(self, g: _Group, in_type, arch: EquiArch):
        super().__init__()
        mods: list[nn.Module] = []
        t = in_type
        for _ in range(arch.layers):
            h = g.regular(arch.hidden_fields)
            mods += [
                _ResidualLinear(g, t, h, arch.residual, arch.init),
                _FieldNorm(h, g.order),
                g.enn.PointwiseNonLinearity(h, "p_tanh"),
            ]
            t = h
        self.net = nn.Sequential(*mods)
        self.out_type = t

    def forward(self, x):
        return self.net(x)


def _radial_squash(u: torch.Tensor, pairs: torch.Tensor, singles: torch.Tensor):
    """Squash u (B, d) into [-1, 1]^d: radial tanh on each (x, y) pair, tanh elsewhere.
    Returns (a, log|det J|)."""
    a = torch.empty_like(u)
    logdet = torch.zeros(u.shape[0], device=u.device, dtype=u.dtype)
    if len(pairs):
        v = u[:, pairs]  # (B, P, 2)
        r = v.norm(dim=-1).clamp_min(1e-8)
        t = torch.tanh(r)
        a[:, pairs] = v * (t / r).unsqueeze(-1)
        ratio = torch.where(r < 1e-4, 1.0 - r * r / 3.0, t / r)  # tanh(r)/r -> 1 as r -> 0
        logdet = logdet + (torch.log1p(-t * t + 1e-7) + torch.log(ratio)).sum(dim=1)
    if len(singles):
        t = torch.tanh(u[:, singles])
        a[:, singles] = t
        logdet = logdet + torch.log1p(-t * t + 1e-7).sum(dim=1)
    return a, logdet


class EquiActor(BasePolicy):
    """C_N-equivariant squashed Gaussian actor over the latent noise."""

    def __init__(
        self,
        observation_space,
        action_space,
        features_extractor,
        features_dim,
        *,
        arch: EquiArch,
        squash: str = "radial",
        **_: Any,
    ):
        super().__init__(observation_space, action_space, features_extractor=features_extractor, squash_output=True)
        if squash not in ("radial", "tanh"):
            raise ValueError(f"squash must be 'radial' or 'tanh', got {squash!r}")
        g = _Group(arch.symmetry)
        self.squash = squash
        self.in_type = g.enn.FieldType(g.gs, g.obs_reps)
        self.trunk = _EquiTrunk(g, self.in_type, arch)
        n_blocks = len(g.lat_blocks)
        self.head_type = g.enn.FieldType(g.gs, g.lat_reps + n_blocks * [g.gs.trivial_repr])
        self.head = _ResidualLinear(g, self.trunk.out_type, self.head_type, arch.residual, arch.init)
        self.register_buffer("obs_perm", torch.tensor(g.obs_perm))
        lat_dim = len(g.lat_perm)
        self.register_buffer("lat_inv", torch.tensor(np.argsort(g.lat_perm)))
        # Per latent dimension (natural order): the index of its block's log-std.
        block_of = np.zeros(lat_dim, dtype=np.int64)
        for b, (_, idx) in enumerate(g.lat_blocks):
            block_of[idx] = b
        self.register_buffer("std_index", torch.tensor(block_of))
        self.register_buffer(
            "pairs", torch.tensor([idx for f, idx in g.lat_blocks if f == 1], dtype=torch.long).reshape(-1, 2)
        )
        self.register_buffer("singles", torch.tensor([idx[0] for f, idx in g.lat_blocks if f == 0], dtype=torch.long))
        self.lat_dim = lat_dim

    def dist_params(self, obs: torch.Tensor):
        feats = self.extract_features(obs, self.features_extractor)
        h = self.trunk(self.in_type(feats[:, self.obs_perm]))
        out = self.head(h).tensor
        mean = out[:, : self.lat_dim][:, self.lat_inv]
        log_std = out[:, self.lat_dim :].clamp(LOG_STD_MIN, LOG_STD_MAX)[:, self.std_index]
        return mean, log_std

    def _squash(self, u):
        if self.squash == "radial":
            return _radial_squash(u, self.pairs, self.singles)
        t = torch.tanh(u)
        return t, torch.log1p(-t * t + 1e-7).sum(dim=1)

    def forward(self, obs, deterministic: bool = False):
        mean, log_std = self.dist_params(obs)
        u = mean if deterministic else mean + log_std.exp() * torch.randn_like(mean)
        return self._squash(u)[0]

    def action_log_prob(self, obs):
        mean, log_std = self.dist_params(obs)
        u = mean + log_std.exp() * torch.randn_like(mean)
        a, logdet = self._squash(u)
        return a, self.log_prob_of(u, mean, log_std) - logdet

    @staticmethod
    def log_prob_of(u, mean, log_std):
        z = (u - mean) / log_std.exp()
        return (-0.5 * z * z - log_std - 0.5 * math.log(2 * math.pi)).sum(dim=1)

    def _predict(self, observation, deterministic: bool = False):
        return self(observation, deterministic)


class EquiCritic(BaseModel):
    """Twin C_N-invariant Q functions: equivariant trunk on [obs, latent], group pooling, linear."""

    def __init__(
        self,
        observation_space,
        action_space,
        features_extractor,
        features_dim,
        *,
        arch: EquiArch,
        n_critics: int = 2,
        **_: Any,
    ):
        super().__init__(observation_space, action_space, features_extractor=features_extractor)
        g = _Group(arch.symmetry)
        self.in_type = g.enn.FieldType(g.gs, g.obs_reps + g.lat_reps)
        obs_dim = len(g.obs_perm)
        self.register_buffer("perm", torch.tensor(g.obs_perm + [obs_dim + i for i in g.lat_perm]))
        self.share_features_extractor = False
        self.n_critics = n_critics
        self.trunks = nn.ModuleList()
        self.pools = nn.ModuleList()
        self.outs = nn.ModuleList()
        self.plain_outs = nn.ModuleList()
        for _ in range(n_critics):
            trunk = _EquiTrunk(g, self.in_type, arch)
            self.trunks.append(trunk)
            self.pools.append(g.enn.GroupPooling(trunk.out_type))
            self.outs.append(nn.Linear(arch.hidden_fields, 1))
            self.plain_outs.append(nn.Linear(trunk.out_type.size, 1) if arch.residual else nn.Identity())
        self.residual = arch.residual

    def _q(self, k: int, x) -> torch.Tensor:
        h = self.trunks[k](x)
        q = self.outs[k](self.pools[k](h).tensor)
        if self.residual:
            q = q + self.plain_outs[k](h.tensor)
        return q

    def forward(self, obs, actions):
        with torch.set_grad_enabled(True if self.training else torch.is_grad_enabled()):
            feats = self.extract_features(obs, self.features_extractor)
        x = self.in_type(torch.cat([feats, actions], dim=1)[:, self.perm])
        return tuple(self._q(k, x) for k in range(self.n_critics))

    def q1_forward(self, obs, actions):
        return self.forward(obs, actions)[0]

    def set_training_mode(self, mode: bool) -> None:
        # escnn caches its expanded weights in eval mode; the target critic's parameters change
        # by Polyak averaging without a mode switch, so critics always expand on the fly.
        self.train(True)


class EquiSACPolicy(SACPolicy):
    """SAC policy with escnn actor and critics (``residual=True`` gives RPP layers)."""

    def __init__(
        self,
        *args: Any,
        symmetry: Symmetry | None = None,
        task: str | None = None,
        hidden_fields: int = 32,
        layers: int = 3,
        residual: bool = False,
        squash: str = "radial",
        equi_weight_decay: float = 1e-5,
        plain_weight_decay: float = 1e-2,
        init: str = "escnn",
        **kwargs: Any,
    ):
        if symmetry is None:
            if task is None:
                raise ValueError("EquiSACPolicy needs symmetry= or task=")
            symmetry = Symmetry(task)
        self._arch = EquiArch(symmetry, hidden_fields, layers, residual, init)
        self._squash = squash
        self._decay = (equi_weight_decay, plain_weight_decay)
        kwargs.setdefault("share_features_extractor", False)
        super().__init__(*args, **kwargs)

    def make_actor(self, features_extractor=None):
        kw = self._update_features_extractor(self.actor_kwargs, features_extractor)
        return EquiActor(
            kw["observation_space"],
            kw["action_space"],
            kw["features_extractor"],
            kw["features_dim"],
            arch=self._arch,
            squash=self._squash,
        ).to(self.device)

    def make_critic(self, features_extractor=None):
        kw = self._update_features_extractor(self.critic_kwargs, features_extractor)
        return EquiCritic(
            kw["observation_space"],
            kw["action_space"],
            kw["features_extractor"],
            kw["features_dim"],
            arch=self._arch,
            n_critics=kw.get("n_critics", 2),
        ).to(self.device)

    # escnn modules in eval mode keep their expanded weights as extra buffers; those are a cache
    # of the parameters, never saved, so a checkpoint loads whatever mode either side was in.
    _ESCNN_CACHE = (".matrix", ".expanded_bias")

    def state_dict(self, *args: Any, **kwargs: Any):
        state = super().state_dict(*args, **kwargs)
        for key in [k for k in state if k.endswith(self._ESCNN_CACHE)]:
            del state[key]
        return state

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        training = self.training
        self.train(True)  # drops the caches, so the keys match the saved ones
        state = {k: v for k, v in state_dict.items() if not k.endswith(self._ESCNN_CACHE)}
        result = super().load_state_dict(state, strict=strict, assign=assign)
        self.set_training_mode(training)
        return result

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        if self._arch.residual:
            # Residual pathway priors: separate L2 strengths on the two paths.
            for module in (self.actor, self.critic):
                plain = [p for n, p in module.named_parameters() if ".plain" in n or "plain_outs" in n]
                ids = {id(p) for p in plain}
                equi = [p for p in module.parameters() if id(p) not in ids]
                module.optimizer = torch.optim.Adam(
                    [
                        {"params": equi, "weight_decay": self._decay[0]},
                        {"params": plain, "weight_decay": self._decay[1]},
                    ],
                    lr=lr_schedule(1),
                )


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
