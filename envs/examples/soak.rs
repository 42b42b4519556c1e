//! Soak test: adversarial actions for many steps per task (no NaN, nothing through the table)
//! and many resets (resident memory stays flat).
//!
//! ```text
//! cargo run --release -p equigym-envs --example soak -- [--steps N] [--resets M] [--tasks lift,stack,square] [--out FILE]
//! ```
//! Full run (docs/reliability.md): `--steps 1000000 --resets 100000 --out docs/reliability/soak.md`.
//! CI smoke run: `--steps 2000 --resets 2000`. Exits non-zero on any violation.

use std::fmt::Write as _;
use std::time::Instant;

use equigym_envs::rng::EpisodeRng;
use equigym_envs::{Env, EnvConfig, FieldKind, ACTION_DIM};

/// How far below the table top a world position may be, inside the table's footprint, before it
/// counts as through the table (m).
const THROUGH_TABLE_TOLERANCE: f64 = 0.005;
/// Resets before the first memory reading (allocator warm-up).
const WARMUP_RESETS: usize = 1000;
/// Observation fields of the robot start with this; the others are objects.
const GRIPPER_FIELD_PREFIX: &str = "gripper";
/// Seed of the adversarial action stream.
const ACTION_SEED: u64 = 0x50a4;

/// An action meant to break things: pushes into the table, jumps between extremes, degenerate
/// rotations, the gripper slammed open and shut, or a uniform draw inside the bounds.
fn adversarial_action(rng: &mut EpisodeRng, env: &Env, previous: &[f64; ACTION_DIM]) -> [f64; ACTION_DIM] {
    let (lo, hi) = env.action_bounds();
    let mut a: [f64; ACTION_DIM] = std::array::from_fn(|k| rng.uniform(lo[k], hi[k]));
    match (rng.uniform(0.0, 6.0)) as u32 {
        // Drive the hand into the table (the lowest target the bounds allow).
        0 => a[2] = lo[2],
        // Jump to the opposite corner of the workspace in one step.
        1 => {
            for k in 0..3 {
                a[k] = if previous[k] > 0.5 * (lo[k] + hi[k]) { lo[k] } else { hi[k] };
            }
        }
        // Degenerate 6D rotation (zero or parallel rows).
        2 => {
            let r = rng.uniform(-1.0, 1.0);
            a[3..9].copy_from_slice(&[r, 0.0, 0.0, 2.0 * r, 0.0, 0.0]);
        }
        // Out-of-bounds values (clamped by the env).
        3 => {
            for v in a.iter_mut() {
                *v *= 1e6;
            }
        }
        // Hold where the robot is, gripper slammed shut or open.
        4 => {
            a = env.current_target();
            a[9] = if rng.uniform(0.0, 1.0) < 0.5 { lo[9] } else { hi[9] };
            a[2] = lo[2];
        }
        _ => {}
    }
    a
}

/// Heights above the table top (m) of the lowest object centre and of the TCP, inside the
/// table's footprint (+inf where none is), and whether the observation is finite.
fn heights_above_table(env: &mut Env) -> (f64, f64, bool) {
    let spec = env.task().scene_spec();
    let fields: Vec<_> = env
        .observation_layout()
        .fields()
        .iter()
        .filter(|f| f.kind == FieldKind::Position && !f.name.contains("_to_"))
        .map(|f| (f.name.starts_with(GRIPPER_FIELD_PREFIX), f.start))
        .collect();
    let obs = env.observe();
    let finite = obs.iter().all(|v| v.is_finite());
    let (mut object, mut tcp) = (f64::INFINITY, f64::INFINITY);
    for (is_gripper, s) in fields {
        let (x, y, z) = (obs[s], obs[s + 1], obs[s + 2]);
        if x.abs() < spec.table.half_extents[0] && y.abs() < spec.table.half_extents[1] {
            let h = z - spec.table.top;
            if is_gripper {
                tcp = tcp.min(h);
            } else {
                object = object.min(h);
            }
        }
    }
    (object, tcp, finite)
}

