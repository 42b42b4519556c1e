//! Gradients of every layer and of the SAC losses against central finite differences (f64), and
//! exact C8 equivariance / invariance of the actor, its log-probability and the critics for all
//! 8 group elements, with the rotation from the symmetry layer.

use equigym_agents::models::{Arch, Method, Models};
use equigym_agents::net::{Net, Tape};
use equigym_agents::rng::{Rng, Stream};
use equigym_agents::sac::{actor_loss_grad, alpha_loss_grad, concat_rows, critic_loss_grad, ActorSample, NoisePrior};
use equigym_envs::TaskOptions;
use equigym_wrappers::{Group, TaskSymmetry};

const ARCH: Arch = Arch { width: 16, layers: 2 };
const ROWS: usize = 5;
const FD_STEP: f64 = 1e-6;

fn sym() -> TaskSymmetry {
    TaskSymmetry::new("lift", &TaskOptions::default(), Group::cyclic(8).unwrap(), 4).unwrap()
}

fn randn(n: usize, rng: &mut Rng) -> Vec<f64> {
    (0..n).map(|_| rng.normal()).collect()
}

fn models(method: Method) -> Models<f64> {
    Models::<f64>::new(method, &sym(), ARCH, 7).unwrap()
}

/// sum(c * net(x)) and its gradient wrt params and input.
fn loss_and_grads(net: &Net<f64>, x: &[f64], c: &[f64]) -> (f64, Vec<f64>, Vec<f64>) {
    let mut tape = Tape::default();
    net.forward(x, ROWS, &mut tape);
    let loss = tape.output().iter().zip(c).map(|(a, b)| a * b).sum();
    let mut g = vec![0.0; net.num_params()];
    let mut ws = Default::default();
    let dx = net.backward(&tape, c, Some(&mut g), true, &mut ws).unwrap().to_vec();
    (loss, g, dx)
}

fn check_net(name: &str, net: &Net<f64>) {
    let mut rng = Rng::new(1, Stream::Eval, 99);
    let x = randn(ROWS * net.n_in, &mut rng);
    let c = randn(ROWS * net.n_out, &mut rng);
    let (_, g, dx) = loss_and_grads(net, &x, &c);
    let eval = |net: &Net<f64>, x: &[f64]| loss_and_grads(net, x, &c).0;
    let stride = (net.num_params() / 60).max(1);
    for i in (0..net.num_params()).step_by(stride) {
        let mut n2 = net.clone();
        n2.params[i] += FD_STEP;
        n2.expand();
        let up = eval(&n2, &x);
        n2.params[i] -= 2.0 * FD_STEP;
        n2.expand();
        let down = eval(&n2, &x);
        let fd = (up - down) / (2.0 * FD_STEP);
        assert!(
            (fd - g[i]).abs() <= 1e-5 * (1.0 + fd.abs()),
            "{name}: param {i}: analytic {} vs finite difference {fd}",
            g[i]
        );
    }
    for i in (0..x.len()).step_by((x.len() / 20).max(1)) {
        let mut x2 = x.clone();
        x2[i] += FD_STEP;
        let up = eval(net, &x2);
        x2[i] -= 2.0 * FD_STEP;
        let down = eval(net, &x2);
        let fd = (up - down) / (2.0 * FD_STEP);
        assert!(
            (fd - dx[i]).abs() <= 1e-5 * (1.0 + fd.abs()),
            "{name}: input {i}: analytic {} vs finite difference {fd}",
            dx[i]
        );
    }
}

#[test]
fn every_layer_matches_finite_differences() {
    for method in [Method::Dsrl, Method::Equi, Method::Approx] {
        let m = models(method);
        check_net(&format!("{method:?} actor"), &m.actor);
        check_net(&format!("{method:?} critic"), &m.critics[0]);
    }
}

/// The actor loss mean(alpha log pi - min Q) as a function of the actor's parameters (the
/// function the SAC step itself calls).
fn actor_loss(
    m: &Models<f64>,
    actor: &Net<f64>,
    obs: &[f64],
    eps: &[f64],
    alpha: f64,
    prior: Option<&NoisePrior>,
) -> (f64, Vec<f64>) {
    let mut s = ActorSample::default();
    m.head.sample(actor, obs, ROWS, eps, &mut s);
    if let Some(p) = prior {
        p.apply(&m.head, &mut s);
    }
    let mut g = vec![0.0; actor.num_params()];
    let loss = actor_loss_grad(&m.head, actor, &m.critics, obs, &s, alpha, prior, &mut g, &mut Default::default());
    (loss, g)
}

