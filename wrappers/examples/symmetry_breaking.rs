//! Measure a task's symmetry breaking from Rust (the Python command `python -m
//! equigym.symmetry_report` runs the same measurement over many settings and writes tables).
//!
//! `cargo run --release -p equigym-wrappers --example symmetry_breaking -- [task] [variant] [limits on|off] [episodes] [joint|cartesian]`

use equigym_envs::Controller;
use equigym_wrappers::breaking::{measure, BreakingConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let mut config = BreakingConfig::new(args.get(1).map_or("lift", |s| s.as_str()));
    config.env.variant = args.get(2).filter(|s| !s.is_empty() && *s != "-").cloned();
    config.env.joint_limits = Some(args.get(3).is_none_or(|s| s != "off"));
    config.env.controller = args.get(5).is_some_and(|s| s == "cartesian").then_some(Controller::Cartesian);
    if let Some(n) = args.get(4) {
        config.episodes = n.parse()?;
    }
    let start = std::time::Instant::now();
    let report = measure(&config)?;
    println!(
        "{} {:?} joint limits {}: expert {}/{} ({:.1} s)",
        config.task,
        config.env.variant,
        if config.env.joint_limits_on() { "on" } else { "off" },
        report.expert_successes,
        report.expert_episodes,
        start.elapsed().as_secs_f64()
    );
    println!(
        "  g  angle  obs err (mean/max)  object err mm (mean/max)  hand mm  reward err  succ mism  unreach  replay"
    );
    for (inv, rep) in report.invariance.iter().zip(&report.replay) {
        println!(
            "  {}  {:5.1}  {:8.5} / {:7.5}  {:8.3} / {:8.3}  {:7.3}  {:9.5}  {:8.3}  {:7.3}  {}/{}",
            inv.element,
            inv.angle_deg,
            inv.observation_error_mean,
            inv.observation_error_max,
            1e3 * inv.object_error_mean,
            1e3 * inv.object_error_max,
            1e3 * inv.hand_error_mean,
            inv.reward_error_mean,
            inv.success_mismatch,
            inv.unreachable,
            rep.successes,
            rep.demos
        );
    }
    Ok(())
}
