//! Steerability of the latent-noise MDP: does the noise an agent picks change whether an episode
//! succeeds, and by how much? Measured with the base policy alone, before any agent is trained.
//!
//! A steering agent (DSRL) can only improve on the diffusion policy where P(success | s, w)
//! depends on the noise w of the chunks it picks. Training curves mix that question with the
//! agent's own problems (critic error, entropy schedule, width), so this module asks it directly,
//! from saved simulator states and many base-policy continuations:
//!
//! - [`probe`]: states s taken along base rollouts (N(0, I) noise) at a few latent steps; from
//!   each, M candidate noises for the next `hold` chunks, each followed by K independent base
//!   continuations. Reported per state: the candidates' success rates, their between-candidate
//!   variance over the binomial variance of one estimate (about 1 when the noise changes nothing
//!   measurable; pooled over states it is a chi-square homogeneity statistic over its degrees of
//!   freedom), and the best candidate's success re-estimated on fresh continuations, which is
//!   what a perfect chooser among the M noises would get, free of the max's selection bias.
//! - [`base_rollouts`]: how base rollouts end ([`Outcome`]: held, lost after success, no grasp,
//!   knocked away, slipped, dropped after the lift, still holding at the horizon), and how far
//!   the commanded chunk moves with the noise at each latent step along them ([`ChunkSpread`]).
//! - [`phase_policies`]: how far the simplest noise policies get: for each [`Phase`] of the
//!   task, either a noise scale (w = s eps) or one constant vector, chosen greedily phase by
//!   phase on one set of starts, then measured beside the base on disjoint starts.
//!
//! Every rollout restores its start state and draws its noise from its own
//! [`SeedUse::Steerability`] stream, so the results are a pure function of the settings, the
//! same for any thread count. Written here rather than in Python because it runs hundreds of
//! thousands of physics steps; the command is `examples/steerability.rs`.

use equigym_envs::rng::{EpisodeRng, SeedUse};
use equigym_envs::tasks::common;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::latent::LatentEnv;

/// Height of the picked object's underside above the table that counts as lifted for the
/// phases and the failure breakdown (the tasks' success checks use their own thresholds).
pub const LIFTED_HEIGHT: f64 = 0.02;
/// An object moved this far in the plane before it was ever grasped was knocked away (m).
pub const KNOCKED_DISTANCE: f64 = 0.02;
/// Consecutive primitive steps with both fingers on the object that count as a grasp.
pub const GRASP_STEPS: usize = 3;

/// Where the task stands, from the picked object (the task's first object).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Phase {
    /// Not grasped yet: approaching.
    Approach,
    /// Not grasped, after a grasp: released, slipped or dropped.
    Released,
    /// Grasped, underside below [`LIFTED_HEIGHT`].
    Grasped,
    /// Grasped and lifted.
    Lifted,
}

impl Phase {
    pub const ALL: [Phase; 4] = [Phase::Approach, Phase::Released, Phase::Grasped, Phase::Lifted];
    pub fn index(self) -> usize {
        self as usize
    }
    pub fn name(self) -> &'static str {
        match self {
            Phase::Approach => "approach",
            Phase::Released => "released",
            Phase::Grasped => "grasped",
            Phase::Lifted => "lifted",
        }
    }
}

/// How an episode ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Succeeded, and still successful at the horizon.
    Held,
    /// Succeeded at some step, not at the horizon (counts as a success, as in DSRL).
    LostAfterSuccess,
    /// Never grasped; the object stayed where it was.
    NoGrasp,
    /// Never grasped; the object was pushed away.
    KnockedAway,
    /// Grasped, lost before it was lifted.
    Slipped,
    /// Grasped and lifted, then lost without success.
    DroppedAfterLift,
    /// Still holding the object at the horizon, without success.
    Holding,
}

impl Outcome {
    pub const ALL: [Outcome; 7] = [
        Outcome::Held,
        Outcome::LostAfterSuccess,
        Outcome::NoGrasp,
        Outcome::KnockedAway,
        Outcome::Slipped,
        Outcome::DroppedAfterLift,
        Outcome::Holding,
    ];
    pub fn is_success(self) -> bool {
        matches!(self, Outcome::Held | Outcome::LostAfterSuccess)
    }
    pub fn name(self) -> &'static str {
        match self {
            Outcome::Held => "success, held to the horizon",
            Outcome::LostAfterSuccess => "success, then lost",
            Outcome::NoGrasp => "no grasp",
            Outcome::KnockedAway => "knocked away",
            Outcome::Slipped => "grasp slipped before the lift",
            Outcome::DroppedAfterLift => "dropped after the lift",
            Outcome::Holding => "timeout, still holding",
        }
    }
}

/// What an episode has done so far (enough to classify its [`Outcome`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Tracker {
    start_xy: [f64; 2],
    grasp_run: usize,
    ever_grasped: bool,
    lifted_while_grasped: bool,
    knocked: bool,
    ever_success: bool,
    first_success: Option<usize>,
}

struct Reading {
    xy: [f64; 2],
    height: f64,
    grasped: bool,
}

