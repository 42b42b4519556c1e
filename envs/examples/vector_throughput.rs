//! Environment steps per second of a [`BatchEnv`] of B environments on T threads (pure Rust,
//! uniform random actions, auto-reset included), for comparison with the Python vector env.
//!
//! `cargo run --release -p equigym-envs --example vector_throughput -- [task] [batch steps] [B,...] [T,...]`
//! prints one line per (B, T): `B=.. T=..: N env steps/s (M us per batch step)`.

use std::time::Instant;

use equigym_envs::rng::EpisodeRng;
use equigym_envs::{AutoresetMode, BatchEnv, Env, EnvConfig};

fn list(arg: Option<&String>, default: &[usize]) -> Result<Vec<usize>, std::num::ParseIntError> {
    match arg {
        None => Ok(default.to_vec()),
        Some(s) => s.split(',').map(str::parse).collect(),
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let task = args.get(1).map(String::as_str).unwrap_or("lift");
    let steps: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(200);
    let sizes = list(args.get(3), &[1, 2, 4, 8, 16, 32, 64])?;
    let threads = list(args.get(4), &[1, 2])?;
    for &b in &sizes {
        for &t in &threads {
            let envs = (0..b).map(|_| Env::new(EnvConfig::new(task))).collect::<Result<Vec<_>, _>>()?;
            let (lo, hi) = envs[0].action_bounds();
            let mut batch = BatchEnv::new(envs, t, AutoresetMode::NextStep)?;
            let mut rng = EpisodeRng::from_seed(0);
            let actions: Vec<Vec<f64>> =
                (0..steps).map(|_| (0..b * 10).map(|j| rng.uniform(lo[j % 10], hi[j % 10])).collect()).collect();
            let seeds: Vec<u64> = (0..b as u64).collect();
            batch.reset(&seeds)?;
            for a in actions.iter().take(steps / 10) {
                batch.step(a)?; // warm-up
            }
            let start = Instant::now();
            for a in &actions {
                batch.step(a)?;
            }
            let secs = start.elapsed().as_secs_f64();
            println!(
                "B={b} T={t}: {:.0} env steps/s ({:.1} us per batch step)",
                (steps * b) as f64 / secs,
                1e6 * secs / steps as f64
            );
        }
    }
    Ok(())
}
