"""Steering agents: exact equivariance of Equi-DSRL's actor (mean, log-std, log-probability) and
invariance of its critics for all of C8; RPP layers and parameter groups; LayerNorm DSRL nets."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("escnn")
pytest.importorskip("stable_baselines3")

from gymnasium import spaces  # noqa: E402

from baselines.agents import EquiSACPolicy, LayerNormSACPolicy, _radial_squash  # noqa: E402
from equigym import Symmetry  # noqa: E402

OBS = spaces.Box(-np.inf, np.inf, (22,), np.float32)
LATENT = spaces.Box(-1.5, 1.5, (40,), np.float32)


def policy(**kw):
    torch.manual_seed(0)
    return EquiSACPolicy(OBS, LATENT, lambda _: 3e-4, task="lift", hidden_fields=8, layers=2, **kw)


@pytest.mark.parametrize("init", ["escnn", "torch"])
def test_equivariant_actor_and_invariant_critics(init):
    sym = Symmetry("lift")
    pol = policy(init=init)
    obs = torch.randn(6, 22, dtype=torch.float32)
    act = torch.rand(6, 40) * 2 - 1
    mean, log_std = pol.actor.dist_params(obs)
    u = mean + log_std.exp() * torch.randn_like(mean)
    a, logdet = pol.actor._squash(u)
    logp = pol.actor.log_prob_of(u, mean, log_std) - logdet
    qs = pol.critic(obs, act)
    for g in sym.elements:
        go = torch.tensor(sym.act_observation(obs.numpy(), g=g))
        m2, s2 = pol.actor.dist_params(go)
        np.testing.assert_allclose(m2.detach().numpy(), sym.act_latent(mean.detach().numpy(), g=g), atol=1e-5)
        np.testing.assert_allclose(s2.detach().numpy(), log_std.detach().numpy(), atol=1e-5)
        gu = torch.tensor(sym.act_latent(u.detach().numpy(), g=g))
        ga, gdet = pol.actor._squash(gu)
        np.testing.assert_allclose(ga.detach().numpy(), sym.act_latent(a.detach().numpy(), g=g), atol=1e-5)
        glogp = pol.actor.log_prob_of(gu, m2, s2) - gdet
        np.testing.assert_allclose(glogp.detach().numpy(), logp.detach().numpy(), atol=1e-4)
        gact = torch.tensor(sym.act_latent(act.numpy(), g=g))
        for q, gq in zip(qs, pol.critic(go, gact)):
            np.testing.assert_allclose(gq.detach().numpy(), q.detach().numpy(), atol=1e-5)


def test_torch_init_scales_every_equivariant_layer_to_pytorchs_default_rms():
    from escnn import nn as enn

    def rms_ratios(pol):
        out = []
        for m in pol.modules():
            if isinstance(m, enn.Linear):
                matrix, _ = m.expand_parameters()
                out.append(matrix.pow(2).mean().sqrt().item() * np.sqrt(3 * m.in_type.size))
        return np.array(out)

    escnn_init, torch_init = rms_ratios(policy()), rms_ratios(policy(init="torch"))
    assert len(torch_init) > 0
    np.testing.assert_allclose(torch_init, 1.0, rtol=1e-5)
    assert escnn_init.max() > 1.3  # escnn's generalised He scale is larger on the hidden layers
    with pytest.raises(ValueError, match="init must be one of"):
        policy(init="xavier")


def test_radial_squash_log_det_matches_autograd():
    torch.manual_seed(1)
    pairs = torch.tensor([[0, 2]])
    singles = torch.tensor([1])
    for scale in (1e-6, 0.3, 2.0):
        u = torch.randn(3, dtype=torch.float64) * scale
        jac = torch.autograd.functional.jacobian(lambda x: _radial_squash(x[None], pairs, singles)[0][0], u)
        _, logdet = _radial_squash(u[None], pairs, singles)
        assert abs(torch.logdet(jac).item() - logdet.item()) < 1e-4  # the 1e-7 guard inside the log
    a, _ = _radial_squash(torch.randn(100, 3) * 10, pairs, singles)
    assert a[:, [0, 2]].norm(dim=1).max() <= 1.0 + 1e-6


def test_box_tanh_option_is_not_c8_equivariant():
    sym = Symmetry("lift")
    pol = policy(squash="tanh")
    u = torch.full((1, 40), 1.3)
    a, _ = pol.actor._squash(u)
    ga, _ = pol.actor._squash(torch.tensor(sym.act_latent(u.numpy(), g=1)))
    assert np.abs(ga.numpy() - sym.act_latent(a.numpy(), g=1)).max() > 1e-2
    with pytest.raises(ValueError, match="squash"):
        policy(squash="box")


def test_rpp_has_two_paths_with_their_own_weight_decay():
    pol = policy(residual=True)
    groups = pol.actor.optimizer.param_groups
    assert [g["weight_decay"] for g in groups] == [1e-5, 1e-2]
    assert sum(p.numel() for p in groups[1]["params"]) > 0


def test_layernorm_dsrl_policy():
    pol = LayerNormSACPolicy(OBS, LATENT, lambda _: 3e-4, net_arch=[32, 32])
    assert any(isinstance(m, torch.nn.LayerNorm) for m in pol.actor.latent_pi)
    qs = pol.critic(torch.randn(4, 22), torch.rand(4, 40))
    assert len(qs) == 2 and qs[0].shape == (4, 1)
    assert any(isinstance(m, torch.nn.LayerNorm) for m in pol.critic.q_networks[0].modules())
