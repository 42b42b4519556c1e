//! `steer run`: one Rust steering run without Python; `steer probe`: the critic probe of a run
//! (`equigym_agents::run::probe`).
//!
//! ```text
//! cargo run --release -p equigym-agents --bin steer -- run --method equi --task lift --seed 0 \
//!     --steps 16000 --out runs/steer-rust [--threads 1] [--preset cpu|paper] [--no-joint-limits] \
//!     [--controller joint|cartesian] [--eval-every 2000] [--eval-episodes 50] [--policy FILE] \
//!     [--ent-init 0.2] [--horizon N] [--terminate-on-success] [--noise-aliased] [--target-entropy X] [--quiet]
//! steer probe <the run's options> --report DIR [--starts 8] [--at 2,4,8,12,16,24] [--candidates 6] \
//!     [--continuations 10] [--actor-samples 2]
//! steer eval <the run's options> [--actor mean|sampled|best-of-N] [--episodes N]
//! ```
//! `run` writes `OUT/<task>/<method>/seed<S>/log.csv` (and run.json, summary.json,
//! checkpoint.bin); started again with the same arguments it resumes from the checkpoint.
//! `probe` loads that checkpoint (the untrained learner when there is none) and writes
//! `DIR/critic-probe.{json,md}`. `eval` evaluates that checkpoint as a policy (the actor's mean
//! noise by default, its samples, or the critic's best of N fresh N(0, I) candidates) on the
//! run's pinned starts (`--episodes`, default the run's `--eval-episodes`) and prints one JSON
//! line with the rate and its Wilson 95 % interval. Both run on `--threads` worker threads.

use equigym_envs::Controller;
use std::process::ExitCode;

use equigym_agents::run::{critic_probe, evaluate_checkpoint, ActorNoise, CriticProbeConfig};
use equigym_agents::{run, Method, Preset, RunConfig};
use equigym_wrappers::steerability::{ProbeConfig, Rate};

const USAGE: &str =
    "usage: steer run --method {dsrl,equi,approx} --task {lift,stack,square} --seed S --steps N --out DIR \
[--threads T] [--preset cpu|paper] [--env JSON] [--no-joint-limits] [--controller joint|cartesian] [--eval-every N] \
[--eval-episodes N] [--policy FILE] [--edp-kernel fourier|dense] [--ent-init X] [--horizon N] [--terminate-on-success] [--noise-aliased] [--target-entropy X | --prior-kl NATS] [--reward-scale X] [--select N] [--utd N] [--quiet]
       steer probe <the run's options> --report DIR [--starts N] [--at K,K,..] [--candidates M] [--continuations K] [--actor-samples A]
       steer eval <the run's options> [--actor mean|sampled|best-of-N] [--episodes N]";

/// Episode seeds of the critic probe's states (the steerability probe's: apart from training and
/// evaluation starts).
const PROBE_SEED: u64 = 3_100_000;

/// A probe's own options, taken out of the arguments before the run's are parsed.
struct ProbeArgs {
    report: std::path::PathBuf,
    config: CriticProbeConfig,
}

fn parse_probe(args: &mut Vec<String>) -> Result<ProbeArgs, String> {
    let mut p = ProbeArgs {
        report: "runs/critic-probe".into(),
        config: CriticProbeConfig {
            probe: ProbeConfig {
                first_seed: PROBE_SEED,
                starts: 8,
                at_latent_steps: vec![2, 4, 8, 12, 16, 24],
                candidates: 6,
                continuations: 10,
                hold: 1,
            },
            actor_samples: 2,
        },
    };
    let mut rest = Vec::new();
    let mut it = std::mem::take(args).into_iter();
    while let Some(a) = it.next() {
        let known = ["--report", "--starts", "--at", "--candidates", "--continuations", "--actor-samples"];
        if !known.contains(&a.as_str()) {
            rest.push(a);
            continue;
        }
        let v = it.next().ok_or_else(|| format!("{a} needs a value\n{USAGE}"))?;
        let num =
            |s: &str| s.trim().parse::<usize>().map_err(|_| format!("{a} takes non-negative integers, got '{v}'"));
        let c = &mut p.config;
        match a.as_str() {
            "--report" => p.report = v.into(),
            "--starts" => c.probe.starts = num(&v)?,
            "--at" => c.probe.at_latent_steps = v.split(',').map(num).collect::<Result<_, _>>()?,
            "--candidates" => c.probe.candidates = num(&v)?,
            "--continuations" => c.probe.continuations = num(&v)?,
            _ => c.actor_samples = num(&v)?,
        }
    }
    *args = rest;
    Ok(p)
}

fn parse(args: &[String]) -> Result<RunConfig, String> {
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
            "--env" => cfg.env = serde_json::from_str(&v).map_err(|e| format!("--env: {e}"))?,
            "--no-joint-limits" => cfg.env.joint_limits = Some(false),
            "--controller" => {
                cfg.env.controller = Some(v.parse::<Controller>().map_err(|e| format!("--controller: {e}"))?)
            }
            "--eval-every" => cfg.eval_every = num()?,
            "--eval-episodes" => cfg.eval_episodes = num()?,
            "--policy" => cfg.policy = Some(v.into()),
            "--edp-kernel" => cfg.edp_kernel = v.parse().map_err(|e| format!("--edp-kernel: {e}"))?,
            "--ent-init" => {
                cfg.ent_init = Some(v.parse::<f64>().map_err(|_| format!("--ent-init takes a number, got '{v}'"))?)
            }
            "--horizon" => cfg.env.horizon = Some(num()?),
            "--target-entropy" => {
                cfg.target_entropy =
                    Some(v.parse::<f64>().map_err(|_| format!("--target-entropy takes a number, got '{v}'"))?)
            }
            "--prior-kl" => {
                cfg.prior_kl = Some(v.parse::<f64>().map_err(|_| format!("--prior-kl takes a number, got '{v}'"))?)
            }
            "--reward-scale" => {
                cfg.reward_scale =
                    Some(v.parse::<f64>().map_err(|_| format!("--reward-scale takes a number, got '{v}'"))?)
            }
            "--select" => cfg.select = Some(num()?),
            "--utd" => cfg.utd = Some(num()?),
            "--quiet" => cfg.progress = false,
            "--terminate-on-success" => cfg.terminate_on_success = true,
            "--noise-aliased" => cfg.noise_aliased = true,
            other => return Err(format!("unknown option {other}\n{USAGE}")),
        }
    }
    Ok(cfg)
}

