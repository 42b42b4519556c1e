//! The diffusion-policy runtime: DDIM arithmetic on a hand-made policy, and file errors.

use std::collections::HashMap;

use equigym_envs::{Env, EnvConfig};
use equigym_wrappers::edp::{Kernel, Precision};
use equigym_wrappers::latent::{latent_batch, LatentEnv};
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
    let layer = (vec![0.0; CHUNK * (OBS + CHUNK + EMB)], vec![eps; CHUNK], CHUNK, OBS + CHUNK + EMB);
    policy_bytes(vec![layer], format)
}

/// A two-layer ReLU policy with fixed pseudo-random weights (every row's arithmetic matters).
fn random_policy() -> Vec<u8> {
    let (inp, hidden) = (OBS + CHUNK + EMB, 37);
    let w = |n: usize, salt: f64| (0..n).map(|i| 0.3 * libm::sin((i as f64) * 0.7548 + salt)).collect::<Vec<f64>>();
    policy_bytes(
        vec![
            (w(hidden * inp, 0.1), w(hidden, 0.2), hidden, inp),
            (w(CHUNK * hidden, 0.3), w(CHUNK, 0.4), CHUNK, hidden),
        ],
        "equigym-edp-1",
    )
}

/// An exported policy file from (weight, bias, n_out, n_in) layers.
fn policy_bytes(layers: Vec<(Vec<f64>, Vec<f64>, usize, usize)>, format: &str) -> Vec<u8> {
    let abar: Vec<f64> = (0..T).map(|t| 1.0 - 0.09 * t as f64).collect();
    let emb: Vec<f64> = (0..T * EMB).map(|i| libm::cos(i as f64 * 0.3)).collect();
    let mut tensors: Vec<(String, Vec<u8>, Vec<usize>)> = vec![
        ("alphas_cumprod".into(), bytes_f64(&abar), vec![T]),
        ("time_embedding".into(), bytes_f64(&emb), vec![T, EMB]),
        ("obs_offset".into(), bytes_f64(&[0.0; OBS]), vec![OBS]),
        ("obs_scale".into(), bytes_f64(&[1.0; OBS]), vec![OBS]),
        ("action_offset".into(), bytes_f64(&[0.5; CHUNK]), vec![CHUNK]),
        ("action_scale".into(), bytes_f64(&[2.0; CHUNK]), vec![CHUNK]),
    ];
    let num_layers = layers.len().to_string();
    for (k, (w, b, n_out, n_in)) in layers.into_iter().enumerate() {
        tensors.push((format!("layer{k}.weight"), bytes_f64(&w), vec![n_out, n_in]));
        tensors.push((format!("layer{k}.bias"), bytes_f64(&b), vec![n_out]));
    }
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    let views: Vec<(String, TensorView)> =
        tensors.iter().map(|(n, d, s)| (n.clone(), TensorView::new(Dtype::F64, s.clone(), d).unwrap())).collect();
    let meta: HashMap<String, String> = [
        ("format", format),
        ("task", "lift"),
        ("chunk_len", "4"),
        ("num_layers", num_layers.as_str()),
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
    let mut p = DiffusionPolicy::from_bytes(&constant_policy(eps, "equigym-edp-1"), "test").unwrap();
    assert_eq!(p.ddim_timesteps(5), vec![8, 6, 4, 2, 0]);
    let w = vec![0.7; CHUNK];
    // By hand: x <- sqrt(ab') x0 + sqrt(1 - ab') eps, x0 = (x - sqrt(1 - ab) eps) / sqrt(ab).
    let abar = |t: i64| if t < 0 { 1.0 } else { 1.0 - 0.09 * t as f64 };
    let mut x = 0.7;
    for t in [8i64, 6, 4, 2, 0] {
        let x0 = (x - (1.0 - abar(t)).sqrt() * eps) / abar(t).sqrt();
        x = abar(t - 2).sqrt() * x0 + (1.0 - abar(t - 2)).sqrt() * eps;
    }
    // float64 network: exact to rounding; float32 (the default): the predicted noise is 0.3
    // rounded to float32 (relative 4e-8), amplified by at most ~10 over the five steps.
    for (precision, tol) in [(Precision::F64, 1e-12), (Precision::F32, 1e-6)] {
        p.precision = precision;
        let mut out = vec![0.0; CHUNK];
        p.sample(&[0.0; OBS], &w, 5, &mut out).unwrap();
        for v in &out {
            assert!((v - (x * 2.0 + 0.5)).abs() < tol, "{precision:?}: {v} vs {}", x * 2.0 + 0.5);
        }
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
    // A policy whose chunks depend on the observation: each row must be denoised from its own
    // environment's observation (a constant policy would hide rows swapped or shared).
    let policy = std::sync::Arc::new(DiffusionPolicy::from_bytes(&random_policy(), "t").unwrap());
    let make = || LatentEnv::new(Env::new(EnvConfig::new("lift")).unwrap(), policy.clone(), 1.5, 5).unwrap();
    let mut batch = latent_batch((0..3).map(|_| make()).collect(), 2, equigym_envs::AutoresetMode::Disabled).unwrap();
    let mut single: Vec<LatentEnv> = (0..3).map(|_| make()).collect();
    batch.reset(&[0, 1, 2]).unwrap();
    for (k, s) in single.iter_mut().enumerate() {
        s.reset(k as u64).unwrap();
    }
    // The same latent for every row: only the observations tell the rows apart.
    let w: Vec<f64> = (0..3 * CHUNK).map(|i| libm::sin((i % CHUNK) as f64 * 0.37)).collect();
    let decoded: Vec<Vec<f64>> = single.iter_mut().map(|s| s.decode(&w[..CHUNK]).unwrap()).collect();
    assert!(decoded[0] != decoded[1] && decoded[1] != decoded[2], "the policy must depend on the observation");
    batch.step(&w).unwrap();
    for (k, b) in batch.envs().enumerate() {
        assert_eq!(b.last_chunk(), &decoded[k][..], "env {k} ran another row's chunk");
    }
    for (k, s) in single.iter_mut().enumerate() {
        let r = s.step(&w[k * CHUNK..(k + 1) * CHUNK]).unwrap();
        let b = batch.last_step(k).unwrap();
        assert_eq!((r.reward, r.terminated, r.truncated, r.success), (b.reward, b.terminated, b.truncated, b.success));
        let member = batch.env(k).unwrap();
        assert_eq!(s.env().get_state().unwrap(), member.env().get_state().unwrap());
        assert_eq!(member.last_executed(), 4);
        assert_eq!(r.executed, 4);
        assert!(r.reward >= -4.0 && r.reward <= 0.0);
    }
    // A masked step decodes only the stepped rows, each as it decodes alone; the others keep
    // their state.
    let held = batch.env(1).unwrap().env().get_state().unwrap();
    let w2: Vec<f64> = (0..3 * CHUNK).map(|i| libm::cos(i as f64 * 0.11)).collect();
    batch.step_masked(&w2, &[true, false, true]).unwrap();
    for k in [0, 2] {
        let expect = single[k].decode(&w2[k * CHUNK..(k + 1) * CHUNK]).unwrap();
        assert_eq!(batch.env(k).unwrap().last_chunk(), &expect[..], "env {k}'s masked-step chunk");
        single[k].step(&w2[k * CHUNK..(k + 1) * CHUNK]).unwrap();
        assert_eq!(single[k].env().get_state().unwrap(), batch.env(k).unwrap().env().get_state().unwrap());
    }
    assert_eq!(batch.env(1).unwrap().env().get_state().unwrap(), held, "the masked env did not move");
}

#[test]
fn latent_vector_env_equals_single_envs_for_any_thread_count() {
    use equigym_envs::AutoresetMode;
    use equigym_wrappers::latent::latent_batch;
    let policy = std::sync::Arc::new(DiffusionPolicy::from_bytes(&random_policy(), "t").unwrap());
    let config = || {
        let mut c = EnvConfig::new("lift");
        c.horizon = Some(12); // three latent steps per episode, so auto-resets happen
        c
    };
    let make = || LatentEnv::new(Env::new(config()).unwrap(), policy.clone(), 1.5, 5).unwrap();
    let n = 7; // not a multiple of the kernel's four-row block
    let seeds: Vec<u64> = (0..n as u64).map(|k| 40 + k).collect();
    let latents =
        |t: usize| -> Vec<f64> { (0..n * CHUNK).map(|i| 2.0 * libm::sin((i * 31 + t * 7) as f64 * 0.113)).collect() };
    // Reference: seven single environments; one episode of three latent steps each.
    let mut singles: Vec<LatentEnv> = (0..n).map(|_| make()).collect();
    let mut want = Vec::new();
    for (k, e) in singles.iter_mut().enumerate() {
        e.reset(seeds[k]).unwrap();
    }
    for t in 0..3 {
        let w = latents(t);
        want.push(
            singles
                .iter_mut()
                .enumerate()
                .map(|(k, e)| (e.step(&w[k * CHUNK..(k + 1) * CHUNK]).unwrap(), e.env_mut().observe().to_vec()))
                .collect::<Vec<_>>(),
        );
    }
    let final_states: Vec<Vec<u8>> = singles.iter().map(|e| e.env().get_state().unwrap()).collect();
    for threads in [1, 2, 3] {
        let mut batch = latent_batch((0..n).map(|_| make()).collect(), threads, AutoresetMode::NextStep).unwrap();
        batch.reset(&seeds).unwrap();
        for (t, want_t) in want.iter().enumerate() {
            batch.step(&latents(t)).unwrap();
            for (k, (w, obs)) in want_t.iter().enumerate() {
                let got = batch.last_step(k).unwrap();
                let want = (w.reward, w.terminated, w.truncated, w.success);
                assert_eq!(
                    (got.reward, got.terminated, got.truncated, got.success),
                    want,
                    "threads {threads}, step {t}, env {k}"
                );
                assert_eq!(batch.obs(k).unwrap(), &obs[..], "threads {threads}, step {t}, env {k}");
            }
        }
        for (k, want) in final_states.iter().enumerate().take(n) {
            assert_eq!(&batch.env(k).unwrap().env().get_state().unwrap(), want, "threads {threads}, env {k}");
            assert!(batch.last_step(k).unwrap().truncated);
        }
        // The next step auto-resets every environment from its seed stream.
        batch.step(&latents(9)).unwrap();
        assert!((0..n).all(|k| batch.was_reset(k).unwrap()));
    }
}

/// The shipped C8 policies' hidden layers (regular fields to regular fields) get Fourier copies,
/// and the Fourier kernel computes the dense kernel's map: in float64 the two agree to the
/// file's float32 rounding of the circulant blocks, and in float32 the Fourier kernel is as
/// close to the float64 chunks as the dense one is; every row's bits are independent of the
/// batch. A plain policy has no copy.
#[test]
fn the_fourier_kernel_is_the_dense_map() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/edp");
    let max_diff = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    for task in ["lift", "stack", "square"] {
        let mut p = DiffusionPolicy::load(format!("{dir}/{task}.safetensors")).unwrap();
        assert_eq!(p.fourier_layers(), vec![1, 2], "{task}");
        let (od, ad, b) = (p.obs_dim(), p.action_dim(), 24);
        let obs: Vec<f64> = (0..b * od).map(|i| 0.1 * libm::sin(i as f64 * 0.37)).collect();
        let latent: Vec<f64> = (0..b * ad).map(|i| 1.3 * libm::cos(i as f64 * 0.61)).collect();
        let mut chunks = |precision, kernel| {
            (p.precision, p.kernel) = (precision, kernel);
            let mut out = vec![0.0; b * ad];
            p.sample(&obs, &latent, p.default_ddim_steps, &mut out).unwrap();
            let mut one = vec![0.0; ad];
            p.sample(&obs[5 * od..6 * od], &latent[5 * ad..6 * ad], p.default_ddim_steps, &mut one).unwrap();
            assert_eq!(one, out[5 * ad..6 * ad], "{task} {precision:?} {kernel:?}: a row's bits depend on its batch");
            out
        };
        let reference = chunks(Precision::F64, Kernel::Dense);
        let fourier64 = chunks(Precision::F64, Kernel::Fourier);
        let (dense32, fourier32) = (chunks(Precision::F32, Kernel::Dense), chunks(Precision::F32, Kernel::Fourier));
        let (d64, e_dense, e_fourier) =
            (max_diff(&reference, &fourier64), max_diff(&reference, &dense32), max_diff(&reference, &fourier32));
        assert!(d64 < 1e-5, "{task}: the float64 kernels differ by {d64}");
        assert!(e_fourier < 2.0 * e_dense + 1e-5, "{task}: float32 errors {e_fourier} (Fourier) against {e_dense}");
        assert!(dense32 != fourier32, "{task}: the float32 kernels should round differently");
    }
    let plain = DiffusionPolicy::from_bytes(&random_policy(), "random").unwrap();
    assert!(plain.fourier_layers().is_empty());
    assert_eq!("fourier".parse::<Kernel>().unwrap(), Kernel::Fourier);
    assert!(matches!("fft".parse::<Kernel>(), Err(Error::Env(_))));
}
