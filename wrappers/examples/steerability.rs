//! The steerability diagnostic (`equigym_wrappers::steerability`): how much the latent noise
//! changes success, with the base policy alone, before any agent is trained.
//!
//! ```text
//! cargo run --release -p equigym-wrappers --example steerability -- --task lift \
//!     --out docs/steering/steerability [--controller joint|cartesian] [--parts base,probe,policies] \
//!     [--hold 1] [--policy FILE] [--threads T] [--quick]
//! ```
//! Writes `OUT/<task>[-cartesian]/{base,probe-hold<H>,policies}.json` and rebuilds `report.md`
//! from every JSON file there. A part whose JSON exists is not run again (`--force` reruns it),
//! so an interrupted run resumes at the part it was in.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use clap::Parser;
use equigym_envs::robot::parse_urdf;
use equigym_envs::{Controller, Env, EnvOptions};
use equigym_wrappers::steerability::{
    base_rollouts, phase_policies, probe, BaseConfig, BaseReport, PolicySearchConfig, PolicySearchReport, ProbeConfig,
    ProbeReport, Rate,
};
use equigym_wrappers::{DiffusionPolicy, LatentEnv, DEFAULT_LATENT_BOUND};

/// Episode seeds of the diagnostic: far from the agents' training streams and evaluation
/// starts (10,000 + k) and from the EDP report's starts.
const BASE_SEED: u64 = 3_000_000;
const PROBE_SEED: u64 = 3_100_000;
const SEARCH_SEED: u64 = 3_200_000;
const TEST_SEED: u64 = 3_300_000;

#[derive(Parser, Debug)]
#[command(about = "Steerability of the latent-noise MDP, measured with the base policy")]
struct Args {
    #[arg(long, default_value = "lift")]
    task: String,
    #[arg(long, default_value = "docs/steering/steerability")]
    out: PathBuf,
    #[arg(long, value_parser = ["joint", "cartesian"], default_value = "joint")]
    controller: String,
    /// Comma-separated: base, probe, policies.
    #[arg(long, default_value = "base,probe,policies")]
    parts: String,
    /// Chunks the probe's candidate noise covers.
    #[arg(long, default_value_t = 1)]
    hold: usize,
    /// Latent steps at which the probe takes states (default: the task's decisive window).
    #[arg(long, value_delimiter = ',')]
    at: Vec<usize>,
    /// A policy file (default: the shipped EDP of the task).
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Worker threads (0: one per core).
    #[arg(long, default_value_t = 0)]
    threads: usize,
    /// Small sizes, for a smoke run.
    #[arg(long)]
    quick: bool,
    /// Rerun parts whose JSON exists.
    #[arg(long)]
    force: bool,
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = Args::parse();
    if args.threads > 0 {
        rayon::ThreadPoolBuilder::new().num_threads(args.threads).build_global()?;
    }
    let policy_path = args.policy.clone().unwrap_or_else(|| {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/edp").join(format!("{}.safetensors", args.task))
    });
    let policy = Arc::new(DiffusionPolicy::load(&policy_path)?);
    let robot = Arc::new(parse_urdf(equigym_envs::env::PANDA_URDF)?);
    let controller = if args.controller == "cartesian" { Controller::Cartesian } else { Controller::Joint };
    let options = EnvOptions { controller: Some(controller), ..EnvOptions::default() };
    let config = options.into_config(&args.task)?;
    let make_env = move || -> equigym_wrappers::Result<LatentEnv> {
        let env = Env::with_robot(config.clone(), robot.clone())?;
        LatentEnv::new(env, policy.clone(), DEFAULT_LATENT_BOUND, policy.default_ddim_steps)
    };
    let dir = args.out.join(if controller == Controller::Cartesian {
        format!("{}-cartesian", args.task)
    } else {
        args.task.clone()
    });
    std::fs::create_dir_all(&dir)?;
    let q = args.quick;
    let parts: Vec<&str> = args.parts.split(',').map(str::trim).collect();
    let run = |name: &str| parts.contains(&name);
    let fresh = |file: &Path| args.force || !file.exists();

