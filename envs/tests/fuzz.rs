//! Property-based fuzzing (proptest, stable Rust) of the inputs a user controls: saved-state
//! bytes, URDF text and actions. Every input must give `Ok` or a typed error, never a panic,
//! and whatever is accepted must keep the simulation finite.
//!
//! Budget: `EQUIGYM_FUZZ_CASES` cases per harness (default [`DEFAULT_CASES`], the CI smoke run);
//! docs/reliability.md lists the longer runs and their findings. Findings are kept twice: in
//! proptest's regression file next to this one and as the named `regression_*` tests below.

use equigym_envs::robot::parse_urdf;
use equigym_envs::{Env, EnvConfig, EnvError, FieldKind};
use proptest::prelude::*;
use proptest::test_runner::Config;

/// Cases per harness when `EQUIGYM_FUZZ_CASES` is not set.
const DEFAULT_CASES: u32 = 24;

/// Steps run after an accepted input, to see that the simulation stays sound.
const STEPS_AFTER: usize = 3;

/// How far below the table top a world position may be before it has gone through the table
/// (m); objects resting on the table have their centres above the top.
const THROUGH_TABLE_TOLERANCE: f64 = 0.005;

const PANDA_URDF: &str = equigym_envs::env::PANDA_URDF;

/// The saved-state checksum (FNV-1a, 64-bit, little-endian at the end), recomputed here to
/// forge states: the format is part of the state's contract.
const CHECKSUM_LEN: usize = 8;
fn fnv1a64(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3))
}