/// What a command line asks for beside the run it names.
enum Job {
    Run,
    Probe(ProbeArgs),
    Eval(ActorNoise, Option<usize>),
}

/// `--actor mean|sampled|best-of-N` and `--episodes N`, taken out of the arguments before the
/// run's are parsed.
fn parse_eval(args: &mut Vec<String>) -> Result<(ActorNoise, Option<usize>), String> {
    let mut episodes = None;
    if let Some(i) = args.iter().position(|a| a == "--episodes") {
        let v = args.get(i + 1).cloned().unwrap_or_default();
        episodes = Some(v.parse().map_err(|_| format!("--episodes takes a count, got '{v}'"))?);
        args.drain(i..(i + 2).min(args.len()));
    }
    let mut noise = ActorNoise::Mean;
    if let Some(i) = args.iter().position(|a| a == "--actor") {
        noise = match args.get(i + 1).map(String::as_str) {
            Some("mean") => ActorNoise::Mean,
            Some("sampled") => ActorNoise::Sampled,
            Some(b) if b.starts_with("best-of-") => {
                let n = b[8..].parse().ok().filter(|n| *n >= 1);
                ActorNoise::BestOf(n.ok_or_else(|| format!("--actor best-of-N takes a count >= 1, got '{b}'"))?)
            }
            other => return Err(format!("--actor takes mean, sampled or best-of-N, got {other:?}\n{USAGE}")),
        };
        args.drain(i..i + 2);
    }
    Ok((noise, episodes))
}

fn main() -> ExitCode {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let parsed = match args.first().map(String::as_str) {
        Some("run") => parse(&args).map(|c| (c, Job::Run)),
        Some("probe") => parse_probe(&mut args).and_then(|p| parse(&args).map(|c| (c, Job::Probe(p)))),
        Some("eval") => parse_eval(&mut args).and_then(|(n, e)| parse(&args).map(|c| (c, Job::Eval(n, e)))),
        _ => Err(USAGE.to_string()),
    };
    let (cfg, job) = match parsed {
        Ok(c) => c,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::from(2);
        }
    };
    let done = match job {
        Job::Run => run(&cfg).map(|s| print_summary(&s)),
        Job::Probe(p) => probe_run(&cfg, &p, &args),
        Job::Eval(noise, episodes) => eval_run(&cfg, noise, episodes),
    };
    match done {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Rayon's global pool with `--threads` workers (0: rayon's default) for `probe` and `eval`.
fn use_threads(cfg: &RunConfig) {
    if cfg.threads > 0 {
        // (fails only when a pool exists already, which then serves)
        let _ = rayon::ThreadPoolBuilder::new().num_threads(cfg.threads).build_global();
    }
}

fn probe_run(cfg: &RunConfig, p: &ProbeArgs, args: &[String]) -> equigym_agents::Result<()> {
    use_threads(cfg);
    let report = critic_probe(cfg, &p.config)?;
    let io = |e: std::io::Error| equigym_agents::Error::InvalidOption(format!("{}: {e}", p.report.display()));
    std::fs::create_dir_all(&p.report).map_err(io)?;
    let json =
        serde_json::to_string_pretty(&report).map_err(|e| equigym_agents::Error::InvalidOption(e.to_string()))?;
    std::fs::write(p.report.join("critic-probe.json"), json + "\n").map_err(io)?;
    let command = format!("target/release/steer probe {} --report {}", args[1..].join(" "), p.report.display());
    std::fs::write(p.report.join("critic-probe.md"), report.markdown(&command)).map_err(io)?;
    println!("{}", p.report.join("critic-probe.md").display());
    Ok(())
}

fn eval_run(cfg: &RunConfig, noise: ActorNoise, episodes: Option<usize>) -> equigym_agents::Result<()> {
    use_threads(cfg);
    let (trained, episodes) = evaluate_checkpoint(cfg, noise, episodes)?;
    let wins = episodes.successes.iter().filter(|s| **s).count();
    let rate = Rate::of(wins, episodes.successes.len());
    let line = serde_json::json!({
        "run_dir": cfg.run_dir(),
        "trained_env_steps": trained,
        "actor": match noise {
            ActorNoise::Mean => "mean".to_string(),
            ActorNoise::Sampled => "sampled".to_string(),
            ActorNoise::BestOf(n) => format!("best-of-{n}"),
        },
        "successes": rate.successes,
        "episodes": rate.n,
        "rate": rate.rate,
        "wilson95": [rate.low, rate.high],
        "noise_mean_norm": episodes.noise.mean_norm(),
        "noise_rms": episodes.noise.rms(),
        "noise_mean": episodes.noise.mean(),
        "failures_stalled": episodes.failures_stalled(),
    });
    println!("{line}");
    Ok(())
}

fn print_summary(s: &equigym_agents::RunSummary) {
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
}