#[test]
fn actor_loss_gradient_matches_finite_differences() {
    for method in [Method::Dsrl, Method::Equi, Method::Approx] {
        let m = models(method);
        let mut rng = Rng::new(2, Stream::Eval, 5);
        let obs = randn(ROWS * m.actor.n_in, &mut rng);
        let mut eps = randn(ROWS * m.head.dim, &mut rng);
        // one near-zero pair exercises the radial squash's series branch
        eps[0] = 1e-3;
        eps[1] = -1e-3;
        let alpha = 0.3;
        // SAC's entropy term, and the KL to the noise prior in its place
        let prior = NoisePrior { bound: 1.5, target_kl: 4.0 };
        for prior in [None, Some(&prior)] {
            let (_, g) = actor_loss(&m, &m.actor, &obs, &eps, alpha, prior);
            let stride = (m.actor.num_params() / 80).max(1);
            for i in (0..m.actor.num_params()).step_by(stride) {
                let mut a2 = m.actor.clone();
                a2.params[i] += FD_STEP;
                a2.expand();
                let up = actor_loss(&m, &a2, &obs, &eps, alpha, prior).0;
                a2.params[i] -= 2.0 * FD_STEP;
                a2.expand();
                let down = actor_loss(&m, &a2, &obs, &eps, alpha, prior).0;
                let fd = (up - down) / (2.0 * FD_STEP);
                assert!(
                    (fd - g[i]).abs() <= 1e-5 * (1.0 + fd.abs()),
                    "{method:?} actor loss (prior {}): param {i}: analytic {} vs finite difference {fd}",
                    prior.is_some(),
                    g[i]
                );
            }
        }
    }
}

#[test]
fn critic_and_entropy_losses_match_finite_differences() {
    for method in [Method::Dsrl, Method::Equi, Method::Approx] {
        let m = models(method);
        let mut rng = Rng::new(5, Stream::Eval, 6);
        let c = &m.critics[1];
        let x = randn(ROWS * c.n_in, &mut rng);
        let y = randn(ROWS, &mut rng);
        let loss = |net: &Net<f64>| {
            let mut g = vec![0.0; net.num_params()];
            (critic_loss_grad(net, &x, &y, &mut g, &mut Default::default()), g)
        };
        let (_, g) = loss(c);
        for i in (0..c.num_params()).step_by((c.num_params() / 50).max(1)) {
            let mut c2 = c.clone();
            c2.params[i] += FD_STEP;
            c2.expand();
            let up = loss(&c2).0;
            c2.params[i] -= 2.0 * FD_STEP;
            c2.expand();
            let fd = (up - loss(&c2).0) / (2.0 * FD_STEP);
            assert!(
                (fd - g[i]).abs() <= 1e-5 * (1.0 + fd.abs()),
                "{method:?} critic loss: param {i}: {} vs {fd}",
                g[i]
            );
        }
    }
    let logp = [-3.0, 1.5, 0.25];
    let (l0, g) = alpha_loss_grad(0.2f64, &logp, 0.0);
    let fd = (alpha_loss_grad(0.2 + FD_STEP, &logp, 0.0).0 - l0) / FD_STEP;
    assert!((fd - g).abs() < 1e-6, "entropy loss: {g} vs {fd}");
}