    if run("base") && fresh(&dir.join("base.json")) {
        let cfg = BaseConfig {
            first_seed: BASE_SEED,
            starts: if q { 2 } else { 40 },
            per_start: if q { 2 } else { 4 },
            spread_noises: if q { 4 } else { 16 },
            spread_starts: if q { 1 } else { 4 },
        };
        timed("base rollouts", || write(&dir.join("base.json"), &base_rollouts(&cfg, &make_env)?))?;
    }
    let probe_file = dir.join(format!("probe-hold{}.json", args.hold));
    if run("probe") && fresh(&probe_file) {
        let cfg = ProbeConfig {
            first_seed: PROBE_SEED,
            starts: if q { 1 } else { 8 },
            at_latent_steps: match () {
                _ if !args.at.is_empty() => args.at.clone(),
                _ if q => vec![2],
                // Lift's base succeeds after about 8 chunks on average, Stack's later.
                _ if args.task == "lift" => vec![1, 2, 3, 4, 6],
                _ => vec![2, 4, 8, 12, 16, 24],
            },
            candidates: if q { 2 } else { 6 },
            continuations: if q { 2 } else { 10 },
            hold: args.hold,
        };
        timed("probes", || write(&probe_file, &probe(&cfg, &make_env)?))?;
    }
    if run("policies") && fresh(&dir.join("policies.json")) {
        let cfg = PolicySearchConfig {
            search_first_seed: SEARCH_SEED,
            search_starts: if q { 2 } else { 24 },
            test_first_seed: TEST_SEED,
            test_starts: if q { 2 } else { 100 },
            scales: if q { vec![0.5, 1.0] } else { vec![0.0, 0.5, 1.0, 1.5] },
            constants: if q { 1 } else { 3 },
        };
        timed("phase policies", || write(&dir.join("policies.json"), &phase_policies(&cfg, &make_env)?))?;
    }
    let policy_arg = args.policy.as_ref().map_or(String::new(), |p| format!(" --policy {}", p.display()));
    let command = format!(
        "cargo run --release -p equigym-wrappers --example steerability -- --task {} --controller {} --out {}{policy_arg}",
        args.task,
        args.controller,
        args.out.display()
    );
    let which = args.policy.as_ref().map_or(format!("the shipped {} EDP", args.task), |p| format!("`{}`", p.display()));
    std::fs::write(dir.join("report.md"), report(&dir, &which, &args.controller, &command)?)?;
    println!("{}", dir.join("report.md").display());
    Ok(())
}

fn timed(
    what: &str,
    f: impl FnOnce() -> Result<(), Box<dyn std::error::Error>>,
) -> Result<(), Box<dyn std::error::Error>> {
    let t = std::time::Instant::now();
    f()?;
    eprintln!("{what}: {:.0} s", t.elapsed().as_secs_f64());
    Ok(())
}

fn write<T: serde::Serialize>(path: &Path, value: &T) -> Result<(), Box<dyn std::error::Error>> {
    std::fs::write(path, serde_json::to_string_pretty(value)? + "\n")?;
    Ok(())
}

fn read<T: serde::de::DeserializeOwned>(path: &Path) -> Result<Option<T>, Box<dyn std::error::Error>> {
    if !path.exists() {
        return Ok(None);
    }
    Ok(Some(serde_json::from_str(&std::fs::read_to_string(path)?)?))
}

fn rate(r: &Rate) -> String {
    format!("{:.3} [{:.3}, {:.3}] ({}/{})", r.rate, r.low, r.high, r.successes, r.n)
}

fn opt(x: Option<f64>, digits: usize) -> String {
    x.map_or("-".into(), |v| format!("{v:.digits$}"))
}

fn report(dir: &Path, policy: &str, controller: &str, command: &str) -> Result<String, Box<dyn std::error::Error>> {
    let mut md = format!(
        "# Steerability of {policy} ({controller} controller)\n\n\
         Made by `{command}` (module `equigym_wrappers::steerability`; rates with Wilson 95 % intervals).\n"
    );
    if let Some(b) = read::<BaseReport>(&dir.join("base.json"))? {
        md += &base_section(&b);
    }
    let mut probes: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("probe-hold")))
        .collect();
    probes.sort();
    for path in probes {
        if let Some(p) = read::<ProbeReport>(&path)? {
            md += &probe_section(&p);
        }
    }
    if let Some(p) = read::<PolicySearchReport>(&dir.join("policies.json"))? {
        md += &policy_section(&p);
    }
    Ok(md)
}

