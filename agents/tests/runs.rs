//! Whole runs on the Lift latent environment (tiny nets, short episodes): the same seed gives
//! identical logs and weights with 1 and 2 threads; a run killed after its second evaluation and
//! started again, or a finished one given a larger budget, ends bit for bit where the
//! uninterrupted run ends; and a committed golden file
//! catches any change in numerics (physics, EDP, kernels, agents).
//!
//! After an intended change of numerics, regenerate the golden file with
//! `EQUIGYM_BLESS=1 cargo test --release -p equigym-agents --test runs` and commit it.

use std::path::{Path, PathBuf};

use equigym_agents::run::LogRow;
use equigym_agents::{run, Method, Preset, RunConfig, RunSummary, TimeSplit};

const GOLDEN: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/golden/lift_short_runs.txt");

fn tiny(method: Method, out: &Path) -> RunConfig {
    let mut c = RunConfig::new(method, "lift", 3, 384, out).unwrap();
    c.preset = Preset {
        name: "test".into(),
        width: 16,
        layers: 2,
        utd: 1,
        utd_square: None,
        batch: 32,
        n_envs: 4,
        warmup: 48,
        ent_init: 0.2,
    };
    c.eval_every = 128;
    c.eval_episodes = 3;
    c.env.horizon = Some(48);
    c
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("equigym-agents-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// The log without its wall-clock column.
fn numbers(rows: &[LogRow]) -> Vec<(u64, u64, u64)> {
    rows.iter().map(|r| (r.env_steps, r.success_rate.to_bits(), r.mean_q.to_bits())).collect()
}

fn describe(method: Method, s: &RunSummary) -> String {
    let mut out = format!("{} params {:016x} grad_steps {}\n", method.name(), s.params_hash, s.grad_steps);
    for r in &s.rows {
        out.push_str(&format!("  {} {:?} {:?}\n", r.env_steps, r.success_rate, r.mean_q));
    }
    out
}

#[test]
fn threads_resume_and_golden() {
    let mut golden = String::new();
    for method in [Method::Dsrl, Method::Equi, Method::Approx] {
        let a_dir = scratch(&format!("a-{}", method.name()));
        let a = run(&tiny(method, &a_dir)).unwrap();
        assert_eq!(a.rows.len(), 4, "evaluations at 16, 128, 256 and 384 env steps");
        assert!(a.grad_steps > 0);
        golden.push_str(&describe(method, &a));
        if method == Method::Equi || method == Method::Dsrl {
            // Two threads: identical log and weights.
            let b_dir = scratch(&format!("b-{}", method.name()));
            let mut cb = tiny(method, &b_dir);
            cb.threads = 2;
            let b = run(&cb).unwrap();
            assert_eq!(numbers(&a.rows), numbers(&b.rows), "{method:?}: threads 1 vs 2");
            assert_eq!(a.params_hash, b.params_hash, "{method:?}: threads 1 vs 2");
            // Killed after the second evaluation, then started again.
            let c_dir = scratch(&format!("c-{}", method.name()));
            let mut cc = tiny(method, &c_dir);
            cc.stop_after_evals = Some(2);
            let stopped = run(&cc).unwrap();
            assert_eq!(stopped.rows.len(), 2);
            cc.stop_after_evals = None;
            let resumed = run(&cc).unwrap();
            assert_eq!(numbers(&a.rows), numbers(&resumed.rows), "{method:?}: resumed run");
            assert_eq!(a.params_hash, resumed.params_hash, "{method:?}: resumed run");
            assert_eq!(a.grad_steps, resumed.grad_steps);
            let run_dir = c_dir.join("lift/").join(method.name()).join("seed3");
            let log = std::fs::read_to_string(run_dir.join("log.csv")).unwrap();
            assert_eq!(log.lines().count(), 5, "the resumed log has every evaluation once");
            // Started again when finished: nothing changes, and the time split (summed over the
            // two invocations that did the work) comes back from summary.json.
            let files = |d: &Path| ["summary.json", "checkpoint.bin"].map(|f| std::fs::read(d.join(f)).unwrap());
            let before = files(&run_dir);
            let again = run(&cc).unwrap();
            assert_eq!(files(&run_dir), before, "{method:?}: a finished run's files are left as they were");
            assert_eq!((again.seconds, again.params_hash), (resumed.seconds, resumed.params_hash));
            let tenths = |x: f64| (x * 10.0).round() / 10.0;
            let t = resumed.time;
            assert_eq!(
                again.time,
                TimeSplit { rollout: tenths(t.rollout), train: tenths(t.train), eval: tenths(t.eval) },
                "{method:?}: the split is the run's, not the invocation's"
            );
            assert!(t.rollout > 0.0 && t.train > 0.0 && t.eval > stopped.time.eval);
            // The evaluation's step count is deterministic: summed over the two invocations it
            // is the uninterrupted run's, and a finished run's restart reads it back.
            assert!(0 < stopped.eval_env_steps && stopped.eval_env_steps < a.eval_env_steps);
            assert_eq!((resumed.eval_env_steps, again.eval_env_steps), (a.eval_env_steps, a.eval_env_steps));
            for d in [b_dir, c_dir] {
                let _ = std::fs::remove_dir_all(d);
            }
        }
        let _ = std::fs::remove_dir_all(a_dir);
    }
    if std::env::var_os("EQUIGYM_BLESS").is_some() {
        std::fs::create_dir_all(Path::new(GOLDEN).parent().unwrap()).unwrap();
        std::fs::write(GOLDEN, &golden).unwrap();
    }
    let want = std::fs::read_to_string(GOLDEN).expect("golden file missing: run with EQUIGYM_BLESS=1 once");
    assert_eq!(golden, want, "numerics changed; if intended, regenerate with EQUIGYM_BLESS=1 (see the module docs)");
}

#[test]
fn bad_options_and_foreign_checkpoints_are_typed_errors() {
    let dir = scratch("errors");
    let mut c = tiny(Method::Dsrl, &dir);
    c.task = "juggle".into();
    assert!(matches!(run(&c), Err(equigym_agents::Error::InvalidOption(_))));
    assert!(matches!(Preset::named("gpu"), Err(equigym_agents::Error::InvalidOption(_))));
    assert!(matches!(Method::parse("ppo"), Err(equigym_agents::Error::InvalidOption(_))));
    let mut c = tiny(Method::Dsrl, &dir);
    c.policy = Some("/nonexistent/edp.safetensors".into());
    assert!(matches!(run(&c), Err(equigym_agents::Error::Wrappers(_))));
    // A checkpoint of another configuration in the same place is refused, not mixed in.
    let mut c = tiny(Method::Dsrl, &dir);
    c.steps = 16;
    run(&c).unwrap();
    c.ent_init = Some(0.5);
    assert!(matches!(run(&c), Err(equigym_agents::Error::Checkpoint { .. })));
    // A corrupt checkpoint is an error too.
    std::fs::write(c.run_dir().join("checkpoint.bin"), b"garbage").unwrap();
    assert!(matches!(run(&c), Err(equigym_agents::Error::Checkpoint { .. })));
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn noise_aliased_runs_resume_bit_for_bit_and_learn_otherwise() {
    // DSRL-NA with training episodes that end at success: thread count and a kill + resume
    // change nothing (the action critics and the chunk replay are checkpointed), and the
    // learner is not the plain one.
    let method = Method::Equi;
    let cfg = |dir: &Path| {
        let mut c = tiny(method, dir);
        c.noise_aliased = true;
        c.terminate_on_success = true;
        c
    };
    let a_dir = scratch("na-a");
    let a = run(&cfg(&a_dir)).unwrap();
    assert_eq!(a.rows.len(), 4);
    let plain_dir = scratch("na-plain");
    let plain = run(&tiny(method, &plain_dir)).unwrap();
    assert_ne!(a.params_hash, plain.params_hash, "noise aliasing changes the learner");
    let meta = std::fs::read_to_string(a_dir.join("lift/equi/seed3/run.json")).unwrap();
    let meta: serde_json::Value = serde_json::from_str(&meta).unwrap();
    assert_eq!((&meta["terminate_on_success"], &meta["noise_aliased"]), (&true.into(), &true.into()), "{meta}");
    assert_eq!((&meta["eval_every"], &meta["eval_episodes"], &meta["horizon"]), (&128.into(), &3.into(), &48.into()));

    let b_dir = scratch("na-b");
    let mut cb = cfg(&b_dir);
    cb.threads = 2;
    let b = run(&cb).unwrap();
    assert_eq!((numbers(&a.rows), a.params_hash), (numbers(&b.rows), b.params_hash), "threads 1 vs 2");

    let c_dir = scratch("na-c");
    let mut cc = cfg(&c_dir);
    // Stopped after the third evaluation (256 env steps), past the warm-up (48 latent steps =
    // 192 env steps), so that the saved action critics have been trained.
    cc.stop_after_evals = Some(3);
    run(&cc).unwrap();
    cc.stop_after_evals = None;
    let resumed = run(&cc).unwrap();
    assert_eq!((numbers(&a.rows), a.params_hash), (numbers(&resumed.rows), resumed.params_hash), "resumed");

    // A finished run whose budget grows (the study's way of extending a cell) continues from its
    // checkpoint to what a run with the larger budget from the start ends at.
    let e_dir = scratch("na-e");
    let mut ce = cfg(&e_dir);
    ce.steps = 256;
    let short = run(&ce).unwrap();
    assert_eq!(short.rows.len(), 3);
    ce.steps = 384;
    let extended = run(&ce).unwrap();
    assert_eq!((numbers(&a.rows), a.params_hash), (numbers(&extended.rows), extended.params_hash), "extended");
    assert_eq!(a.grad_steps, extended.grad_steps);

    // A plain run's checkpoint is not resumed as a noise-aliased one.
    let mut cp = tiny(method, &plain_dir);
    cp.steps = 512;
    cp.noise_aliased = true;
    assert!(run(&cp).is_err());
    for d in [a_dir, b_dir, c_dir, e_dir, plain_dir] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn selecting_runs_resume_bit_for_bit_and_refuse_actor_options() {
    // Selection among fresh candidates (`select`): thread count and a kill + resume change
    // nothing, the actor is never stepped, and options that only an actor has are refused.
    let cfg = |dir: &Path| {
        let mut c = tiny(Method::Dsrl, dir);
        c.select = Some(4);
        c.terminate_on_success = true;
        c
    };
    let a_dir = scratch("select-a");
    let a = run(&cfg(&a_dir)).unwrap();
    assert_eq!(a.rows.len(), 4);
    let meta = std::fs::read_to_string(a_dir.join("lift/dsrl/seed3/run.json")).unwrap();
    let meta: serde_json::Value = serde_json::from_str(&meta).unwrap();
    assert_eq!(meta["select"], 4, "{meta}");
    // The learner's record is the selecting learner's: no entropy coefficient, a real critic loss.
    let train = std::fs::read_to_string(a_dir.join("lift/dsrl/seed3/train.csv")).unwrap();
    let last: Vec<f64> = train.lines().last().unwrap().split(',').map(|v| v.parse().unwrap()).collect();
    assert_eq!((last[1], last[2]), (0.0, 0.0), "alpha and entropy of a learner without an actor: {train}");
    assert!(last[4] > 0.0 && last[5].is_finite() && last[6].is_finite(), "critic loss, target and policy Q: {train}");

    let b_dir = scratch("select-b");
    let mut cb = cfg(&b_dir);
    cb.threads = 2;
    cb.stop_after_evals = Some(3);
    run(&cb).unwrap();
    cb.stop_after_evals = None;
    let b = run(&cb).unwrap();
    assert_eq!((numbers(&a.rows), a.params_hash), (numbers(&b.rows), b.params_hash), "2 threads, resumed");

    let plain_dir = scratch("select-plain");
    let mut cp = tiny(Method::Dsrl, &plain_dir);
    cp.terminate_on_success = true;
    let plain = run(&cp).unwrap();
    assert_ne!(a.params_hash, plain.params_hash, "selection trains another learner");

    for bad in [
        |c: &mut RunConfig| c.select = Some(0),
        |c: &mut RunConfig| c.noise_aliased = true,
        |c: &mut RunConfig| c.target_entropy = Some(5.0),
        |c: &mut RunConfig| c.prior_kl = Some(2.0),
    ] {
        let mut c = cfg(&a_dir);
        bad(&mut c);
        assert!(matches!(run(&c), Err(equigym_agents::Error::InvalidOption(_))));
    }
    for d in [a_dir, b_dir, plain_dir] {
        let _ = std::fs::remove_dir_all(d);
    }
}
