//! The batched environment: bitwise equal to B single environments with the same seeds,
//! independent of the thread count, with gymnasium's auto-reset semantics and typed errors.

use equigym_envs::batch::episode_seed_stream;
use equigym_envs::rng::EpisodeRng;
use equigym_envs::{AutoresetMode, BatchEnv, Env, EnvConfig, EnvError};

const B: usize = 5;

fn config(task: &str, horizon: usize) -> EnvConfig {
    let mut c = EnvConfig::new(task);
    c.horizon = Some(horizon);
    c
}

fn batch(task: &str, horizon: usize, threads: usize, mode: AutoresetMode) -> BatchEnv {
    let envs = (0..B).map(|_| Env::new(config(task, horizon)).unwrap()).collect();
    BatchEnv::new(envs, threads, mode).unwrap()
}

/// Random actions for `steps` steps of B environments, flat.
fn actions(env: &Env, steps: usize, seed: u64) -> Vec<Vec<f64>> {
    let (lo, hi) = env.action_bounds();
    let mut rng = EpisodeRng::from_seed(seed);
    (0..steps).map(|_| (0..B * 10).map(|j| rng.uniform(lo[j % 10], hi[j % 10])).collect()).collect()
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Everything a batch reports after one step, as bits.
fn record(b: &BatchEnv) -> Vec<u64> {
    let mut out = Vec::new();
    for i in 0..b.num_envs() {
        out.extend(bits(b.obs(i).unwrap()));
        let s = b.last_step(i).unwrap();
        out.extend([
            s.reward.to_bits(),
            s.terminated as u64,
            s.truncated as u64,
            s.success as u64,
            b.was_reset(i).unwrap() as u64,
        ]);
    }
    out
}

#[test]
fn batch_equals_single_environments_bitwise_for_any_thread_count_with_next_step_autoreset() {
    let horizon = 7;
    let seeds: Vec<u64> = (0..B as u64).map(|i| 100 + 3 * i).collect();
    let probe = Env::new(config("lift", horizon)).unwrap();
    let acts = actions(&probe, 20, 1);

    // The reference: B single environments, reset by hand the way NextStep auto-reset does.
    let mut singles: Vec<Env> = (0..B).map(|_| Env::new(config("lift", horizon)).unwrap()).collect();
    let mut streams: Vec<EpisodeRng> = seeds.iter().map(|&s| episode_seed_stream(s)).collect();
    let mut ended = [false; B];
    let mut expected = Vec::new();
    let mut row = Vec::new();
    for (env, &s) in singles.iter_mut().zip(&seeds) {
        row.extend(bits(env.reset(s).unwrap()));
    }
    let first_obs = row.clone();
    for a in &acts {
        let mut rec = Vec::new();
        for i in 0..B {
            if ended[i] {
                let seed = streams[i].next_u64();
                rec.extend(bits(singles[i].reset(seed).unwrap()));
                rec.extend([0f64.to_bits(), 0, 0, 0, 1]);
                ended[i] = false;
            } else {
                let r = singles[i].step(&a[i * 10..i * 10 + 10]).unwrap();
                rec.extend(bits(singles[i].observe()));
                rec.extend([
                    r.reward.to_bits(),
                    r.terminated as u64,
                    r.truncated as u64,
                    r.evaluation.success() as u64,
                    0,
                ]);
                ended[i] = r.terminated || r.truncated;
            }
        }
        expected.push(rec);
    }

    for threads in [1, 2, 3] {
        let mut b = batch("lift", horizon, threads, AutoresetMode::NextStep);
        b.reset(&seeds).unwrap();
        let obs0: Vec<u64> = (0..B).flat_map(|i| bits(b.obs(i).unwrap())).collect();
        assert_eq!(obs0, first_obs, "reset observations, {threads} threads");
        for (t, a) in acts.iter().enumerate() {
            b.step(a).unwrap();
            assert_eq!(record(&b), expected[t], "step {t}, {threads} threads");
        }
        // Episode boundaries: 7 steps, one reset step, 7 steps, ... -> three episodes started.
        assert_eq!(b.episode_index(0), Some(2));
    }
}

#[test]
fn same_step_autoreset_returns_the_reset_observation_and_keeps_the_final_one() {
    let horizon = 4;
    let seeds = [1, 2, 3, 4, 5];
    let probe = Env::new(config("stack", horizon)).unwrap();
    let acts = actions(&probe, horizon, 2);
    let mut next = batch("stack", horizon, 2, AutoresetMode::NextStep);
    let mut same = batch("stack", horizon, 2, AutoresetMode::SameStep);
    next.reset(&seeds).unwrap();
    same.reset(&seeds).unwrap();
    for (t, a) in acts.iter().enumerate() {
        next.step(a).unwrap();
        same.step(a).unwrap();
        for i in 0..B {
            let last = t + 1 == horizon;
            assert_eq!(same.last_step(i).unwrap(), next.last_step(i).unwrap());
            assert_eq!(same.last_step(i).unwrap().truncated, last);
            assert_eq!(same.was_reset(i).unwrap(), last);
            if last {
                assert_eq!(bits(same.final_obs(i).unwrap()), bits(next.obs(i).unwrap()));
            } else {
                assert!(same.final_obs(i).is_none());
                assert_eq!(bits(same.obs(i).unwrap()), bits(next.obs(i).unwrap()));
            }
        }
    }
    // The reset observation in SameStep mode is the one NextStep returns on the following call.
    next.step(&acts[0]).unwrap();
    for i in 0..B {
        assert!(next.was_reset(i).unwrap());
        assert_eq!(bits(same.obs(i).unwrap()), bits(next.obs(i).unwrap()));
        assert_eq!(same.episode_seeds()[i], next.episode_seeds()[i]);
    }
}

#[test]
fn bad_input_is_a_typed_error_and_nothing_steps() {
    let mut b = batch("lift", 400, 2, AutoresetMode::NextStep);
    assert!(matches!(b.step(&[0.0; B * 10]), Err(EnvError::CallOrder(_))));
    b.reset(&[0, 1, 2, 3, 4]).unwrap();
    let before: Vec<u64> = (0..B).flat_map(|i| bits(b.obs(i).unwrap())).collect();
    let hold: Vec<f64> = b.envs().flat_map(|e| e.current_target()).collect();
    assert!(matches!(b.step(&hold[..B * 10 - 1]), Err(EnvError::WrongLength { .. })));
    let mut bad = hold.clone();
    bad[4 * 10 + 2] = f64::NAN;
    match b.step(&bad) {
        Err(EnvError::NonFinite { what, index, .. }) => {
            assert_eq!(what, "action of environment 4");
            assert_eq!(index, 2);
        }
        other => panic!("expected NonFinite, got {other:?}"),
    }
    assert!(b.envs().all(|e| e.elapsed_steps() == 0), "no environment stepped");
    let after: Vec<u64> = (0..B).flat_map(|i| bits(b.obs(i).unwrap())).collect();
    assert_eq!(before, after);
    assert!(matches!(b.reset(&[0, 1]), Err(EnvError::WrongLength { .. })));
    b.step(&hold).unwrap();
    assert!(b.envs().all(|e| e.elapsed_steps() == 1));
    // Out-of-range indices are answered with None, never a panic.
    assert!(b.obs(B).is_none() && b.last_step(B).is_none() && b.was_reset(B).is_none());
    assert!(b.final_obs(usize::MAX).is_none() && b.episode_index(B).is_none() && b.env(B).is_none());
    assert!(BatchEnv::<Env>::new(Vec::new(), 1, AutoresetMode::NextStep).is_err());
    assert!("sometimes".parse::<AutoresetMode>().is_err());
}

#[test]
fn masked_reset_resets_only_the_chosen_environments() {
    let mut b = batch("lift", 400, 2, AutoresetMode::NextStep);
    b.reset(&[10, 11, 12, 13, 14]).unwrap();
    let hold: Vec<f64> = b.envs().flat_map(|e| e.current_target()).collect();
    b.step(&hold).unwrap();
    b.reset_masked(&[0, 99, 0, 0, 0], &[false, true, false, false, false]).unwrap();
    let steps: Vec<usize> = b.envs().map(|e| e.elapsed_steps()).collect();
    assert_eq!(steps, [1, 0, 1, 1, 1]);
    let mut single = Env::new(EnvConfig::new("lift")).unwrap();
    assert_eq!(bits(b.obs(1).unwrap()), bits(single.reset(99).unwrap()));
    assert_eq!(b.episode_seeds()[1], 99);
}

#[test]
fn disabled_autoreset_leaves_resets_to_the_caller_and_refuses_to_step_an_ended_episode() {
    let horizon = 3;
    let mut b = batch("lift", horizon, 2, AutoresetMode::Disabled);
    b.reset(&[20, 21, 22, 23, 24]).unwrap();
    let hold: Vec<f64> = b.envs().flat_map(|e| e.current_target()).collect();
    for _ in 0..horizon {
        b.step(&hold).unwrap();
    }
    // Every episode ended on that step and none was reset behind the caller's back.
    assert!((0..B).all(|i| b.last_step(i).unwrap().truncated && !b.was_reset(i).unwrap()));
    assert!(b.envs().all(|e| e.elapsed_steps() == horizon));
    let err = b.step(&hold).unwrap_err();
    assert!(matches!(err, EnvError::CallOrder(_)), "{err}");
    assert!(b.envs().all(|e| e.elapsed_steps() == horizon), "a refused step moved something");
    // The caller resets the ended episodes with seeds of its choosing; then they step again.
    b.reset_masked(&[30, 31, 32, 33, 34], &[true; B]).unwrap();
    let mut single = Env::new(config("lift", horizon)).unwrap();
    assert_eq!(bits(b.obs(3).unwrap()), bits(single.reset(33).unwrap()));
    b.step(&hold).unwrap();
    assert!(b.envs().all(|e| e.elapsed_steps() == 1));
    assert_eq!("disabled".parse::<AutoresetMode>().unwrap().as_str(), "disabled");
}

#[test]
fn masked_steps_move_only_the_chosen_environments() {
    let seeds = [40, 41, 42, 43, 44];
    let mut b = batch("lift", 400, 2, AutoresetMode::NextStep);
    b.reset(&seeds).unwrap();
    let probe = Env::new(config("lift", 400)).unwrap();
    let acts = actions(&probe, 1, 5).remove(0);
    let mask = [true, false, true, false, false];
    // The rows of environments that do not step are not read, not even checked.
    let mut rows = acts.clone();
    rows[10..20].fill(f64::NAN);
    b.step_masked(&rows, &mask).unwrap();
    for i in 0..B {
        let mut single = Env::new(config("lift", 400)).unwrap();
        single.reset(seeds[i]).unwrap();
        if mask[i] {
            single.step(&acts[i * 10..(i + 1) * 10]).unwrap();
        }
        assert_eq!(bits(b.obs(i).unwrap()), bits(single.observe()), "environment {i}");
        assert_eq!(b.env(i).unwrap().elapsed_steps(), mask[i] as usize);
    }
    // A stepped row is still checked, and a wrong mask length is a typed error.
    rows[0] = f64::NAN;
    assert!(b.step_masked(&rows, &mask).is_err());
    assert!(matches!(b.step_masked(&acts, &[true; 2]), Err(EnvError::WrongLength { .. })));
}

#[test]
fn edit_changes_a_member_in_place_and_reads_its_observation_again() {
    let mut b = batch("lift", 400, 1, AutoresetMode::Disabled);
    b.reset(&[50, 51, 52, 53, 54]).unwrap();
    let mut donor = Env::new(config("lift", 400)).unwrap();
    donor.reset(77).unwrap();
    let state = donor.get_state().unwrap();
    b.edit(2, |e| e.set_state(&state)).unwrap().unwrap();
    assert_eq!(bits(b.obs(2).unwrap()), bits(donor.observe()));
    assert!(b.edit(B, |_| ()).is_none());
}

/// A member that takes `millis` per step, fails while `fail` is set, and writes the batch's
/// global step order into its observation (to see the schedule).
struct Timed {
    millis: u64,
    fail: bool,
    clock: std::sync::Arc<std::sync::atomic::AtomicUsize>,
}

impl equigym_envs::BatchMember for Timed {
    fn observation_dim(&self) -> usize {
        1
    }
    fn action_dim(&self) -> usize {
        1
    }
    fn reset_into(&mut self, _seed: u64, obs: &mut [f64]) -> equigym_envs::Result<()> {
        obs[0] = -1.0;
        Ok(())
    }
    fn step_into(&mut self, _action: &[f64], obs: &mut [f64]) -> equigym_envs::Result<equigym_envs::MemberStep> {
        obs[0] = self.clock.fetch_add(1, std::sync::atomic::Ordering::SeqCst) as f64;
        std::thread::sleep(std::time::Duration::from_millis(self.millis));
        if self.fail {
            return Err(EnvError::Physics(format!("member of {} ms", self.millis)));
        }
        Ok(equigym_envs::MemberStep::default())
    }
    fn observe_into(&mut self, _obs: &mut [f64]) {}
}

fn timed_batch(millis: &[u64], threads: usize) -> BatchEnv<Timed> {
    let clock = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let members = millis.iter().map(|&millis| Timed { millis, fail: false, clock: clock.clone() }).collect();
    let mut b = BatchEnv::new(members, threads, AutoresetMode::Disabled).unwrap();
    b.reset(&vec![0; millis.len()]).unwrap();
    b
}

#[test]
fn the_members_that_took_longest_on_the_last_step_step_first() {
    // One thread makes the schedule the order: index order while nothing is known, then by
    // the last step's time, slowest first (here the reverse of the index order). The sleeps lie
    // 40 ms apart so that a loaded machine's late wake-ups (a few ms) cannot reorder them.
    let millis = [1, 40, 80, 120];
    let mut b = timed_batch(&millis, 1);
    let order = |b: &BatchEnv<Timed>| (0..4).map(|i| b.obs(i).unwrap()[0] as usize).collect::<Vec<_>>();
    b.step(&[0.0; 4]).unwrap();
    assert_eq!(order(&b), [0, 1, 2, 3]);
    b.step(&[0.0; 4]).unwrap();
    assert_eq!(order(&b), [7, 6, 5, 4], "the slowest member should step first");
    // A member left out of a masked step keeps its last time.
    b.step_masked(&[0.0; 4], &[true, true, true, false]).unwrap();
    b.step(&[0.0; 4]).unwrap();
    assert_eq!(order(&b), [14, 13, 12, 11]);
}

#[test]
fn of_several_failing_members_the_lowest_index_reports_for_any_thread_count() {
    for threads in [1, 2, 3] {
        let mut b = timed_batch(&[3, 1, 6, 2, 5], threads);
        b.step(&[0.0; 5]).unwrap();
        for i in [1, 3] {
            b.edit(i, |m| m.fail = true).unwrap();
        }
        let err = b.step(&[0.0; 5]).unwrap_err();
        assert!(err.to_string().contains("member of 1 ms"), "{threads} threads: {err}");
        // Every member stepped, the failing ones included: ten steps in all.
        let last: Vec<f64> = (0..5).map(|i| b.obs(i).unwrap()[0]).collect();
        assert!(last.iter().all(|&x| x >= 5.0), "{threads} threads: {last:?}");
        assert!(b.step(&[0.0; 5]).is_err(), "a failed member step leaves the batch needing a reset");
    }
}
