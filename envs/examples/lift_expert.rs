//! Drive Lift with the scripted expert, without Python: success rate and control steps/s.
//!
//! `cargo run --release -p equigym-envs --example lift_expert -- [episodes] [image.png]`

use std::time::Instant;

use equigym_envs::experts::{make_expert, ExpertOptions};
use equigym_envs::{Env, EnvConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let episodes: u64 = args.get(1).map(|s| s.parse()).transpose()?.unwrap_or(50);
    let image = args.get(2).cloned();
    let verbose = std::env::var("EQUIGYM_VERBOSE").is_ok();
    let mut env = Env::new(EnvConfig::new("lift"))?;
    let mut expert = make_expert("lift", ExpertOptions::default())?;
    let (mut successes, mut steps) = (0usize, 0usize);
    let start = Instant::now();
    for seed in 0..episodes {
        env.reset(seed)?;
        expert.reset(&env, seed);
        let mut success = false;
        for t in 0..env.horizon() {
            let action = expert.act(&env);
            let step = env.step(&action)?;
            steps += 1;
            if verbose && seed == 0 && t % 5 == 0 {
                let o = env.observe();
                println!("t={t} phase={} tcp=({:.3},{:.3},{:.3}) cube=({:.3},{:.3},{:.3}) fingers=({:.4},{:.4}) terms={:?}",
                    expert.phase(), o[11], o[12], o[13], o[0], o[1], o[2], o[20], o[21], step.evaluation.terms);
            }
            if step.evaluation.success {
                success = true;
                break;
            }
        }
        if !success && verbose {
            println!("seed {seed} failed in phase {}", expert.phase());
        }
        successes += success as usize;
    }
    let secs = start.elapsed().as_secs_f64();
    println!(
        "lift expert: {successes}/{episodes} successes ({:.1}%), {steps} control steps in {secs:.2} s = {:.0} steps/s",
        100.0 * successes as f64 / episodes as f64,
        steps as f64 / secs
    );
    if let Some(path) = image {
        env.reset(0)?;
        equigym_envs::render::save_png(&env.render(320, 240)?, &path)?;
        println!("wrote {path}");
    }
    Ok(())
}
