//! The diffusion-policy runtime: DDIM arithmetic on a hand-made policy, and file errors.

use std::collections::HashMap;

use equigym_envs::{Env, EnvConfig};
use equigym_wrappers::latent::{step_batch, LatentEnv};
use equigym_wrappers::{DiffusionPolicy, Error};
use safetensors::tensor::TensorView;
use safetensors::Dtype;

const OBS: usize = 22;
const CHUNK: usize = 40;
const T: usize = 10;
const EMB: usize = 2;

fn bytes_f64(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// A one-layer policy whose noise prediction is the constant `eps` (zero weights).
fn constant_policy(eps: f64, format: &str) -> Vec<u8> {
    let abar: Vec<f64> = (0..T).map(|t| 1.0 - 0.09 * t as f64).collect();
    let mut tensors: Vec<(String, Vec<u8>, Vec<usize>)> = vec![
        ("alphas_cumprod".into(), bytes_f64(&abar), vec![T]),
        ("time_embedding".into(), bytes_f64(&vec![0.0; T * EMB]), vec![T, EMB]),
        ("obs_offset".into(), bytes_f64(&[0.0; OBS]), vec![OBS]),
        ("obs_scale".into(), bytes_f64(&[1.0; OBS]), vec![OBS]),
        ("action_offset".into(), bytes_f64(&[0.5; CHUNK]), vec![CHUNK]),
        ("action_scale".into(), bytes_f64(&[2.0; CHUNK]), vec![CHUNK]),
        ("layer0.weight".into(), bytes_f64(&vec![0.0; CHUNK * (OBS + CHUNK + EMB)]), vec![CHUNK, OBS + CHUNK + EMB]),
        ("layer0.bias".into(), bytes_f64(&[eps; CHUNK]), vec![CHUNK]),
    ];
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    let views: Vec<(String, TensorView)> =
        tensors.iter().map(|(n, d, s)| (n.clone(), TensorView::new(Dtype::F64, s.clone(), d).unwrap())).collect();
    let meta: HashMap<String, String> = [
        ("format", format),
        ("task", "lift"),
        ("chunk_len", "4"),
        ("num_layers", "1"),
        ("activation", "relu"),
        ("num_train_timesteps", "10"),
        ("ddim_steps", "5"),
        ("group", "C8"),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.to_string()))
    .collect();
    safetensors::serialize(views, Some(meta)).unwrap()
}

#[test]
fn ddim_follows_the_closed_form() {
    let eps = 0.3;
    let p = DiffusionPolicy::from_bytes(&constant_policy(eps, "equigym-edp-1"), "test").unwrap();
    assert_eq!(p.ddim_timesteps(5), vec![8, 6, 4, 2, 0]);
    let w = vec![0.7; CHUNK];
    let mut out = vec![0.0; CHUNK];
    p.sample(&[0.0; OBS], &w, 5, &mut out).unwrap();
    // By hand: x <- sqrt(ab') x0 + sqrt(1 - ab') eps, x0 = (x - sqrt(1 - ab) eps) / sqrt(ab).
    let abar = |t: i64| if t < 0 { 1.0 } else { 1.0 - 0.09 * t as f64 };
    let mut x = 0.7;
    for t in [8i64, 6, 4, 2, 0] {
        let x0 = (x - (1.0 - abar(t)).sqrt() * eps) / abar(t).sqrt();
        x = abar(t - 2).sqrt() * x0 + (1.0 - abar(t - 2)).sqrt() * eps;
    }
    for v in &out {
        assert!((v - (x * 2.0 + 0.5)).abs() < 1e-12);
    }
}

#[test]
fn bad_files_are_typed_errors() {
    let good = constant_policy(0.0, "equigym-edp-1");
    assert!(matches!(DiffusionPolicy::from_bytes(&good[..good.len() - 9], "t"), Err(Error::Policy { .. })));
    assert!(matches!(DiffusionPolicy::from_bytes(b"nonsense", "t"), Err(Error::Policy { .. })));
    let err = DiffusionPolicy::from_bytes(&constant_policy(0.0, "other-format"), "t").unwrap_err();
    assert!(err.to_string().contains("format"), "{err}");
    assert!(matches!(DiffusionPolicy::load("/nonexistent/policy.safetensors"), Err(Error::PolicyNotFound(_))));
    let p = DiffusionPolicy::from_bytes(&good, "t").unwrap();
    let mut out = vec![0.0; CHUNK];
    assert!(p.sample(&[0.0; OBS], &[f64::NAN; CHUNK], 5, &mut out).is_err());
    assert!(p.sample(&[0.0; OBS], &[0.0; CHUNK], 0, &mut out).is_err());
    assert!(p.sample(&[0.0; 3], &[0.0; CHUNK], 5, &mut out).is_err());
    // A Lift policy refuses a Stack environment.
    let stack = Env::new(EnvConfig::new("stack")).unwrap();
    assert!(LatentEnv::new(stack, std::sync::Arc::new(p), 1.5, 5).is_err());
}

#[test]
fn batched_latent_steps_equal_single_ones() {
    let policy = std::sync::Arc::new(DiffusionPolicy::from_bytes(&constant_policy(0.1, "equigym-edp-1"), "t").unwrap());
    let make = || LatentEnv::new(Env::new(EnvConfig::new("lift")).unwrap(), policy.clone(), 1.5, 5).unwrap();
    let mut batch: Vec<LatentEnv> = (0..3).map(|_| make()).collect();
    let mut single: Vec<LatentEnv> = (0..3).map(|_| make()).collect();
    for (k, (b, s)) in batch.iter_mut().zip(single.iter_mut()).enumerate() {
        b.reset(k as u64).unwrap();
        s.reset(k as u64).unwrap();
    }
    let w: Vec<f64> = (0..3 * CHUNK).map(|i| ((i as f64) * 0.37).sin()).collect();
    let steps = step_batch(&mut batch, &w).unwrap();
    for (k, s) in single.iter_mut().enumerate() {
        let r = s.step(&w[k * CHUNK..(k + 1) * CHUNK]).unwrap();
        assert_eq!(r, steps[k]);
        assert_eq!(s.env().get_state().unwrap(), batch[k].env().get_state().unwrap());
        assert_eq!(r.executed, 4);
        assert!(r.reward >= -4.0 && r.reward <= 0.0);
    }
}