fn read(env: &LatentEnv) -> Reading {
    let e = env.env();
    let object = &e.task().objects()[0];
    let pose = common::pose_of(e.scene(), object);
    let p = pose.translation.vector;
    let top = e.task().scene_spec().table.top;
    Reading { xy: [p.x, p.y], height: p.z - object.half_extents.z - top, grasped: common::grasped(e.scene(), object) }
}

/// The phase of the environment's current state, in the episode `tracker` has followed.
pub fn phase(env: &LatentEnv, tracker: &Tracker) -> Phase {
    let r = read(env);
    match (r.grasped, r.height >= LIFTED_HEIGHT) {
        (false, _) if tracker.ever_grasped => Phase::Released,
        (false, _) => Phase::Approach,
        (true, false) => Phase::Grasped,
        (true, true) => Phase::Lifted,
    }
}

impl Tracker {
    /// A tracker for the episode `env` has just been reset to.
    pub fn start(env: &LatentEnv) -> Self {
        Self {
            start_xy: read(env).xy,
            grasp_run: 0,
            ever_grasped: false,
            lifted_while_grasped: false,
            knocked: false,
            ever_success: false,
            first_success: None,
        }
    }

    /// Record one primitive step (the step count is the episode's primitive steps so far).
    fn record(&mut self, env: &LatentEnv, success: bool, step: usize) {
        let r = read(env);
        self.grasp_run = if r.grasped { self.grasp_run + 1 } else { 0 };
        if self.grasp_run >= GRASP_STEPS {
            self.ever_grasped = true;
            self.lifted_while_grasped |= r.height >= LIFTED_HEIGHT;
        }
        if !self.ever_grasped {
            let d = ((r.xy[0] - self.start_xy[0]).powi(2) + (r.xy[1] - self.start_xy[1]).powi(2)).sqrt();
            self.knocked |= d >= KNOCKED_DISTANCE;
        }
        if success && !self.ever_success {
            self.ever_success = true;
            self.first_success = Some(step);
        }
    }

    /// The outcome of an episode that ended (at the horizon) in `env`'s state.
    fn outcome(&self, env: &LatentEnv, success_now: bool) -> Outcome {
        let holding = read(env).grasped;
        match () {
            _ if self.ever_success && success_now => Outcome::Held,
            _ if self.ever_success => Outcome::LostAfterSuccess,
            _ if !self.ever_grasped && self.knocked => Outcome::KnockedAway,
            _ if !self.ever_grasped => Outcome::NoGrasp,
            _ if holding => Outcome::Holding,
            _ if self.lifted_while_grasped => Outcome::DroppedAfterLift,
            _ => Outcome::Slipped,
        }
    }
}

/// A random stream of the diagnostic, named by a path of integers (which start, which state,
/// which candidate, which continuation, ...).
fn stream(path: &[u64]) -> EpisodeRng {
    // splitmix64 over the path: distinct paths give unrelated ChaCha8 keys.
    let mut h: u64 = 0x9E37_79B9_7F4A_7C15;
    for &p in path {
        h ^= p.wrapping_add(0x9E37_79B9_7F4A_7C15).wrapping_add(h << 6).wrapping_add(h >> 2);
        let mut z = h;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        h = z ^ (z >> 31);
    }
    EpisodeRng::for_use(h, SeedUse::Steerability)
}

// Stream path heads, one per kind of draw.
const PREFIX: u64 = 1;
const CANDIDATE: u64 = 2;
const CONTINUATION: u64 = 3;
const HOLDOUT: u64 = 4;
const BASE: u64 = 5;
const SPREAD: u64 = 6;
const POOL: u64 = 7;
const POLICY: u64 = 8;

fn normals(rng: &mut EpisodeRng, scale: f64, out: &mut [f64]) {
    for v in out.iter_mut() {
        *v = scale * rng.normal();
    }
}

/// One saved point of an episode, to continue from.
#[derive(Clone, Debug)]
pub struct Start {
    state: Vec<u8>,
    tracker: Tracker,
    /// Primitive steps done.
    steps: usize,
    /// Latent steps done.
    pub latent_step: usize,
    pub phase: Phase,
    /// The observation at this point.
    pub observation: Vec<f64>,
}

impl Start {
    fn capture(env: &mut LatentEnv, tracker: &Tracker, latent_step: usize) -> Result<Self> {
        Ok(Self {
            observation: env.env_mut().observe().to_vec(),
            state: env.env().get_state()?,
            tracker: tracker.clone(),
            steps: env.env().elapsed_steps(),
            latent_step,
            phase: phase(env, tracker),
        })
    }
}

/// A finished rollout.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rollout {
    pub success: bool,
    /// `None` when the rollout stopped at its first success.
    pub outcome: Option<Outcome>,
    pub primitive_steps: usize,
    /// The episode's primitive step count at its first success.
    pub first_success: Option<usize>,
}

/// Run from `start` to the horizon (or to the first success with `stop_at_success`), the
/// noise of latent step k (counted from the episode start) drawn by `noise(k, phase, out)`.
fn rollout(
    env: &mut LatentEnv,
    start: &Start,
    stop_at_success: bool,
    noise: impl FnMut(usize, Phase, &mut [f64]),
) -> Result<Rollout> {
    rollout_with(env, start, stop_at_success, noise, |_, _, _| Ok(()))
}

