//! The base-policy evaluation (a run's control arms) follows the evaluation protocol: the pinned
//! starts EVAL_SEED + k, success if any latent step succeeds (and the episode stops there), the
//! noise of episode k from its own stream scaled by s; results do not depend on the threads.

use std::sync::Arc;

use equigym_agents::evaluation::{evaluate_base, ChunkMoves, Episodes, NoiseMoments, EVAL_SEED, STALL_MOVE};
use equigym_agents::rng::{Rng, Stream};
use equigym_agents::run::{evaluate_checkpoint, make_env, ActorNoise};
use equigym_agents::sac::candidates;
use equigym_agents::{Error, Method, RunConfig};
use equigym_wrappers::DiffusionPolicy;

fn config(threads: usize) -> RunConfig {
    let mut c = RunConfig::new(Method::Dsrl, "lift", 5, 0, std::env::temp_dir()).unwrap();
    c.eval_episodes = 8;
    c.env.horizon = Some(120);
    c.threads = threads;
    c
}

/// Episode k by hand, one latent step at a time.
fn by_hand(cfg: &RunConfig, scale: f64, k: u64) -> bool {
    let mut rng = Rng::new(cfg.seed, Stream::BaseEval, k);
    by_hand_from(cfg, k, |dim, bound| (0..dim).map(|_| (scale * rng.normal()).clamp(-bound, bound)).collect())
}

/// Episode k by hand with the noise `noise(latent dim, bound)` at every latent step. The
/// episodes must match to the bit: an outcome on the arm turns on the last bits of a chunk.
fn by_hand_from(cfg: &RunConfig, k: u64, noise: impl FnMut(usize, f64) -> Vec<f64>) -> bool {
    by_hand_moves(cfg, k, noise).0
}

/// [`by_hand_from`], with the chunk-to-chunk moves of the commanded hand position (the mean of
/// the chunk's positions), counted as the evaluation documents them.
fn by_hand_moves(cfg: &RunConfig, k: u64, mut noise: impl FnMut(usize, f64) -> Vec<f64>) -> (bool, ChunkMoves) {
    let mut policy =
        DiffusionPolicy::load(equigym_agents::run::DEFAULT_POLICY_DIR.to_owned() + "/lift.safetensors").unwrap();
    policy.kernel = cfg.edp_kernel;
    let policy = Arc::new(policy);
    let mut env = make_env(cfg, &policy).unwrap();
    env.reset(EVAL_SEED + k).unwrap();
    let (mut moves, mut before) = (ChunkMoves::default(), None::<[f64; 3]>);
    loop {
        let w = noise(env.latent_dim(), env.bound());
        let r = env.step(&w).unwrap();
        let actions: Vec<&[f64]> = env.last_chunk().chunks_exact(equigym_envs::ACTION_DIM).collect();
        let mut now = [0.0; 3];
        for (i, p) in now.iter_mut().enumerate() {
            *p = actions.iter().map(|a| a[i] / actions.len() as f64).sum();
        }
        if let Some(b) = before {
            let d = (0..3).map(|i| (now[i] - b[i]).powi(2)).sum::<f64>().sqrt();
            moves.moves += 1;
            moves.stalled += u32::from(d < STALL_MOVE);
        }
        before = Some(now);
        if r.success {
            return (true, moves);
        }
        if r.terminated || r.truncated {
            return (false, moves);
        }
    }
}

#[test]
fn base_evaluation_is_the_protocol_on_pinned_starts() {
    let cfg = config(1);
    let full = evaluate_base(&cfg, 1.0).unwrap();
    assert_eq!(full.first_start, EVAL_SEED);
    assert_eq!(full.successes.len(), 8);
    assert_eq!(full.rate.n, 8);
    assert_eq!(full.rate.successes, full.successes.iter().filter(|s| **s).count());
    assert!(full.rate.low <= full.rate.rate && full.rate.rate <= full.rate.high);
    for k in 0..8 {
        assert_eq!(full.successes[k], by_hand(&cfg, 1.0, k as u64), "episode {k}");
    }
    // Threads change nothing; a narrow scale is the same streams scaled.
    assert_eq!(evaluate_base(&config(2), 1.0).unwrap(), full);
    let narrow = evaluate_base(&cfg, 0.5).unwrap();
    assert_eq!(narrow.scale, 0.5);
    for k in [0usize, 3] {
        assert_eq!(narrow.successes[k], by_hand(&cfg, 0.5, k as u64), "episode {k} at scale 0.5");
    }
}

