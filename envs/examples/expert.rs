//! Drive a task with its scripted expert, without Python: success rate, control steps/s, and
//! failure statistics by initial object yaw and position (where the Panda's joint limits and
//! reach break the task's rotational symmetry).
//!
//! `cargo run --release -p equigym-envs --example expert -- [task] [episodes] [image.png] [variant] [setting]`
//!
//! `setting`: solver settings as in `shared/settings.rs` (default: the shipped ones).

use std::time::Instant;

use equigym_envs::experts::{make_expert, ExpertOptions};
use equigym_envs::render::save_png;
use equigym_envs::Env;

mod shared;
use shared::settings::Setting;

struct Episode {
    success: bool,
    phase: &'static str,
    /// Initial (x, y, yaw) of each task object.
    starts: Vec<(f64, f64, f64)>,
}

fn table(
    title: &str,
    episodes: &[Episode],
    bins: usize,
    key: impl Fn(&Episode) -> usize,
    label: impl Fn(usize) -> String,
) {
    let mut n = vec![0usize; bins];
    let mut ok = vec![0usize; bins];
    for e in episodes {
        let b = key(e).min(bins - 1);
        n[b] += 1;
        ok[b] += e.success as usize;
    }
    println!("{title}");
    for b in 0..bins {
        if n[b] > 0 {
            println!("  {:<22} {:>4}/{:<4} {:>6.1}%", label(b), ok[b], n[b], 100.0 * ok[b] as f64 / n[b] as f64);
        }
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let task = args.get(1).cloned().unwrap_or_else(|| "lift".into());
    let episodes: u64 = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(50);
    let image = args.get(3).filter(|s| !s.is_empty()).cloned();
    let setting = Setting::parse(args.get(5).map(String::as_str).unwrap_or(""))?;
    let mut config = setting.env_config(&task);
    config.task_options.variant = args.get(4).cloned().filter(|v| !v.is_empty());
    let mut env = Env::new(config)?;
    let mut expert = make_expert(&task, ExpertOptions::default())?;
    let mut log = Vec::new();
    let mut steps = 0usize;
    // How far each commanded position is from where the hand is one control step later (m).
    let mut lags = Vec::new();
    let start = Instant::now();
    for seed in 0..episodes {
        env.reset(seed)?;
        setting.apply(&mut env);
        expert.reset(&env, seed);
        let starts = env
            .task()
            .objects()
            .iter()
            .map(|o| {
                let p = equigym_envs::math::from_pose(env.scene().world.bodies[o.body].position());
                let x = p.rotation * nalgebra::Vector3::x();
                (p.translation.x, p.translation.y, libm::atan2(x.y, x.x).rem_euclid(std::f64::consts::TAU))
            })
            .collect();
        let mut success = false;
        for _ in 0..env.horizon() {
            let action = expert.act(&env);
            steps += 1;
            let done = env.step(&action)?.evaluation.success();
            let hand = env.scene().tcp_pose().translation.vector;
            lags.push((nalgebra::Vector3::new(action[0], action[1], action[2]) - hand).norm());
            if done {
                success = true;
                break;
            }
        }
        log.push(Episode { success, phase: expert.phase(), starts });
    }
    let secs = start.elapsed().as_secs_f64();
    let wins = log.iter().filter(|e| e.success).count();
    println!(
        "{task} expert: {wins}/{episodes} successes ({:.1}%), {steps} control steps in {secs:.2} s = {:.0} steps/s",
        100.0 * wins as f64 / episodes as f64,
        steps as f64 / secs
    );
    lags.sort_by(f64::total_cmp);
    let quantile = |q: f64| 1e3 * lags[((lags.len() - 1) as f64 * q) as usize];
    println!(
        "  commanded position vs the hand one step later: mean {:.1} mm, p90 {:.1} mm, max {:.1} mm",
        1e3 * lags.iter().sum::<f64>() / lags.len().max(1) as f64,
        quantile(0.9),
        quantile(1.0)
    );
    let names: Vec<&str> = env.task().objects().iter().map(|o| o.name).collect();
    if log.iter().any(|e| !e.success) {
        let mut phases: Vec<&str> = log.iter().filter(|e| !e.success).map(|e| e.phase).collect();
        phases.sort();
        phases.dedup();
        for p in phases {
            println!("  failed in phase {p}: {}", log.iter().filter(|e| !e.success && e.phase == p).count());
        }
    }
    let failed: Vec<String> = log.iter().enumerate().filter(|(_, e)| !e.success).map(|(s, _)| s.to_string()).collect();
    if !failed.is_empty() {
        println!("  failed seeds: {}", failed.join(" "));
    }
    for (k, name) in names.iter().enumerate() {
        let deg = 360.0 / 8.0;
        table(
            &format!("success by initial {name} yaw"),
            &log,
            8,
            |e| (e.starts[k].2.to_degrees() / deg) as usize,
            |b| format!("yaw {:>3.0}..{:<3.0} deg", b as f64 * deg, (b + 1) as f64 * deg),
        );
        // Distance from the robot base (x = -0.56): reach is where the arm's limits bite.
        table(
            &format!("success by {name} distance from the robot base"),
            &log,
            6,
            |e| {
                let d = ((e.starts[k].0 + 0.56).powi(2) + e.starts[k].1.powi(2)).sqrt();
                ((d - 0.3) / 0.1).max(0.0) as usize
            },
            |b| format!("{:.1}..{:.1} m", 0.3 + 0.1 * b as f64, 0.4 + 0.1 * b as f64),
        );
        table(
            &format!("success by {name} quadrant"),
            &log,
            4,
            |e| (e.starts[k].0 >= 0.0) as usize * 2 + (e.starts[k].1 >= 0.0) as usize,
            |b| format!("x {} 0, y {} 0", if b >= 2 { ">=" } else { "<" }, if b % 2 == 1 { ">=" } else { "<" }),
        );
    }
    if let Some(path) = image {
        env.reset(0)?;
        save_png(&env.render(320, 240)?, &path)?;
        println!("wrote {path}");
    }
    Ok(())
}