/// [`rollout`], with `before_chunk(env, tracker, k)` called before the noise of every latent
/// step k is drawn (to measure the state the chunk starts in; it must not change the state).
fn rollout_with(
    env: &mut LatentEnv,
    start: &Start,
    stop_at_success: bool,
    mut noise: impl FnMut(usize, Phase, &mut [f64]),
    mut before_chunk: impl FnMut(&mut LatentEnv, &Tracker, usize) -> Result<()>,
) -> Result<Rollout> {
    env.env_mut().set_state(&start.state)?;
    let mut tracker = start.tracker.clone();
    let mut steps = start.steps;
    let mut k = start.latent_step;
    let mut w = vec![0.0; env.latent_dim()];
    loop {
        before_chunk(env, &tracker, k)?;
        noise(k, phase(env, &tracker), &mut w);
        let chunk = env.decode(&w)?;
        let mut ended = false;
        let mut success_now = false;
        for a in chunk.chunks_exact(equigym_envs::ACTION_DIM) {
            let r = env.env_mut().step(a)?;
            steps += 1;
            success_now = r.evaluation.success();
            tracker.record(env, success_now, steps);
            if r.truncated || r.terminated {
                ended = true;
                break;
            }
            if stop_at_success && success_now {
                return Ok(Rollout {
                    success: true,
                    outcome: None,
                    primitive_steps: steps - start.steps,
                    first_success: tracker.first_success,
                });
            }
        }
        k += 1;
        if ended {
            let outcome = tracker.outcome(env, success_now);
            return Ok(Rollout {
                success: outcome.is_success(),
                outcome: Some(outcome),
                primitive_steps: steps - start.steps,
                first_success: tracker.first_success,
            });
        }
    }
}

/// Reset to `seed` and capture the episode's first state.
fn episode_start(env: &mut LatentEnv, seed: u64) -> Result<Start> {
    env.reset(seed)?;
    let tracker = Tracker::start(env);
    Start::capture(env, &tracker, 0)
}

/// Run `jobs` in parallel, each on a worker's own environment (made by `make_env`); results
/// in job order.
fn par_jobs<J: Sync, T: Send>(
    jobs: &[J],
    make_env: &(dyn Fn() -> Result<LatentEnv> + Sync),
    run: impl Fn(&mut LatentEnv, &J) -> Result<T> + Sync,
) -> Result<Vec<T>> {
    jobs.par_iter()
        .map_init(make_env, |env, job| match env {
            Ok(env) => run(env, job),
            Err(e) => Err(e.clone()),
        })
        .collect()
}

// -- statistics -------------------------------------------------------------------------------

/// Wilson score interval (95 %) of `successes` out of `n`.
pub fn wilson(successes: usize, n: usize) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let z = 1.959_963_984_540_054_f64;
    let (k, n) = (successes as f64, n as f64);
    let p = k / n;
    let denom = 1.0 + z * z / n;
    let centre = (p + z * z / (2.0 * n)) / denom;
    let half = z * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt() / denom;
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

/// A success rate with its Wilson interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Rate {
    pub successes: usize,
    pub n: usize,
    pub rate: f64,
    pub low: f64,
    pub high: f64,
}

impl Rate {
    pub fn of(successes: usize, n: usize) -> Self {
        let (low, high) = wilson(successes, n);
        Self { successes, n, rate: if n == 0 { 0.0 } else { successes as f64 / n as f64 }, low, high }
    }
}

// -- probes -----------------------------------------------------------------------------------

/// Settings of [`probe`].
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ProbeConfig {
    /// Episode seeds `first_seed .. first_seed + starts`.
    pub first_seed: u64,
    pub starts: usize,
    /// Latent steps (from the episode start) at which a base rollout's state is probed; states
    /// after a success or past the horizon are skipped.
    pub at_latent_steps: Vec<usize>,
    /// Candidate noises per state (M).
    pub candidates: usize,
    /// Continuations per candidate (K), and for the best candidate's re-estimate.
    pub continuations: usize,
    /// Chunks the candidate noise covers (1: the next chunk only); base noise after that.
    pub hold: usize,
}

/// One probed state.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ProbedState {
    pub seed: u64,
    pub latent_step: usize,
    pub phase: Phase,
    /// Successes of each candidate out of `continuations`.
    pub candidate_successes: Vec<usize>,
    /// Mean success over all candidates' continuations (the base policy's P(success | s)).
    pub mean: f64,
    /// Between-candidate variance of the rates over the binomial variance of one estimate
    /// (`None` when every continuation succeeded or every one failed).
    pub variance_ratio: Option<f64>,
    /// The best candidate's success on fresh continuations.
    pub best_holdout: Rate,
    /// Successes of the caller's extra candidates ([`probe_with`]) out of `continuations`, in
    /// the order it gave them (not part of the statistics above).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub extra_successes: Vec<usize>,
    /// The observation at the state, as a policy or critic sees it.
    #[serde(skip)]
    pub observation: Vec<f64>,
    /// Every candidate's noise (the M random ones, then the extras), `hold x latent_dim` each.
    #[serde(skip)]
    pub candidates: Vec<Vec<f64>>,
    /// Every candidate's continuations, in the same order.
    #[serde(skip)]
    pub continuations: Vec<Vec<Rollout>>,
}

