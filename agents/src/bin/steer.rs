//! `steer run`: one Rust steering run without Python.
//!
//! ```text
//! cargo run --release -p equigym-agents --bin steer -- run --method equi --task lift --seed 0 \
//!     --steps 16000 --out runs/steer-rust [--threads 1] [--preset cpu|paper] [--no-joint-limits] \
//!     [--controller joint|cartesian] [--eval-every 2000] [--eval-episodes 50] [--policy FILE] \
//!     [--ent-init 0.2] [--horizon N] [--terminate-on-success] [--noise-aliased] [--target-entropy X] [--quiet]
//! ```
//! Writes `OUT/<task>/<method>/seed<S>/log.csv` (and run.json, summary.json, checkpoint.bin);
//! started again with the same arguments it resumes from the checkpoint.

use equigym_envs::Controller;
use std::process::ExitCode;

use equigym_agents::{run, Method, Preset, RunConfig};

const USAGE: &str =
    "usage: steer run --method {dsrl,equi,approx} --task {lift,stack,square} --seed S --steps N --out DIR \
[--threads T] [--preset cpu|paper] [--no-joint-limits] [--controller joint|cartesian] [--eval-every N] \
[--eval-episodes N] [--policy FILE] [--ent-init X] [--horizon N] [--terminate-on-success] [--noise-aliased] [--target-entropy X | --prior-kl NATS] [--quiet]";

fn parse(args: &[String]) -> Result<RunConfig, String> {
    if args.first().map(String::as_str) != Some("run") {
        return Err(USAGE.into());
    }
    let mut method = None;
    let mut task = "lift".to_string();
    let mut seed = 0u64;
    let mut steps = 20_000usize;
    let mut out = "runs/steer-rust".to_string();
    let mut rest: Vec<(String, Option<String>)> = Vec::new();
    let mut it = args[1..].iter();
    while let Some(a) = it.next() {
        let flag = matches!(a.as_str(), "--no-joint-limits" | "--quiet" | "--terminate-on-success" | "--noise-aliased");
        let val =
            if flag { None } else { Some(it.next().ok_or_else(|| format!("{a} needs a value\n{USAGE}"))?.clone()) };
        let num = |v: &Option<String>| -> Result<u64, String> {
            v.as_deref()
                .unwrap_or("")
                .parse::<u64>()
                .map_err(|_| format!("{a} takes a non-negative integer, got {:?}", v.as_deref().unwrap_or("")))
        };
        match a.as_str() {
            "--method" => method = Some(Method::parse(val.as_deref().unwrap_or("")).map_err(|e| e.to_string())?),
            "--task" => task = val.unwrap_or_default(),
            "--seed" => seed = num(&val)?,
            "--steps" => steps = num(&val)? as usize,
            "--out" => out = val.unwrap_or_default(),
            _ => rest.push((a.clone(), val)),
        }
    }
    let method = method.ok_or_else(|| format!("--method is required\n{USAGE}"))?;
    let mut cfg = RunConfig::new(method, &task, seed, steps, out).map_err(|e| e.to_string())?;
    cfg.progress = true;
    for (a, v) in rest {
        let v = v.unwrap_or_default();
        let num = || v.parse::<usize>().map_err(|_| format!("{a} takes a non-negative integer, got '{v}'"));
        match a.as_str() {
            "--threads" => cfg.threads = num()?,
            "--preset" => cfg.preset = Preset::named(&v).map_err(|e| e.to_string())?,
            "--no-joint-limits" => cfg.joint_limits = false,
            "--controller" => cfg.controller = Some(v.parse::<Controller>().map_err(|e| format!("--controller: {e}"))?),
            "--eval-every" => cfg.eval_every = num()?,
            "--eval-episodes" => cfg.eval_episodes = num()?,
            "--policy" => cfg.policy = Some(v.into()),
            "--ent-init" => {
                cfg.ent_init = Some(v.parse::<f64>().map_err(|_| format!("--ent-init takes a number, got '{v}'"))?)
            }
            "--horizon" => cfg.horizon = Some(num()?),
            "--target-entropy" => {
                cfg.target_entropy =
                    Some(v.parse::<f64>().map_err(|_| format!("--target-entropy takes a number, got '{v}'"))?)
            }
            "--prior-kl" => {
                cfg.prior_kl = Some(v.parse::<f64>().map_err(|_| format!("--prior-kl takes a number, got '{v}'"))?)
            }
            "--quiet" => cfg.progress = false,
            "--terminate-on-success" => cfg.terminate_on_success = true,
            "--noise-aliased" => cfg.noise_aliased = true,
            other => return Err(format!("unknown option {other}\n{USAGE}")),
        }
    }
    Ok(cfg)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let cfg = match parse(&args) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    match run(&cfg) {
        Ok(s) => {
            println!(
                "{}: {} env steps, {} gradient steps, {:.1} s (collecting {:.1} s, training {:.1} s, \
                 evaluating {:.1} s over {} env steps), final success {}, params {:016x}",
                s.run_dir.display(),
                s.env_steps,
                s.grad_steps,
                s.seconds,
                s.time.rollout,
                s.time.train,
                s.time.eval,
                s.eval_env_steps,
                s.rows.last().map_or("-".into(), |r| r.success_rate.to_string()),
                s.params_hash
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
