//! Speed of the agents' kernels and gradient steps (one thread):
//! `cargo run --release -p equigym-agents --example bench [-- --quick] [--kernels]`
//! (`--kernels`: the peak and gemm rows only; `--only METHOD [--width W] [--steps N]`: one
//! method's gradient steps/s).
//!
//! Prints, as Markdown rows: the core's measured f32 FMA peak, the gemm kernel's GFLOP/s on the
//! layer shapes of the cpu preset and of 3 x 256 at batch 256, and SAC gradient steps per
//! second of each method at the cpu preset and at 3 x 256 (synthetic Lift-sized batches).

use std::time::Instant;

use equigym_agents::models::{Arch, Method, Models};
use equigym_agents::nn::{gemm, Trans};
use equigym_agents::replay::{Batch, Replay};
use equigym_agents::rng::{Rng, Stream};
use equigym_agents::sac::{Sac, SacConfig};
use equigym_envs::TaskOptions;
use equigym_wrappers::{Group, TaskSymmetry};

/// CPU time of this thread (seconds; Linux's schedstat), so that other load on the machine
/// distorts the figures less than wall time would; wall time elsewhere.
struct Clock(Option<f64>, Instant);

fn thread_cpu() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    Some(s.split_whitespace().next()?.parse::<f64>().ok()? * 1e-9)
}

impl Clock {
    fn start() -> Self {
        Clock(thread_cpu(), Instant::now())
    }
    fn seconds(&self) -> f64 {
        match (self.0, thread_cpu()) {
            (Some(a), Some(b)) => b - a,
            _ => self.1.elapsed().as_secs_f64(),
        }
    }
}

/// Independent FMA chains per lane block (enough to cover latency x throughput).
const CHAINS: usize = 12;

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn fma_peak_loop(iters: usize) -> f32 {
    let mut acc = [[1.0f32; 8]; CHAINS];
    let (m, a) = ([0.999_999f32; 8], [1e-7f32; 8]);
    for _ in 0..iters {
        for c in acc.iter_mut() {
            for j in 0..8 {
                c[j] = c[j].mul_add(m[j], a[j]);
            }
        }
    }
    acc.iter().flatten().sum()
}

/// The same chains in 16-lane (AVX-512) registers (intrinsics: LLVM kept a 16-wide array
/// version of the loop above in memory).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn fma_peak_loop_512(iters: usize) -> f32 {
    use std::arch::x86_64::*;
    let mut acc = [_mm512_set1_ps(1.0); CHAINS];
    let (m, a) = (_mm512_set1_ps(0.999_999), _mm512_set1_ps(1e-7));
    for _ in 0..iters {
        for c in acc.iter_mut() {
            *c = _mm512_fmadd_ps(*c, m, a);
        }
    }
    acc.iter().map(|v| _mm512_reduce_add_ps(*v)).sum()
}

/// GFLOP/s of dependent-free FMAs on one core (2 flops each), in the widest registers the
/// kernels use on this CPU (AVX-512 where [`equigym_agents::nn::has_avx512`], else AVX2): the
/// peak the gemm copy that runs here can reach.
fn fma_peak() -> f64 {
    #[cfg(target_arch = "x86_64")]
    {
        if equigym_agents::nn::has_avx512() {
            let iters = 20_000_000;
            let t = Clock::start();
            let s = unsafe { fma_peak_loop_512(iters) };
            let dt = t.seconds();
            std::hint::black_box(s);
            return (iters * CHAINS * 16 * 2) as f64 / dt / 1e9;
        }
        if equigym_agents::nn::has_fast_fma() {
            let iters = 20_000_000;
            let t = Clock::start();
            let s = unsafe { fma_peak_loop(iters) };
            let dt = t.seconds();
            std::hint::black_box(s);
            return (iters * CHAINS * 8 * 2) as f64 / dt / 1e9;
        }
    }
    f64::NAN
}