/// What [`probe`] found.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ProbeReport {
    pub config: ProbeConfig,
    pub states: Vec<ProbedState>,
    /// Pooled chi-square homogeneity statistic over its degrees of freedom (1 under "the noise
    /// changes nothing"), over the informative states, and its standard deviation under that
    /// hypothesis, sqrt(2 / df).
    pub pooled_ratio: Option<f64>,
    pub pooled_ratio_null_sd: Option<f64>,
    pub informative_states: usize,
    /// Mean over states of (best candidate's fresh success - state's mean), with its s.e.
    pub best_gain: Option<f64>,
    pub best_gain_se: Option<f64>,
    /// The same per phase: (phase, states, pooled ratio, mean gain).
    pub by_phase: Vec<PhaseProbe>,
    pub primitive_steps: usize,
}

impl ProbeReport {
    /// The standard deviation of P(success | s, w) across noises w that the probes imply once
    /// the binomial noise of each estimate is taken out: sqrt of the mean over informative
    /// states of (between-candidate variance - p (1 - p) / K), 0 when that is negative.
    pub fn implied_noise_sd(&self) -> Option<f64> {
        let k = self.config.continuations as f64;
        let excess: Vec<f64> = self
            .states
            .iter()
            .filter(|s| s.variance_ratio.is_some())
            .map(|s| {
                let m = s.candidate_successes.len() as f64;
                let rates: Vec<f64> = s.candidate_successes.iter().map(|&w| w as f64 / k).collect();
                let var = rates.iter().map(|r| (r - s.mean).powi(2)).sum::<f64>() / (m - 1.0);
                var - s.mean * (1.0 - s.mean) / k
            })
            .collect();
        (!excess.is_empty()).then(|| (excess.iter().sum::<f64>() / excess.len() as f64).max(0.0).sqrt())
    }
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PhaseProbe {
    pub phase: Phase,
    pub states: usize,
    pub informative_states: usize,
    pub pooled_ratio: Option<f64>,
    pub best_gain: Option<f64>,
    pub best_gain_se: Option<f64>,
}

/// `Some(x)` for a finite `x` (the reports' JSON has no NaN).
fn finite(x: f64) -> Option<f64> {
    x.is_finite().then_some(x)
}

type Pooled = (Option<f64>, Option<f64>, usize, Option<f64>, Option<f64>);

fn pooled(states: &[&ProbedState], m: usize) -> Pooled {
    let informative: Vec<f64> = states.iter().filter_map(|s| s.variance_ratio).collect();
    let df = (informative.len() * (m - 1)) as f64;
    let ratio = if df > 0.0 { informative.iter().sum::<f64>() * (m - 1) as f64 / df } else { f64::NAN };
    let gains: Vec<f64> = states.iter().map(|s| s.best_holdout.rate - s.mean).collect();
    let (g, se) = mean_se(&gains);
    let sd = if df > 0.0 { (2.0 / df).sqrt() } else { f64::NAN };
    (finite(ratio), finite(sd), informative.len(), finite(g), finite(se))
}

/// Mean and standard error.
pub fn mean_se(xs: &[f64]) -> (f64, f64) {
    let n = xs.len() as f64;
    if xs.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let m = xs.iter().sum::<f64>() / n;
    if xs.len() < 2 {
        return (m, f64::NAN);
    }
    let v = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    (m, (v / n).sqrt())
}

/// Extra candidate noises at a probed state, from (episode seed, latent step, observation): a
/// trained actor's picks, say. Each is `hold x latent_dim` long.
pub type ExtraCandidates<'a> = &'a (dyn Fn(u64, usize, &[f64]) -> Result<Vec<Vec<f64>>> + Sync);

/// Measure how much the next `hold` chunks' noise changes P(success) from states along base
/// rollouts (see the module documentation). `make_env` builds one latent environment per worker.
pub fn probe(config: &ProbeConfig, make_env: &(dyn Fn() -> Result<LatentEnv> + Sync)) -> Result<ProbeReport> {
    probe_with(config, make_env, &|_, _, _| Ok(Vec::new()))
}

/// [`probe`], with `extra` candidates at every state beside the M random ones, each followed by
/// K continuations of its own (streams after the random candidates', so the random candidates'
/// results are [`probe`]'s, bit for bit).
pub fn probe_with(
    config: &ProbeConfig,
    make_env: &(dyn Fn() -> Result<LatentEnv> + Sync),
    extra: ExtraCandidates,
) -> Result<ProbeReport> {
    let (m, kc, hold) = (config.candidates.max(2), config.continuations.max(1), config.hold.max(1));
    // 1. Base rollouts to the last probe step, saving the probed states.
    let starts = probe_starts(config, make_env)?;

    // 2. M candidates (and the extras) x K continuations from every state.
    let dim = make_env()?.latent_dim();
    let candidates = probe_candidates(&starts, m, dim * hold, extra)?;
    let candidate = |s: usize, c: usize| -> &[f64] { &candidates[s][c] };
    let continue_with = |env: &mut LatentEnv, s: usize, cand: &[f64], mut rng: EpisodeRng| -> Result<Rollout> {
        let k0 = starts[s].1.latent_step;
        rollout(env, &starts[s].1, true, |k, _, w| {
            let j = k - k0;
            if j < hold {
                w.copy_from_slice(&cand[j * dim..(j + 1) * dim]);
            } else {
                normals(&mut rng, 1.0, w);
            }
        })
    };
    let jobs: Vec<(usize, usize, usize)> = (0..starts.len())
        .flat_map(|s| (0..candidates[s].len()).flat_map(move |c| (0..kc).map(move |r| (s, c, r))))
        .collect();
    let runs = par_jobs(&jobs, make_env, |env, &(s, c, r)| {
        let (seed, st) = &starts[s];
        let rng = stream(&[CONTINUATION, *seed, st.latent_step as u64, c as u64, r as u64]);
        continue_with(env, s, candidate(s, c), rng)
    })?;
    let mut primitive_steps: usize = runs.iter().map(|r| r.primitive_steps).sum();
    let mut continuations: Vec<Vec<Vec<Rollout>>> =
        candidates.iter().map(|cs| vec![Vec::with_capacity(kc); cs.len()]).collect();
    for (&(s, c, _), r) in jobs.iter().zip(&runs) {
        continuations[s][c].push(*r);
    }
    let wins: Vec<Vec<usize>> =
        continuations.iter().map(|cs| cs.iter().map(|rs| rs.iter().filter(|r| r.success).count()).collect()).collect();

    // 3. The best candidate of each state on fresh continuations.
    let best: Vec<usize> = wins.iter().map(|w| (0..m).fold(0, |b, c| if w[c] > w[b] { c } else { b })).collect();
    let holdout_jobs: Vec<(usize, usize)> = (0..starts.len()).flat_map(|s| (0..kc).map(move |r| (s, r))).collect();
    let fresh = par_jobs(&holdout_jobs, make_env, |env, &(s, r)| {
        let (seed, st) = &starts[s];
        let rng = stream(&[HOLDOUT, *seed, st.latent_step as u64, r as u64]);
        continue_with(env, s, candidate(s, best[s]), rng)
    })?;
    primitive_steps += fresh.iter().map(|r| r.primitive_steps).sum::<usize>();
    let mut fresh_wins = vec![0usize; starts.len()];
    for (&(s, _), r) in holdout_jobs.iter().zip(&fresh) {
        fresh_wins[s] += r.success as usize;
    }

    let states: Vec<ProbedState> = starts
        .iter()
        .enumerate()
        .map(|(s, (seed, st))| ProbedState {
            seed: *seed,
            latent_step: st.latent_step,
            phase: st.phase,
            candidate_successes: wins[s][..m].to_vec(),
            mean: wins[s][..m].iter().sum::<usize>() as f64 / (m * kc) as f64,
            variance_ratio: variance_ratio(&wins[s][..m], kc),
            best_holdout: Rate::of(fresh_wins[s], kc),
            extra_successes: wins[s][m..].to_vec(),
            observation: st.observation.clone(),
            candidates: candidates[s].clone(),
            continuations: std::mem::take(&mut continuations[s]),
        })
        .collect();
    Ok(probe_report(config, states, m, primitive_steps))
}

/// The base rollouts of [`probe`]: each start's states at the probed latent steps (a start that
/// succeeds or ends earlier gives fewer).
fn probe_starts(config: &ProbeConfig, make_env: &(dyn Fn() -> Result<LatentEnv> + Sync)) -> Result<Vec<(u64, Start)>> {
    let last = config.at_latent_steps.iter().copied().max().unwrap_or(0);
    let seeds: Vec<u64> = (0..config.starts as u64).map(|i| config.first_seed + i).collect();
    let found: Vec<Vec<(u64, Start)>> = par_jobs(&seeds, make_env, |env, &seed| {
        let mut rng = stream(&[PREFIX, seed]);
        let mut tracker = episode_start(env, seed)?.tracker;
        let mut out = Vec::new();
        let mut w = vec![0.0; env.latent_dim()];
        for k in 0..=last {
            if config.at_latent_steps.contains(&k) {
                out.push((seed, Start::capture(env, &tracker, k)?));
            }
            normals(&mut rng, 1.0, &mut w);
            let chunk = env.decode(&w)?;
            for a in chunk.chunks_exact(equigym_envs::ACTION_DIM) {
                let r = env.env_mut().step(a)?;
                tracker.record(env, r.evaluation.success(), env.env().elapsed_steps());
                if r.truncated || r.evaluation.success() {
                    return Ok(out);
                }
            }
        }
        Ok(out)
    })?;
    Ok(found.into_iter().flatten().collect())
}

/// Every state's candidates: `m` random noises (each from its own stream), then `extra`'s, each
/// `len` long.
fn probe_candidates(
    starts: &[(u64, Start)],
    m: usize,
    len: usize,
    extra: ExtraCandidates,
) -> Result<Vec<Vec<Vec<f64>>>> {
    let extras: Vec<Vec<Vec<f64>>> =
        starts.iter().map(|(seed, st)| extra(*seed, st.latent_step, &st.observation)).collect::<Result<_>>()?;
    if let Some(got) = extras.iter().flatten().map(Vec::len).find(|&n| n != len) {
        return Err(
            equigym_envs::EnvError::WrongLength { what: "extra candidate noise".into(), expected: len, got }.into()
        );
    }
    Ok(starts
        .iter()
        .zip(extras)
        .map(|((seed, st), extra)| {
            let random = (0..m).map(|c| {
                let mut v = vec![0.0; len];
                normals(&mut stream(&[CANDIDATE, *seed, st.latent_step as u64, c as u64]), 1.0, &mut v);
                v
            });
            random.chain(extra).collect()
        })
        .collect())
}

/// Between-candidate variance of the success rates over the binomial variance at their mean
/// (`None` where the mean is 0 or 1).
fn variance_ratio(wins: &[usize], kc: usize) -> Option<f64> {
    let m = wins.len();
    let mean = wins.iter().sum::<usize>() as f64 / (m * kc) as f64;
    let var = wins.iter().map(|&w| (w as f64 / kc as f64 - mean).powi(2)).sum::<f64>() / (m - 1) as f64;
    let binomial = mean * (1.0 - mean) / kc as f64;
    (binomial > 0.0).then(|| var / binomial)
}

/// The pooled figures of [`probe`], over all states and per phase.
fn probe_report(config: &ProbeConfig, states: Vec<ProbedState>, m: usize, primitive_steps: usize) -> ProbeReport {
    let all: Vec<&ProbedState> = states.iter().collect();
    let (pooled_ratio, pooled_ratio_null_sd, informative_states, best_gain, best_gain_se) = pooled(&all, m);
    let by_phase = Phase::ALL
        .iter()
        .filter_map(|&p| {
            let these: Vec<&ProbedState> = states.iter().filter(|s| s.phase == p).collect();
            (!these.is_empty()).then(|| {
                let (r, _, inf, g, se) = pooled(&these, m);
                PhaseProbe {
                    phase: p,
                    states: these.len(),
                    informative_states: inf,
                    pooled_ratio: r,
                    best_gain: g,
                    best_gain_se: se,
                }
            })
        })
        .collect();
    ProbeReport {
        config: config.clone(),
        states,
        pooled_ratio,
        pooled_ratio_null_sd,
        informative_states,
        best_gain,
        best_gain_se,
        by_phase,
        primitive_steps,
    }
}

// -- base rollouts: failure breakdown and chunk spread ----------------------------------------

/// Settings of [`base_rollouts`].
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BaseConfig {
    pub first_seed: u64,
    pub starts: usize,
    /// Rollouts per start (independent noise).
    pub per_start: usize,
    /// Noises decoded at every latent step for the chunk spread, on the first rollout of the
    /// first `spread_starts` starts (0: no spread).
    pub spread_noises: usize,
    pub spread_starts: usize,
}

/// How much the commanded chunk moves with the noise at one latent step.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct ChunkSpread {
    pub latent_step: usize,
    pub phase: Phase,
    /// RMS distance of the commanded positions from their mean over the noises (mm).
    pub position_mm: f64,
    /// Standard deviation of the commanded gripper width over the noises (mm).
    pub width_mm: f64,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BaseReport {
    pub config: BaseConfig,
    pub success: Rate,
    /// Count of each [`Outcome`], in [`Outcome::ALL`]'s order.
    pub outcomes: Vec<(Outcome, usize)>,
    /// Successes per start (out of `per_start`).
    pub per_start_successes: Vec<usize>,
    /// Primitive step of the first success, over successful rollouts (mean).
    pub mean_first_success_step: Option<f64>,
    pub spread: Vec<ChunkSpread>,
    /// Mean spread per phase: (phase, latent steps, position mm, width mm).
    pub spread_by_phase: Vec<(Phase, usize, f64, f64)>,
}

fn chunk_spread(
    env: &mut LatentEnv,
    tracker: &Tracker,
    rng: &mut EpisodeRng,
    noises: usize,
    latent_step: usize,
) -> Result<ChunkSpread> {
    let dim = env.latent_dim();
    let ad = equigym_envs::ACTION_DIM;
    let mut chunks = Vec::with_capacity(noises);
    let mut w = vec![0.0; dim];
    for _ in 0..noises {
        normals(rng, 1.0, &mut w);
        chunks.push(env.decode(&w)?);
    }
    let n = noises as f64;
    let steps = dim / ad;
    let (mut pos, mut width) = (0.0, 0.0);
    for t in 0..steps {
        for d in 0..3 {
            let i = t * ad + d;
            let m = chunks.iter().map(|c| c[i]).sum::<f64>() / n;
            pos += chunks.iter().map(|c| (c[i] - m).powi(2)).sum::<f64>() / n;
        }
        let i = t * ad + ad - 1;
        let m = chunks.iter().map(|c| c[i]).sum::<f64>() / n;
        width += (chunks.iter().map(|c| (c[i] - m).powi(2)).sum::<f64>() / n).sqrt();
    }
    Ok(ChunkSpread {
        latent_step,
        phase: phase(env, tracker),
        position_mm: 1e3 * (pos / steps as f64).sqrt(),
        width_mm: 1e3 * width / steps as f64,
    })
}

/// Base rollouts to the horizon: how they end, and (on the first few) the chunk spread.
pub fn base_rollouts(config: &BaseConfig, make_env: &(dyn Fn() -> Result<LatentEnv> + Sync)) -> Result<BaseReport> {
    let jobs: Vec<(u64, usize)> = (0..config.starts as u64)
        .flat_map(|i| (0..config.per_start).map(move |r| (config.first_seed + i, r)))
        .collect();
    let results = par_jobs(&jobs, make_env, |env, &(seed, r)| {
        let start = episode_start(env, seed)?;
        let spread_here = r == 0 && ((seed - config.first_seed) as usize) < config.spread_starts;
        let mut rng = stream(&[BASE, seed, r as u64]);
        let mut spread_rng = stream(&[SPREAD, seed]);
        let mut spreads = Vec::new();
        // The spread is measured before each chunk, from the state the chunk starts in; the
        // rollout's own noise comes from its own stream, so measuring does not change it.
        let r = rollout_with(
            env,
            &start,
            false,
            |_, _, w| normals(&mut rng, 1.0, w),
            |env, tracker, k| {
                if spread_here && config.spread_noises > 1 {
                    spreads.push(chunk_spread(env, tracker, &mut spread_rng, config.spread_noises, k)?);
                }
                Ok(())
            },
        )?;
        let outcome = r.outcome.expect("a rollout run to the horizon has an outcome");
        Ok((outcome, r.first_success, spreads))
    })?;
    let mut per_start = vec![0usize; config.starts];
    let mut counts = vec![0usize; Outcome::ALL.len()];
    let mut firsts = Vec::new();
    let mut spread = Vec::new();
    for (&(seed, _), (outcome, first, s)) in jobs.iter().zip(results) {
        counts[Outcome::ALL.iter().position(|o| *o == outcome).unwrap_or(0)] += 1;
        per_start[(seed - config.first_seed) as usize] += outcome.is_success() as usize;
        if let Some(f) = first {
            firsts.push(f as f64);
        }
        spread.extend(s);
    }
    let successes: usize = per_start.iter().sum();
    let spread_by_phase = Phase::ALL
        .iter()
        .filter_map(|&p| {
            let these: Vec<&ChunkSpread> = spread.iter().filter(|s| s.phase == p).collect();
            let n = these.len() as f64;
            (!these.is_empty()).then(|| {
                (
                    p,
                    these.len(),
                    these.iter().map(|s| s.position_mm).sum::<f64>() / n,
                    these.iter().map(|s| s.width_mm).sum::<f64>() / n,
                )
            })
        })
        .collect();
    Ok(BaseReport {
        config: config.clone(),
        success: Rate::of(successes, jobs.len()),
        outcomes: Outcome::ALL.iter().copied().zip(counts).collect(),
        per_start_successes: per_start,
        mean_first_success_step: finite(mean_se(&firsts).0),
        spread,
        spread_by_phase,
    })
}

// -- simple noise policies per phase ----------------------------------------------------------

/// What a phase policy does in one phase.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Choice {
    /// Fresh noise s eps, eps ~ N(0, I) (s = 1: the base policy).
    Scale(f64),
    /// The same vector at every latent step of the phase (index into the candidate pool).
    Constant(usize),
}

