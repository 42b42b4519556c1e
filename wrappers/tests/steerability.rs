//! The steerability diagnostic: reproducible for any thread count, and it measures what it says.

use std::sync::Arc;

use equigym_envs::robot::parse_urdf;
use equigym_envs::{Env, EnvOptions};
use equigym_wrappers::steerability::{base_rollouts, probe, probe_with, BaseConfig, ProbeConfig};
use equigym_wrappers::{DiffusionPolicy, LatentEnv, DEFAULT_LATENT_BOUND};

const HORIZON: usize = 48;

fn maker() -> impl Fn() -> equigym_wrappers::Result<LatentEnv> + Sync {
    let policy = Arc::new(
        DiffusionPolicy::load(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/edp/lift.safetensors")).unwrap(),
    );
    let robot = Arc::new(parse_urdf(equigym_envs::env::PANDA_URDF).unwrap());
    let config = EnvOptions { horizon: Some(HORIZON), ..EnvOptions::default() }.into_config("lift").unwrap();
    move || {
        let env = Env::with_robot(config.clone(), robot.clone())?;
        LatentEnv::new(env, policy.clone(), DEFAULT_LATENT_BOUND, policy.default_ddim_steps)
    }
}

fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(f)
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let make = maker();
    let base = BaseConfig { first_seed: 5, starts: 3, per_start: 2, spread_noises: 3, spread_starts: 1 };
    let probe_cfg =
        ProbeConfig { first_seed: 9, starts: 2, at_latent_steps: vec![1, 3], candidates: 2, continuations: 2, hold: 1 };
    let run = |threads| {
        in_pool(threads, || {
            let b = base_rollouts(&base, &make).unwrap();
            let p = probe(&probe_cfg, &make).unwrap();
            (serde_json::to_string(&b).unwrap(), serde_json::to_string(&p).unwrap())
        })
    };
    let one = run(1);
    assert_eq!(one, run(2));
    // Every rollout was classified, and the spread was measured before each chunk of one rollout.
    let b: equigym_wrappers::steerability::BaseReport = serde_json::from_str(&one.0).unwrap();
    assert_eq!(b.outcomes.iter().map(|o| o.1).sum::<usize>(), 6);
    assert_eq!(b.spread.len(), HORIZON / 4);
    let wins: usize = b.outcomes.iter().filter(|o| o.0.is_success()).map(|o| o.1).sum();
    assert_eq!(wins, b.success.successes);
}

#[test]
fn a_candidate_held_for_the_whole_episode_decides_it() {
    // With the candidate noise covering every remaining chunk, continuations of one candidate
    // are the same rollout: each candidate succeeds in all of them or in none. With one chunk of
    // candidate noise, the continuations draw their own noise afterwards and may disagree.
    let make = maker();
    let cfg = ProbeConfig {
        first_seed: 21,
        starts: 2,
        at_latent_steps: vec![1],
        candidates: 3,
        continuations: 3,
        hold: HORIZON / 4,
    };
    let report = probe(&cfg, &make).unwrap();
    assert!(!report.states.is_empty());
    for s in &report.states {
        for &k in &s.candidate_successes {
            assert!(k == 0 || k == cfg.continuations, "{:?}", s.candidate_successes);
        }
        assert_eq!(s.variance_ratio.is_some(), s.mean > 0.0 && s.mean < 1.0);
    }
}

#[test]
fn extra_candidates_are_probed_beside_the_random_ones_without_moving_them() {
    // A caller's candidates (a trained actor's picks) get continuations of their own; the random
    // candidates' results stay those of the plain probe, and the state's observation is the one
    // the caller was given. An extra of the wrong length is refused.
    let make = maker();
    let cfg =
        ProbeConfig { first_seed: 9, starts: 1, at_latent_steps: vec![1], candidates: 2, continuations: 2, hold: 1 };
    let plain = probe(&cfg, &make).unwrap();
    let dim = make().unwrap().latent_dim();
    let seen = std::sync::Mutex::new(Vec::new());
    let extra = |seed: u64, k: usize, obs: &[f64]| {
        seen.lock().unwrap().push((seed, k, obs.to_vec()));
        Ok(vec![vec![0.0; dim], vec![0.5; dim]])
    };
    let with = probe_with(&cfg, &make, &extra).unwrap();
    assert_eq!(
        serde_json::to_value(&plain.states[0].candidate_successes).unwrap(),
        serde_json::to_value(&with.states[0].candidate_successes).unwrap()
    );
    let s = &with.states[0];
    assert_eq!(s.extra_successes.len(), 2);
    assert_eq!(s.candidates.len(), 4);
    assert_eq!(s.candidates[3], vec![0.5; dim]);
    assert!(s.continuations.iter().all(|c| c.len() == cfg.continuations));
    for (c, &k) in s.continuations[2..].iter().zip(&s.extra_successes) {
        assert_eq!(c.iter().filter(|r| r.success).count(), k);
    }
    let seen = seen.into_inner().unwrap();
    assert_eq!(seen, vec![(s.seed, s.latent_step, s.observation.clone())]);
    assert!(!s.observation.is_empty());
    let wrong = |_: u64, _: usize, _: &[f64]| Ok(vec![vec![0.0; dim + 1]]);
    assert!(probe_with(&cfg, &make, &wrong).is_err());
}