fn base_section(b: &BaseReport) -> String {
    let c = &b.config;
    let mut md = format!(
        "\n## Base rollouts: how they end\n\n{} starts (seeds {}..) x {} rollouts, N(0, I) noise, run to the horizon.\n\
         Success {}; first success at primitive step {} on average.\n\n| outcome | rollouts | share |\n|---|---:|---:|\n",
        c.starts,
        c.first_seed,
        c.per_start,
        rate(&b.success),
        opt(b.mean_first_success_step, 0)
    );
    let n = b.success.n.max(1) as f64;
    for (o, k) in &b.outcomes {
        md += &format!("| {} | {} | {:.2} |\n", o.name(), k, *k as f64 / n);
    }
    let mut hist = vec![0usize; c.per_start + 1];
    for &s in &b.per_start_successes {
        hist[s] += 1;
    }
    md += &format!(
        "\nStarts by successes out of {}: {}.\n",
        c.per_start,
        hist.iter().enumerate().map(|(k, n)| format!("{k}: {n}")).collect::<Vec<_>>().join(", ")
    );
    if !b.spread_by_phase.is_empty() {
        md += &format!(
            "\n### How far the chunk moves with the noise\n\n{} noises decoded before every chunk of the first rollout of {} starts: \
             RMS spread of the commanded positions and std of the commanded width across noises.\n\n\
             | phase | chunks | position (mm) | width (mm) |\n|---|---:|---:|---:|\n",
            c.spread_noises, c.spread_starts
        );
        for (p, k, pos, w) in &b.spread_by_phase {
            md += &format!("| {} | {} | {:.1} | {:.1} |\n", p.name(), k, pos, w);
        }
    }
    md
}

fn probe_section(p: &ProbeReport) -> String {
    let c = &p.config;
    let mut md = format!(
        "\n## Does the noise of the next {} chunk(s) change success?\n\n\
         States along base rollouts of {} starts (seeds {}..) at latent steps {:?} (skipped after a success); from each, \
         {} candidate noises for the next {} chunk(s), each followed by {} base continuations, then the best candidate \
         again on {} fresh continuations. {} primitive steps.\n\n\
         - Between-candidate variance / binomial variance, pooled over {} informative states: **{}** (1 when the noise \
         changes nothing measurable; s.d. under that hypothesis {}).\n\
         - Implied s.d. of P(success | s, w) across noises, binomial noise taken out: **{}**.\n\
         - Best candidate's fresh success minus the state's mean: **{} +- {}** (s.e. over {} states).\n\n\
         | phase | states | informative | variance ratio | best - mean |\n|---|---:|---:|---:|---:|\n",
        c.hold,
        c.starts,
        c.first_seed,
        c.at_latent_steps,
        c.candidates,
        c.hold,
        c.continuations,
        c.continuations,
        p.primitive_steps,
        p.informative_states,
        opt(p.pooled_ratio, 2),
        opt(p.pooled_ratio_null_sd, 2),
        opt(p.implied_noise_sd(), 3),
        opt(p.best_gain, 3),
        opt(p.best_gain_se, 3),
        p.states.len()
    );
    for ph in &p.by_phase {
        md += &format!(
            "| {} | {} | {} | {} | {} +- {} |\n",
            ph.phase.name(),
            ph.states,
            ph.informative_states,
            opt(ph.pooled_ratio, 2),
            opt(ph.best_gain, 3),
            opt(ph.best_gain_se, 3)
        );
    }
    md += "\n| seed | latent step | phase | successes per candidate | mean | ratio | best, fresh |\n|---|---:|---|---|---:|---:|---|\n";
    for s in &p.states {
        md += &format!(
            "| {} | {} | {} | {:?} | {:.2} | {} | {} |\n",
            s.seed,
            s.latent_step,
            s.phase.name(),
            s.candidate_successes,
            s.mean,
            opt(s.variance_ratio, 2),
            rate(&s.best_holdout)
        );
    }
    md
}

fn policy_section(p: &PolicySearchReport) -> String {
    let c = &p.config;
    let mut md = format!(
        "\n## The best simple noise policies: one choice per phase\n\n\
         Per phase (approach / released / grasped / lifted), fresh noise at a scale in {:?} or one of {} constant vectors; chosen greedily \
         phase by phase on {} starts (seeds {}..), then measured with the base and every uniform scale on {} other starts \
         (seeds {}..), paired.\n\n\
         - Chosen: approach {}, released {}, grasped {}, lifted {} (search {}).\n\
         - Test starts: base {}; chosen {}; best uniform scale {} {}.\n\
         - Paired: {} starts only the chosen policy solved, {} only the base.\n\n\
         | phase | choice | search success |\n|---|---|---|\n",
        c.scales,
        c.constants,
        c.search_starts,
        c.search_first_seed,
        c.test_starts,
        c.test_first_seed,
        p.chosen[0],
        p.chosen[1],
        p.chosen[2],
        p.chosen[3],
        rate(&p.chosen_search),
        rate(&p.base_test),
        rate(&p.chosen_test),
        p.best_scale_test.0,
        rate(&p.best_scale_test.1),
        p.only_chosen,
        p.only_base
    );
    for t in &p.trials {
        md += &format!("| {} | {} | {} |\n", t.phase.name(), t.choice, rate(&t.search));
    }
    md
}