/// Resident set size in kB (Linux; None elsewhere).
fn rss_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

struct Row {
    task: String,
    steps: usize,
    episodes: usize,
    steps_per_s: f64,
    non_finite: usize,
    through: usize,
    lowest_object: f64,
    lowest_tcp: f64,
    resets: usize,
    rss_start: Option<u64>,
    rss_end: Option<u64>,
}

fn soak(task: &str, steps: usize, resets: usize) -> Result<Row, Box<dyn std::error::Error>> {
    let mut env = Env::new(EnvConfig::new(task))?;
    let mut rng = EpisodeRng::from_seed(ACTION_SEED);
    let (mut non_finite, mut through, mut episodes) = (0, 0, 1);
    let (mut lowest_object, mut lowest_tcp) = (f64::INFINITY, f64::INFINITY);
    env.reset(0)?;
    let mut previous = env.current_target();
    let start = Instant::now();
    for _ in 0..steps {
        let a = adversarial_action(&mut rng, &env, &previous);
        previous = a;
        let step = env.step(&a)?;
        let (object, tcp, finite) = heights_above_table(&mut env);
        non_finite += usize::from(!finite);
        through += usize::from(object.min(tcp) < -THROUGH_TABLE_TOLERANCE);
        lowest_object = lowest_object.min(object);
        lowest_tcp = lowest_tcp.min(tcp);
        if step.truncated || step.terminated || !finite {
            env.reset(episodes as u64)?;
            episodes += 1;
        }
    }
    let steps_per_s = steps as f64 / start.elapsed().as_secs_f64();
    let warmup = WARMUP_RESETS.min(resets);
    for s in 0..warmup {
        env.reset(s as u64)?;
    }
    let rss_start = rss_kb();
    for s in warmup..resets {
        env.reset(s as u64)?;
    }
    let rss_end = rss_kb();
    Ok(Row {
        task: task.into(),
        steps,
        episodes,
        steps_per_s,
        non_finite,
        through,
        lowest_object,
        lowest_tcp,
        resets,
        rss_start,
        rss_end,
    })
}

fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> T {
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let steps: usize = arg(&args, "--steps", 20_000);
    let resets: usize = arg(&args, "--resets", 5_000);
    let tasks: String = arg(&args, "--tasks", "lift,stack,square".to_string());
    let out: Option<String> = args.iter().position(|a| a == "--out").and_then(|i| args.get(i + 1)).cloned();

    let mut table = String::new();
    writeln!(
        table,
        "Generated by `cargo run --release -p equigym-envs --example soak -- --steps {steps} --resets {resets} --tasks {tasks}`.\n"
    )?;
    writeln!(
        table,
        "| task | adversarial steps | episodes | steps/s | non-finite obs | through the table | lowest object centre above the top (mm) | lowest TCP above the top (mm) | resets | RSS after {WARMUP_RESETS} resets (kB) | RSS at the end (kB) |"
    )?;
    writeln!(table, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")?;
    let mut failed = false;
    for task in tasks.split(',') {
        let r = soak(task, steps, resets)?;
        let kb = |v: Option<u64>| v.map_or("n/a".to_string(), |v| v.to_string());
        writeln!(
            table,
            "| {} | {} | {} | {:.0} | {} | {} | {:.1} | {:.1} | {} | {} | {} |",
            r.task,
            r.steps,
            r.episodes,
            r.steps_per_s,
            r.non_finite,
            r.through,
            1000.0 * r.lowest_object,
            1000.0 * r.lowest_tcp,
            r.resets,
            kb(r.rss_start),
            kb(r.rss_end)
        )?;
        failed |= r.non_finite > 0 || r.through > 0;
        eprintln!("{task} done");
    }
    print!("{table}");
    if let Some(path) = out {
        std::fs::write(&path, &table)?;
    }
    if failed {
        return Err("soak found non-finite observations or bodies through the table".into());
    }
    Ok(())
}