fn gemm_gflops(m: usize, n: usize, k: usize, ta: Trans, reps: usize) -> f64 {
    let a: Vec<f32> = (0..m * k).map(|i| (i % 7) as f32 * 0.1).collect();
    let b: Vec<f32> = (0..k * n).map(|i| (i % 5) as f32 * 0.1).collect();
    let mut c = vec![0.0f32; m * n];
    gemm(m, n, k, &a, ta, &b, &mut c, false);
    // At least `reps` calls and a quarter of a second of CPU time (the clock's resolution).
    let t = Clock::start();
    let mut calls = 0;
    while calls < reps || t.seconds() < 0.25 {
        gemm(m, n, k, &a, ta, &b, &mut c, true);
        calls += 1;
    }
    std::hint::black_box(&c);
    (2 * m * n * k * calls) as f64 / t.seconds() / 1e9
}

fn grad_steps_per_s(method: Method, arch: Arch, steps: usize) -> (f64, usize) {
    let sym = TaskSymmetry::new("lift", &TaskOptions::default(), Group::cyclic(8).unwrap(), 4).unwrap();
    let models = Models::<f32>::new(method, &sym, arch, 0).unwrap();
    let fields = models.fields;
    let (od, ad) = (sym.observation.dim(), sym.chunk.dim());
    let mut sac = Sac::new(
        models,
        od,
        SacConfig { lr: 3e-4, gamma: 0.99, tau: 0.005, target_entropy: 0.0, ent_init: 0.2, prior: None },
    );
    let mut replay = Replay::new(od, ad, 10_000);
    let mut rng = Rng::new(0, Stream::Eval, 0);
    for _ in 0..2048 {
        let o: Vec<f32> = (0..od).map(|_| rng.normal() as f32).collect();
        let a: Vec<f32> = (0..ad).map(|_| (rng.uniform() * 2.0 - 1.0) as f32).collect();
        replay.push(&o, &a, -(rng.below(5) as f32), &o, false);
    }
    let mut batch = Batch::default();
    let (mut r1, mut r2) = (Rng::new(0, Stream::Replay, 0), Rng::new(0, Stream::Train, 0));
    replay.sample(256, &mut r1, &mut batch);
    sac.train_step(&batch, &mut r2);
    let t = Clock::start();
    for _ in 0..steps {
        replay.sample(256, &mut r1, &mut batch);
        sac.train_step(&batch, &mut r2);
    }
    (steps as f64 / t.seconds(), fields)
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    // `--only dsrl|equi|approx [--width W] [--steps N]`: gradient steps of one method only (for
    // profiling, and for benches/agents.py, which alternates it with the SB3 measurement).
    let arg = |name: &str| std::env::args().skip_while(|a| a != name).nth(1);
    if let Some(m) = arg("--only") {
        let method = Method::parse(&m).expect("--only dsrl|equi|approx");
        let width = arg("--width").map_or(64, |w| w.parse().expect("--width N"));
        let steps = arg("--steps").map_or(if quick { 50 } else { 300 }, |w| w.parse().expect("--steps N"));
        let (sps, fields) = grad_steps_per_s(method, Arch { width, layers: 3 }, steps);
        println!("{m} 3x{width} ({fields} fields): {sps:.1} gradient steps/s");
        return;
    }
    let reps = if quick { 20 } else { 200 };
    println!("| measure | value |\n|---|---:|");
    println!("| f32 FMA peak, one core (GFLOP/s) | {:.1} |", fma_peak());
    for &(m, n, k, ta, what) in &[
        (256, 64, 64, Trans::N, "256x64 . 64x64 (cpu MLP hidden)"),
        (256, 192, 192, Trans::N, "256x192 . 192x192 (cpu Equi hidden, dense)"),
        (256, 256, 256, Trans::N, "256x256 . 256x256 (3x256 hidden)"),
        (192, 192, 256, Trans::T, "X^T dY 192x256 . 256x192 (weight gradient)"),
    ] {
        println!("| gemm {what} (GFLOP/s) | {:.1} |", gemm_gflops(m, n, k, ta, reps));
    }
    if std::env::args().any(|a| a == "--kernels") {
        return;
    }
    let steps = if quick { 20 } else { 200 };
    for (arch, name) in
        [(Arch { width: 64, layers: 3 }, "cpu preset (3x64)"), (Arch { width: 256, layers: 3 }, "3x256")]
    {
        for method in [Method::Dsrl, Method::Equi, Method::Approx] {
            let (sps, fields) = grad_steps_per_s(method, arch, steps);
            let f = if fields > 0 { format!(", {fields} fields") } else { String::new() };
            println!("| {} {name}{f}: gradient steps/s (batch 256) | {sps:.1} |", method.name());
        }
    }
}