#[test]
fn actor_and_log_prob_are_equivariant_and_critics_invariant_for_all_8_elements() {
    let sym = sym();
    for method in [Method::Equi, Method::Approx] {
        let m = models(method);
        // Approx has a plain path: equivariance holds only with it switched off.
        let mut m = m;
        if method == Method::Approx {
            for net in std::iter::once(&mut m.actor).chain(m.critics.iter_mut()) {
                zero_plain_paths(net);
            }
        }
        let mut rng = Rng::new(3, Stream::Eval, 1);
        let (od, ad) = (m.actor.n_in, m.head.dim);
        let obs = randn(ROWS * od, &mut rng);
        let eps = randn(ROWS * ad, &mut rng);
        let mut s = ActorSample::default();
        m.head.sample(&m.actor, &obs, ROWS, &eps, &mut s);
        let (a, logp) = (s.a.clone(), s.logp.clone());
        let mut x = Vec::new();
        concat_rows(&obs, od, &a, ad, ROWS, &mut x);
        let mut tape = Tape::default();
        m.critics[0].forward(&x, ROWS, &mut tape);
        let q = tape.output().to_vec();
        for g in Group::cyclic(8).unwrap().elements().unwrap() {
            let mut gobs = obs.clone();
            sym.act_observation(&g, &mut gobs).unwrap();
            let mut geps = eps.clone();
            sym.act_latent(&g, &mut geps).unwrap();
            m.head.sample(&m.actor, &gobs, ROWS, &geps, &mut s);
            let mut ga = a.clone();
            sym.act_latent(&g, &mut ga).unwrap();
            for (u, v) in s.a.iter().zip(&ga) {
                assert!(
                    (u - v).abs() < 1e-9,
                    "{method:?}: pi(g s) != g pi(s) at {} deg: {u} vs {v}",
                    g.angle().to_degrees()
                );
            }
            for (u, v) in s.logp.iter().zip(&logp) {
                assert!(
                    (u - v).abs() < 1e-9,
                    "{method:?}: log pi changes under {} deg: {u} vs {v}",
                    g.angle().to_degrees()
                );
            }
            concat_rows(&gobs, od, &ga, ad, ROWS, &mut x);
            m.critics[0].forward(&x, ROWS, &mut tape);
            for (u, v) in tape.output().iter().zip(&q) {
                assert!(
                    (u - v).abs() < 1e-9,
                    "{method:?}: Q(g s, g a) != Q(s, a) at {} deg: {u} vs {v}",
                    g.angle().to_degrees()
                );
            }
        }
    }
}

fn zero_plain_paths(net: &mut Net<f64>) {
    use equigym_agents::net::{Layer, LinearKind};
    let mut ranges = Vec::new();
    for l in &net.layers {
        match l {
            Layer::Linear(lin) => {
                if let LinearKind::Equi { plain: Some((w, b)), .. } = &lin.kind {
                    ranges.push((*w, lin.n_in * lin.n_out));
                    ranges.push((*b, lin.n_out));
                }
            }
            Layer::PoolHead { plain: Some((w, b)), fields, order, .. } => {
                ranges.push((*w, fields * order));
                ranges.push((*b, 1));
            }
            _ => {}
        }
    }
    for (at, n) in ranges {
        net.params[at..at + n].iter_mut().for_each(|v| *v = 0.0);
    }
    net.expand();
}

#[test]
fn approx_plain_paths_break_equivariance_and_equi_count_matches_the_mlp() {
    let sym = sym();
    // RPP's plain path is really there: with it, the actor is not equivariant.
    let m = models(Method::Approx);
    let mut rng = Rng::new(4, Stream::Eval, 2);
    let obs = randn(m.actor.n_in, &mut rng);
    let mut tape = Tape::default();
    m.actor.forward(&obs, 1, &mut tape);
    let out = tape.output().to_vec();
    let g = Group::cyclic(8).unwrap().element(1).unwrap();
    let mut gobs = obs.clone();
    sym.act_observation(&g, &mut gobs).unwrap();
    m.actor.forward(&gobs, 1, &mut tape);
    let mut gmean = out[..m.head.dim].to_vec();
    sym.act_latent(&g, &mut gmean).unwrap();
    let gap: f64 = tape.output()[..m.head.dim].iter().zip(&gmean).map(|(a, b)| (a - b).abs()).sum();
    assert!(gap > 1e-6, "the plain path should break exact equivariance");
    // Parameter matching picks the closest candidate (as baselines/steer.py).
    let cpu = Arch { width: 64, layers: 3 };
    let f = equigym_agents::models::matched_fields(&sym, cpu, false).unwrap();
    assert_eq!(f, 24, "the cpu preset's matched Equi nets use 24 regular fields");
}
