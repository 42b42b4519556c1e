//! Property-based fuzzing (proptest) of diffusion-policy files: edited bytes of the shipped
//! Lift policy must load or give a typed error, never panic, and a policy that loads must drive
//! the latent environment to `Ok` or a typed error.
//!
//! Budget: `EQUIGYM_FUZZ_CASES` cases per harness (default [`DEFAULT_CASES`]); see
//! docs/reliability.md.

use std::sync::Arc;

use equigym_envs::{Env, EnvConfig, EnvError};
use equigym_wrappers::latent::LatentEnv;
use equigym_wrappers::{DiffusionPolicy, Error, DEFAULT_LATENT_BOUND};
use proptest::prelude::*;
use proptest::test_runner::Config;

const DEFAULT_CASES: u32 = 24;

/// The policy file the harnesses edit.
const SHIPPED_LIFT: &[u8] = include_bytes!("../../assets/edp/lift.safetensors");

/// The first bytes of a safetensors file hold its length prefix and JSON header (2.3 kB for
/// the shipped Lift policy): the parser's side of the file, where edits are aimed half the time.
const HEADER_FOCUS: usize = 2400;

fn config() -> Config {
    let cases = std::env::var("EQUIGYM_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(DEFAULT_CASES);
    Config { cases, failure_persistence: None, ..Config::default() }
}

#[path = "../../envs/tests/support/byte_edits.rs"]
mod byte_edits;
use byte_edits::Edit;

/// Edits, and whether they aim at the header.
fn edits() -> impl Strategy<Value = (bool, Vec<Edit>)> {
    (any::<bool>(), byte_edits::edits([4, 1, 2, 2], 6))
}

fn apply(bytes: &[u8], header: bool, edits: &[Edit]) -> Vec<u8> {
    byte_edits::apply(bytes, if header { HEADER_FOCUS } else { usize::MAX }, edits)
}

fn drive(policy: DiffusionPolicy) -> Result<(), TestCaseError> {
    let env = Env::new(EnvConfig::new("lift")).unwrap();
    let steps = policy.default_ddim_steps;
    let mut latent = match LatentEnv::new(env, Arc::new(policy), DEFAULT_LATENT_BOUND, steps.max(1)) {
        Ok(l) => l,
        Err(Error::Policy { .. } | Error::Env(EnvError::InvalidConfig(_))) => return Ok(()),
        Err(e) => return Err(TestCaseError::fail(format!("untyped error wrapping a loaded policy: {e}"))),
    };
    latent.reset(0).map_err(|e| TestCaseError::fail(format!("reset: {e}")))?;
    let w = vec![0.5; latent.latent_dim()];
    match latent.step(&w) {
        Ok(step) => prop_assert!(step.reward.is_finite()),
        // A policy whose weights became NaN decodes to NaN actions, which the env refuses.
        Err(Error::Env(EnvError::NonFinite { .. })) | Err(Error::Policy { .. }) => {}
        Err(e) => prop_assert!(false, "untyped error stepping with a loaded policy: {e}"),
    }
    Ok(())
}

#[test]
fn the_unedited_policy_loads_and_steps() {
    // Not through `drive`, which accepts a refusal: the shipped file must load, build a latent
    // env and take a finite step.
    let policy = DiffusionPolicy::from_bytes(SHIPPED_LIFT, "lift").unwrap();
    let steps = policy.default_ddim_steps;
    let env = Env::new(EnvConfig::new("lift")).unwrap();
    let mut latent = LatentEnv::new(env, Arc::new(policy), DEFAULT_LATENT_BOUND, steps).unwrap();
    latent.reset(0).unwrap();
    let step = latent.step(&vec![0.5; latent.latent_dim()]).unwrap();
    assert!(step.reward.is_finite() && step.executed > 0);
}

proptest! {
    #![proptest_config(config())]

    #[test]
    fn fuzz_policy_bytes((header, edits) in edits()) {
        let bytes = apply(SHIPPED_LIFT, header, &edits);
        match DiffusionPolicy::from_bytes(&bytes, "fuzz") {
            Ok(policy) => drive(policy)?,
            Err(Error::Policy { .. }) => {}
            Err(e) => prop_assert!(false, "untyped error: {e}"),
        }
    }

    #[test]
    fn fuzz_policy_random_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
        let refused = matches!(DiffusionPolicy::from_bytes(&bytes, "fuzz"), Err(Error::Policy { .. }));
        prop_assert!(refused, "random bytes were not refused as a policy error");
    }
}

/// The shipped Lift policy with one metadata entry replaced.
fn with_metadata(key: &str, value: &str) -> Vec<u8> {
    use safetensors::tensor::TensorView;
    use safetensors::SafeTensors;
    let (_, meta) = SafeTensors::read_metadata(SHIPPED_LIFT).unwrap();
    let mut metadata = meta.metadata().clone().unwrap();
    metadata.insert(key.into(), value.into());
    let st = SafeTensors::deserialize(SHIPPED_LIFT).unwrap();
    let views: Vec<(String, TensorView)> = st.tensors().into_iter().collect();
    safetensors::serialize(views, Some(metadata)).unwrap()
}

/// Regression (found by reading the counts the fuzz harness feeds on): a file declaring
/// `usize::MAX` layers made `Vec::with_capacity` abort, and a huge chunk length overflowed
/// `chunk_len * ACTION_DIM`; both are now refused as policy errors.
#[test]
fn regression_huge_counts_in_metadata_are_refused() {
    for (key, value) in
        [("num_layers", "18446744073709551615"), ("chunk_len", "18446744073709551615"), ("num_layers", "5000")]
    {
        let bytes = with_metadata(key, value);
        assert!(matches!(DiffusionPolicy::from_bytes(&bytes, "t"), Err(Error::Policy { .. })), "{key} = {value}");
    }
    // The same rebuild with the real value still loads.
    assert!(DiffusionPolicy::from_bytes(&with_metadata("chunk_len", "4"), "t").is_ok());
}
