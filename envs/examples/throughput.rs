//! Control steps per second of a task under uniform random actions, and reset time. It also
//! prints the checksum of the saved state at the end of the run, so that two builds can be
//! checked for the same bits on the same run.
//!
//! `cargo run --release -p equigym-envs --example throughput -- [task] [steps]`

use std::time::Instant;

use equigym_envs::env::STATE_CHECKSUM_LEN;
use equigym_envs::rng::EpisodeRng;
use equigym_envs::{Action, Env, EnvConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let task = args.get(1).map(String::as_str).unwrap_or("lift");
    let steps: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(4000);
    let mut env = Env::new(EnvConfig::new(task))?;
    let mut rng = EpisodeRng::from_seed(0);
    let (lo, hi) = env.action_bounds();
    let actions: Vec<Action> = (0..steps).map(|_| std::array::from_fn(|k| rng.uniform(lo[k], hi[k]))).collect();
    env.reset(0)?;
    let start = Instant::now();
    let mut resets = 0.0;
    for (i, a) in actions.iter().enumerate() {
        if env.step(a)?.truncated {
            let t = Instant::now();
            env.reset(i as u64)?;
            resets += t.elapsed().as_secs_f64();
        }
    }
    let total = start.elapsed().as_secs_f64();
    let state = env.get_state()?;
    let checksum: String = state[state.len() - STATE_CHECKSUM_LEN..].iter().map(|b| format!("{b:02x}")).collect();
    let t = Instant::now();
    for s in 0..100 {
        env.reset(s)?;
    }
    let reset_ms = t.elapsed().as_secs_f64() * 10.0;
    println!(
        "{task}: {:.0} control steps/s (stepping only: {:.0}), reset {reset_ms:.3} ms, final state checksum {checksum}",
        steps as f64 / total,
        steps as f64 / (total - resets)
    );
    Ok(())
}