impl std::fmt::Display for Choice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Choice::Scale(s) => write!(f, "N(0, {s}^2 I)"),
            Choice::Constant(k) => write!(f, "vector #{k}"),
        }
    }
}

/// One choice per [`Phase`].
pub type PhasePolicy = [Choice; 4];

/// Settings of [`phase_policies`].
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PolicySearchConfig {
    /// Starts the greedy search scores policies on.
    pub search_first_seed: u64,
    pub search_starts: usize,
    /// Disjoint starts the chosen policy and the base are measured on (paired).
    pub test_first_seed: u64,
    pub test_starts: usize,
    pub scales: Vec<f64>,
    /// Constant vectors in the pool (N(0, I) draws).
    pub constants: usize,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PolicyTrial {
    pub phase: Phase,
    pub choice: Choice,
    pub search: Rate,
}

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PolicySearchReport {
    pub config: PolicySearchConfig,
    pub trials: Vec<PolicyTrial>,
    pub chosen: PhasePolicy,
    pub chosen_search: Rate,
    pub base_test: Rate,
    pub chosen_test: Rate,
    /// Best narrow-noise base (one scale in every phase) on the test starts, with its scale.
    pub best_scale_test: (f64, Rate),
    /// Test starts where only the chosen policy / only the base succeeded (McNemar's counts).
    pub only_chosen: usize,
    pub only_base: usize,
}

fn run_policy(env: &mut LatentEnv, policy: &PhasePolicy, pool: &[Vec<f64>], seed: u64) -> Result<bool> {
    let start = episode_start(env, seed)?;
    let mut rng = stream(&[POLICY, seed]);
    let r = rollout(env, &start, true, |_, p, w| match policy[p.index()] {
        Choice::Scale(s) => normals(&mut rng, s, w),
        Choice::Constant(k) => w.copy_from_slice(&pool[k]),
    })?;
    Ok(r.success)
}

fn score(
    policies: &[PhasePolicy],
    pool: &[Vec<f64>],
    first_seed: u64,
    n: usize,
    make_env: &(dyn Fn() -> Result<LatentEnv> + Sync),
) -> Result<Vec<Vec<bool>>> {
    let jobs: Vec<(usize, u64)> =
        (0..policies.len()).flat_map(|p| (0..n as u64).map(move |i| (p, first_seed + i))).collect();
    let wins = par_jobs(&jobs, make_env, |env, &(p, seed)| run_policy(env, &policies[p], pool, seed))?;
    Ok(wins.chunks(n.max(1)).map(|c| c.to_vec()).collect())
}

fn rate(wins: &[bool]) -> Rate {
    Rate::of(wins.iter().filter(|w| **w).count(), wins.len())
}

/// Greedy search over per-phase noise choices (see the module documentation). Episodes of one
/// seed share their noise stream across policies, so comparisons are paired.
pub fn phase_policies(
    config: &PolicySearchConfig,
    make_env: &(dyn Fn() -> Result<LatentEnv> + Sync),
) -> Result<PolicySearchReport> {
    let dim = make_env()?.latent_dim();
    let pool: Vec<Vec<f64>> = (0..config.constants)
        .map(|k| {
            let mut v = vec![0.0; dim];
            normals(&mut stream(&[POOL, k as u64]), 1.0, &mut v);
            v
        })
        .collect();
    let options: Vec<Choice> =
        config.scales.iter().map(|&s| Choice::Scale(s)).chain((0..config.constants).map(Choice::Constant)).collect();
    let base: PhasePolicy = [Choice::Scale(1.0); 4];
    let (sf, sn) = (config.search_first_seed, config.search_starts);
    let mut chosen = base;
    let mut chosen_wins = score(&[base], &pool, sf, sn, make_env)?.remove(0);
    let mut trials = Vec::new();
    for phase in Phase::ALL {
        let candidates: Vec<PhasePolicy> = options
            .iter()
            .filter(|&&o| o != chosen[phase.index()])
            .map(|&o| {
                let mut p = chosen;
                p[phase.index()] = o;
                p
            })
            .collect();
        let scored = score(&candidates, &pool, sf, sn, make_env)?;
        let mut best: Option<(PhasePolicy, Vec<bool>)> = None;
        for (p, w) in candidates.iter().zip(scored) {
            trials.push(PolicyTrial { phase, choice: p[phase.index()], search: rate(&w) });
            let better = |b: &Vec<bool>| rate(&w).successes > rate(b).successes;
            if better(best.as_ref().map_or(&chosen_wins, |b| &b.1)) {
                best = Some((*p, w));
            }
        }
        if let Some((p, w)) = best {
            chosen = p;
            chosen_wins = w;
        }
    }
    // Test starts: the chosen policy, the base and every uniform scale, paired.
    let mut tested: Vec<PhasePolicy> = vec![chosen, base];
    tested.extend(config.scales.iter().filter(|&&s| s != 1.0).map(|&s| [Choice::Scale(s); 4]));
    let test = score(&tested, &pool, config.test_first_seed, config.test_starts, make_env)?;
    let (only_chosen, only_base) = test[0]
        .iter()
        .zip(&test[1])
        .fold((0, 0), |(a, b), (c, d)| (a + (*c && !*d) as usize, b + (*d && !*c) as usize));
    let mut best_scale = (1.0, rate(&test[1]));
    for (p, w) in tested.iter().zip(&test).skip(2) {
        if rate(w).successes > best_scale.1.successes {
            if let Choice::Scale(s) = p[0] {
                best_scale = (s, rate(w));
            }
        }
    }
    Ok(PolicySearchReport {
        config: config.clone(),
        trials,
        chosen,
        chosen_search: rate(&chosen_wins),
        base_test: rate(&test[1]),
        chosen_test: rate(&test[0]),
        best_scale_test: best_scale,
        only_chosen,
        only_base,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_matches_known_values() {
        // 50 of 100: 0.4038 .. 0.5962; 0 of 10: 0 .. 0.2775.
        let (l, h) = wilson(50, 100);
        assert!((l - 0.4038).abs() < 1e-4 && (h - 0.5962).abs() < 1e-4, "{l} {h}");
        let (l, h) = wilson(0, 10);
        assert!(l == 0.0 && (h - 0.2775).abs() < 1e-4, "{l} {h}");
    }

    #[test]
    fn streams_differ_by_path() {
        let a = stream(&[1, 2, 3]).next_u64();
        assert_ne!(a, stream(&[1, 3, 2]).next_u64());
        assert_ne!(a, stream(&[1, 2, 3, 0]).next_u64());
        assert_eq!(a, stream(&[1, 2, 3]).next_u64());
    }
}