#[test]
fn bad_scales_and_tasks_are_typed_errors() {
    let cfg = config(1);
    for s in [-0.1, f64::NAN, f64::INFINITY] {
        assert!(matches!(evaluate_base(&cfg, s), Err(Error::InvalidOption(_))), "scale {s}");
    }
    let mut bad = config(1);
    bad.task = "juggle".into();
    assert!(matches!(evaluate_base(&bad, 1.0), Err(Error::InvalidOption(_))));
    let mut none = config(1);
    none.eval_episodes = 0;
    assert!(matches!(evaluate_base(&none, 1.0), Err(Error::InvalidOption(_))));
}

#[test]
fn a_checkpoint_is_evaluated_on_the_same_pinned_starts() {
    // No checkpoint under this directory: the untrained learner. Best of one candidate is the
    // base policy on the evaluation's own noise stream (episode k: Stream::Eval, key k).
    let dir = std::env::temp_dir().join(format!("equigym-eval-ckpt-{}", std::process::id()));
    let mut cfg = config(1);
    cfg.out = dir.clone();
    let (trained, one) = evaluate_checkpoint(&cfg, ActorNoise::BestOf(1), None).unwrap();
    assert_eq!(trained, None);
    assert_eq!(one.successes.len(), 8);
    for k in [0u64, 5] {
        // One candidate as the evaluation draws it: float32 normals, clipped, over the bound.
        let mut rng = Rng::new(cfg.seed, Stream::Eval, k);
        let best_of_one = |dim, bound| {
            let mut w = vec![0.0f32; dim];
            candidates(&mut rng, bound, &mut w);
            w.iter().map(|v| *v as f64 * bound).collect()
        };
        let (success, moves) = by_hand_moves(&cfg, k, best_of_one);
        assert_eq!(one.successes[k as usize], success, "episode {k}");
        assert_eq!(one.moves[k as usize], moves, "episode {k}: chunk-to-chunk moves");
    }
    assert!(one.moves.iter().all(|m| m.moves > 0), "every episode runs more than one chunk");
    // Fewer episodes are the first ones of the same starts; threads change nothing.
    let (_, three) = evaluate_checkpoint(&cfg, ActorNoise::BestOf(1), Some(3)).unwrap();
    assert_eq!(three.successes, one.successes[..3]);
    let mut two_threads = cfg.clone();
    two_threads.threads = 2;
    for noise in [ActorNoise::Mean, ActorNoise::BestOf(4)] {
        let a = evaluate_checkpoint(&cfg, noise, Some(4)).unwrap();
        assert_eq!(a, evaluate_checkpoint(&two_threads, noise, Some(4)).unwrap(), "{noise:?}");
    }
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn the_stalled_share_reads_the_failing_episodes_only() {
    let m = |moves, stalled| ChunkMoves { moves, stalled };
    let episodes = |successes: Vec<bool>, moves: Vec<ChunkMoves>| Episodes {
        successes,
        env_steps: 0,
        noise: NoiseMoments::default(),
        moves,
    };
    // Two failures (a half and all of their chunks stalled); the success's stalls do not count.
    let e = episodes(vec![false, true, false], vec![m(10, 5), m(8, 8), m(4, 4)]);
    assert_eq!(e.failures_stalled(), Some(0.75));
    // No failing episode, or none that moved: no share.
    assert_eq!(episodes(vec![true], vec![m(3, 3)]).failures_stalled(), None);
    assert_eq!(episodes(vec![false], vec![m(0, 0)]).failures_stalled(), None);
}
