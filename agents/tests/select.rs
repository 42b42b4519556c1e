//! The selecting learner (`--select N`): its policy is the best of N fresh candidates from the
//! EDP's noise by min-Q, and its critics learn that policy's value without an actor.

use equigym_agents::models::{Arch, Method, Models};
use equigym_agents::replay::Batch;
use equigym_agents::rng::{Rng, Stream};
use equigym_agents::sac::{argmax, candidates, Sac, SacConfig};
use equigym_envs::TaskOptions;
use equigym_wrappers::{Group, TaskSymmetry};

const BOUND: f64 = 1.5;

fn learner() -> Sac<f64> {
    let sym = TaskSymmetry::new("lift", &TaskOptions::default(), Group::cyclic(8).unwrap(), 4).unwrap();
    let od = sym.observation.dim();
    let models = Models::<f64>::new(Method::Dsrl, &sym, Arch { width: 32, layers: 2 }, 5).unwrap();
    let config = SacConfig { lr: 3e-3, gamma: 0.9, tau: 0.05, target_entropy: 0.0, ent_init: 0.2, prior: None };
    Sac::new(models, od, config)
}

fn randn(n: usize, rng: &mut Rng) -> Vec<f64> {
    (0..n).map(|_| rng.normal()).collect()
}

/// `rows` random states and an executed noise for each, from the EDP's noise.
fn states_and_noise(sac: &Sac<f64>, rows: usize, rng: &mut Rng) -> (Vec<f64>, Vec<f64>) {
    let obs = randn(rows * sac.obs_dim, rng);
    let mut act = vec![0.0; rows * sac.latent_dim()];
    candidates(rng, BOUND, &mut act);
    (obs, act)
}

#[test]
fn select_takes_the_candidate_of_highest_min_q() {
    let mut sac = learner();
    let (od, ad, rows, n) = (sac.obs_dim, sac.latent_dim(), 3, 8);
    let obs = randn(rows * od, &mut Rng::new(1, Stream::Eval, 0));
    let rng = Rng::new(1, Stream::Eval, 1);
    let picked = sac.select(&obs, rows, n, BOUND, &mut rng.clone());
    let mut w = vec![0.0f64; rows * n * ad];
    candidates(&mut rng.clone(), BOUND, &mut w);
    assert!(w.iter().all(|v| v.abs() <= 1.0), "candidates are scaled into the actor's box");
    for r in 0..rows {
        let o: Vec<f64> = (0..n).flat_map(|_| obs[r * od..(r + 1) * od].to_vec()).collect();
        let q = sac.min_q(&o, &w[r * n * ad..(r + 1) * n * ad], n);
        let best = argmax(&q);
        assert_eq!(&picked[r * ad..(r + 1) * ad], &w[(r * n + best) * ad..(r * n + best + 1) * ad], "row {r}");
        assert!(q.iter().any(|x| *x != q[best]), "distinct candidates score differently");
    }
}

#[test]
fn select_steps_fit_the_value_of_the_selecting_policy_and_leave_the_actor() {
    let mut sac = learner();
    let (od, rows) = (sac.obs_dim, 16);
    let mut rng = Rng::new(2, Stream::Train, 0);
    let (obs, act) = states_and_noise(&sac, rows, &mut rng);
    // Terminal transitions: the value is the reward, whatever the next state's candidates.
    let reward: Vec<f64> = (0..rows).map(|r| -(r as f64) / 4.0).collect();
    let batch = Batch::of(obs.clone(), act.clone(), reward.clone(), randn(rows * od, &mut rng), vec![1.0; rows]);
    let actor = sac.actor.params.clone();
    let first = sac.train_step_select(&batch, 4, BOUND, &mut rng).critic_loss;
    let mut last = first;
    for _ in 0..1500 {
        last = sac.train_step_select(&batch, 4, BOUND, &mut rng).critic_loss;
    }
    assert!(last < 1e-3 * first, "critic loss {first} -> {last}");
    let q = sac.min_q(&obs, &act, rows);
    for (q, r) in q.iter().zip(&reward) {
        assert!((q - r).abs() < 0.05, "Q {q} against the reward {r}");
    }
    assert_eq!(sac.actor.params, actor, "the selecting learner has no actor step");
}

#[test]
fn the_target_bootstraps_from_the_best_candidate() {
    // Zero rewards and next states that are the states themselves: with one candidate the
    // critic tracks the mean of Q' over the noise; with 64 it climbs to the best of them.
    let mean_q = |n: usize| {
        let mut sac = learner();
        let rows = 16;
        let mut rng = Rng::new(3, Stream::Train, 0);
        let (obs, act) = states_and_noise(&sac, rows, &mut rng);
        let batch = Batch::of(obs.clone(), act.clone(), vec![0.0; rows], obs.clone(), vec![0.0; rows]);
        for _ in 0..300 {
            sac.train_step_select(&batch, n, BOUND, &mut rng);
        }
        sac.min_q(&obs, &act, rows).iter().sum::<f64>() / rows as f64
    };
    let (one, best) = (mean_q(1), mean_q(64));
    assert!(best > one + 0.05, "Q with the best of 64 ({best}) against one candidate ({one})");
}