fn cases() -> u32 {
    std::env::var("EQUIGYM_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(DEFAULT_CASES)
}

fn config() -> Config {
    Config { cases: cases(), failure_persistence: None, ..Config::default() }
}

/// The world-frame positions in an observation (object centres, gripper), by field name.
fn world_positions(env: &Env, obs: &[f64]) -> Vec<(String, [f64; 3])> {
    env.observation_layout()
        .fields()
        .iter()
        .filter(|f| f.kind == FieldKind::Position && !f.name.contains("_to_"))
        .map(|f| (f.name.clone(), [obs[f.start], obs[f.start + 1], obs[f.start + 2]]))
        .collect()
}

/// The simulation is sound: a finite observation and nothing below the table top inside the
/// table's footprint.
fn assert_sound(env: &mut Env) -> Result<(), TestCaseError> {
    let obs = env.observe().to_vec();
    prop_assert!(obs.iter().all(|v| v.is_finite()), "non-finite observation {obs:?}");
    let spec = env.task().scene_spec();
    for (name, p) in world_positions(env, &obs) {
        let inside = p[0].abs() < spec.table.half_extents[0] && p[1].abs() < spec.table.half_extents[1];
        prop_assert!(
            !(inside && p[2] < spec.table.top - THROUGH_TABLE_TOLERANCE),
            "{name} at {p:?} is below the table top {}",
            spec.table.top
        );
    }
    Ok(())
}

fn step_a_little(env: &mut Env) -> Result<(), TestCaseError> {
    for _ in 0..STEPS_AFTER {
        let hold = env.current_target();
        match env.step(&hold) {
            Ok(_) | Err(EnvError::CallOrder(_)) => {}
            Err(e) => return Err(TestCaseError::fail(format!("holding failed after an accepted input: {e}"))),
        }
    }
    assert_sound(env)
}

/// A valid state a few steps into an episode.
fn some_state(task: &str, seed: u64) -> (Env, Vec<u8>) {
    let mut env = Env::new(EnvConfig::new(task)).unwrap();
    env.reset(seed).unwrap();
    for _ in 0..2 {
        let hold = env.current_target();
        env.step(&hold).unwrap();
    }
    let state = env.get_state().unwrap();
    (env, state)
}

#[path = "support/byte_edits.rs"]
mod byte_edits;
use byte_edits::{apply as apply_anywhere, Edit};

fn edits() -> impl Strategy<Value = Vec<Edit>> {
    byte_edits::edits([1, 1, 1, 1], 8)
}

fn apply(bytes: &[u8], edits: &[Edit]) -> Vec<u8> {
    apply_anywhere(bytes, usize::MAX, edits)
}

/// An action component: anything from ordinary values to NaN and huge magnitudes.
fn component() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => -2.0f64..2.0,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => Just(0.0),
        1 => any::<f64>(),
        1 => prop_oneof![Just(1e300), Just(-1e300), Just(f64::MIN_POSITIVE), Just(1e-300)],
    ]
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_set_state_bytes(task in prop_oneof![Just("lift"), Just("stack"), Just("square")],
                            seed in 0u64..1000, edits in edits()) {
        let (mut env, state) = some_state(task, seed);
        let before = env.get_state().unwrap();
        let bytes = apply(&state, &edits);
        match env.set_state(&bytes) {
            Ok(()) => step_a_little(&mut env)?,
            Err(EnvError::InvalidState(_)) => prop_assert_eq!(env.get_state().unwrap(), before, "a refused state changed the env"),
            Err(e) => prop_assert!(false, "set_state gave an untyped error: {e}"),
        }
    }

    /// Edited states whose checksum was recomputed (a forged state): the decoder and the
    /// physics engine behind the checksum. rapier trusts its serialised worlds (forged
    /// multibody data reached index and assertion panics in its first step), so `set_state`
    /// steps a copy first and `step` turns a later engine panic into a typed error that ends
    /// the episode.
    #[test]
    fn fuzz_set_state_forged_checksum(task in prop_oneof![Just("lift"), Just("stack"), Just("square")],
                                      seed in 0u64..1000, edits in edits()) {
        let (mut env, state) = some_state(task, seed);
        let mut bytes = apply(&state[..state.len() - CHECKSUM_LEN], &edits);
        bytes.extend_from_slice(&fnv1a64(&bytes).to_le_bytes());
        match env.set_state(&bytes) {
            Ok(()) => {
                // A forged state may describe anything the format can (an object inside the
                // table, say); what it must not do is crash: steps succeed or end the episode
                // with a typed error.
                for _ in 0..STEPS_AFTER {
                    let hold = env.current_target();
                    match env.step(&hold) {
                        Ok(_) | Err(EnvError::CallOrder(_)) | Err(EnvError::Physics(_)) => {}
                        Err(e) => prop_assert!(false, "untyped error stepping a forged state: {e}"),
                    }
                }
            }
            Err(EnvError::InvalidState(_)) => {}
            Err(e) => prop_assert!(false, "set_state gave an untyped error: {e}"),
        }
        // Whatever the forged state did, a reset gives a sound environment again.
        env.reset(seed).map_err(|e| TestCaseError::fail(format!("reset after a forged state failed: {e}")))?;
        step_a_little(&mut env)?;
    }

    #[test]
    fn fuzz_set_state_random_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let (mut env, _) = some_state("lift", 0);
        match env.set_state(&bytes) {
            Ok(()) => step_a_little(&mut env)?,
            Err(EnvError::InvalidState(_)) => {}
            Err(e) => prop_assert!(false, "set_state gave an untyped error: {e}"),
        }
    }

    #[test]
    fn fuzz_urdf_text(edits in edits()) {
        let text = apply(PANDA_URDF.as_bytes(), &edits);
        let text = String::from_utf8_lossy(&text);
        if let Ok(robot) = parse_urdf(&text) {
            match Env::with_robot(EnvConfig::new("lift"), std::sync::Arc::new(robot)) {
                Ok(mut env) => {
                    env.reset(0).map_err(|e| TestCaseError::fail(format!("reset failed: {e}")))?;
                    step_a_little(&mut env)?;
                }
                Err(EnvError::InvalidConfig(_) | EnvError::Urdf { .. }) => {}
                Err(e) => prop_assert!(false, "untyped error building with a parsed URDF: {e}"),
            }
        }
    }

    #[test]
    fn fuzz_urdf_garbage(text in ".{0,300}") {
        prop_assert!(parse_urdf(&text).is_err());
    }

    #[test]
    fn fuzz_actions(task in prop_oneof![Just("lift"), Just("stack"), Just("square")],
                    actions in proptest::collection::vec(proptest::collection::vec(component(), 8..12), 1..6)) {
        let mut env = Env::new(EnvConfig::new(task)).unwrap();
        env.reset(3).unwrap();
        for a in &actions {
            match env.step(a) {
                Ok(_) => assert_sound(&mut env)?,
                Err(EnvError::WrongLength { .. } | EnvError::NonFinite { .. }) => {
                    prop_assert!(a.len() != 10 || a.iter().any(|v| !v.is_finite()));
                }
                Err(e) => prop_assert!(false, "untyped error for action {a:?}: {e}"),
            }
        }
    }
}

/// Regression (fuzz_set_state_bytes, 2000 cases): one byte of a Square state set to 0x80 was
/// accepted by the decoder and made parry's cuboid-cuboid SAT assert (`separation >= 0.0`)
/// panic on the next step; another edit tripped an arena-index assert. Saved states now end with
/// a checksum, so edited bytes are refused before they reach the physics engine.
#[test]
fn regression_edited_state_byte_is_refused_not_stepped() {
    let (mut env, state) = some_state("square", 486);
    let before = env.get_state().unwrap();
    let bytes = apply(&state, &[Edit::Set(384_839_254_416_231_509, 128)]);
    assert!(matches!(env.set_state(&bytes), Err(EnvError::InvalidState(_))));
    assert_eq!(env.get_state().unwrap(), before);
    for cut in [0, 1, state.len() / 2, state.len() - 1] {
        assert!(matches!(env.set_state(&state[..cut]), Err(EnvError::InvalidState(_))), "cut at {cut}");
    }
    env.set_state(&state).unwrap();
    step_a_little(&mut env).unwrap();
}
