//! Measuring how much a task breaks the rotational symmetry.
//!
//! Two probes, both on states visited by the task's scripted expert:
//!
//! - **Transition invariance**: for sampled states s and the expert's action a, compare
//!   step(g s, g a) with g step(s, a): the observation error, the error of object and hand
//!   positions (metres), the dense-reward and success mismatch. Element 0 (the identity, built
//!   with the same state transform) is the floor of the measurement.
//! - **Rotated demonstrations**: replay each successful expert demonstration open loop after
//!   rotating its initial state and all its actions by g, and count successes.
//!
//! On an exactly invariant MDP both probes give zero error and the same success for every g.
//! The robot base does not rotate, so the arm's reach and joint limits (and the joint-space
//! path of the controller) make the errors grow with the rotation.

use equigym_envs::experts::{make_expert, ExpertOptions};
use equigym_envs::math::from_pose;
use equigym_envs::rng::{EpisodeRng, SeedUse};
use equigym_envs::{Action, Controller, Env, EnvError, EnvOptions, RewardKind};
use nalgebra::{Point3, Vector3};
use serde::Serialize;

use crate::error::Result;
use crate::group::{Group, PlanarRotation};
use crate::symmetry::{transform_state, TaskSymmetry, ROTATION_CENTRE};

/// What to measure.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(into = "ConfigRecord")]
pub struct BreakingConfig {
    pub task: String,
    /// The environment's options (reset variant, joint limits, controller, ...; the Python
    /// environments' keyword arguments). The reward is always the dense one.
    pub env: EnvOptions,
    /// Order N of the cyclic group whose elements are probed.
    pub group_order: usize,
    /// Expert episodes (seeds `seed .. seed + episodes`): demonstrations and sampled states.
    pub episodes: usize,
    /// States sampled per episode for the transition probe.
    pub states_per_episode: usize,
    /// Control steps per transition probe (the expert's recorded actions).
    pub probe_steps: usize,
    /// Extra control steps a replayed demonstration may take (holding its last action).
    pub replay_slack: usize,
    pub seed: u64,
}

impl BreakingConfig {
    pub fn new(task: &str) -> Self {
        Self {
            task: task.into(),
            env: EnvOptions::default(),
            group_order: 8,
            episodes: 20,
            states_per_episode: 4,
            probe_steps: 1,
            replay_slack: 30,
            seed: 0,
        }
    }
}

/// A configuration as the report writes it: the committed reports' fields, the settings that
/// the symmetry study varies resolved from the options, the other options only where set.
#[derive(Serialize)]
struct ConfigRecord {
    task: String,
    variant: Option<String>,
    joint_limits: bool,
    cartesian_control: bool,
    group_order: usize,
    episodes: usize,
    states_per_episode: usize,
    probe_steps: usize,
    replay_slack: usize,
    seed: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    env: Option<EnvOptions>,
}

impl From<BreakingConfig> for ConfigRecord {
    fn from(c: BreakingConfig) -> Self {
        let rest = EnvOptions { joint_limits: None, controller: None, variant: None, ..c.env.clone() };
        Self {
            variant: c.env.variant.clone(),
            joint_limits: c.env.joint_limits_on(),
            cartesian_control: c.env.arm_controller() == Controller::Cartesian,
            env: (rest != EnvOptions::default()).then_some(rest),
            task: c.task,
            group_order: c.group_order,
            episodes: c.episodes,
            states_per_episode: c.states_per_episode,
            probe_steps: c.probe_steps,
            replay_slack: c.replay_slack,
            seed: c.seed,
        }
    }
}

/// Transition-invariance statistics for one group element.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct InvarianceRow {
    pub element: usize,
    pub angle_deg: f64,
    pub samples: usize,
    /// || o(step(g s, g a)) - g o(step(s, a)) ||_2, mean and max.
    pub observation_error_mean: f64,
    pub observation_error_max: f64,
    /// Largest object position error (m), mean over samples and max.
    pub object_error_mean: f64,
    pub object_error_max: f64,
    /// TCP position error (m), mean.
    pub hand_error_mean: f64,
    /// | r_dense(g s') - r_dense(s') |, mean.
    pub reward_error_mean: f64,
    /// Fraction of samples whose success flags differ.
    pub success_mismatch: f64,
    /// Fraction of rotated states whose hand the arm cannot reach within 1 mm.
    pub unreachable: f64,
}

/// Open-loop replay of rotated demonstrations for one group element.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ReplayRow {
    pub element: usize,
    pub angle_deg: f64,
    pub demos: usize,
    pub successes: usize,
}

impl ReplayRow {
    pub fn success_rate(&self) -> f64 {
        if self.demos == 0 {
            0.0
        } else {
            self.successes as f64 / self.demos as f64
        }
    }
}

/// Everything one measurement produced.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct BreakingReport {
    pub config: BreakingConfig,
    pub expert_episodes: usize,
    pub expert_successes: usize,
    pub invariance: Vec<InvarianceRow>,
    pub replay: Vec<ReplayRow>,
}

impl BreakingReport {
    /// Mean over the non-identity elements of a row statistic.
    pub fn mean_over_rotations(&self, stat: impl Fn(&InvarianceRow) -> f64) -> f64 {
        let rows: Vec<_> = self.invariance.iter().filter(|r| r.element != 0).collect();
        rows.iter().map(|r| stat(r)).sum::<f64>() / rows.len().max(1) as f64
    }
    /// Mean replay success over the non-identity elements.
    pub fn rotated_replay_success(&self) -> f64 {
        let rows: Vec<_> = self.replay.iter().filter(|r| r.element != 0).collect();
        rows.iter().map(|r| r.success_rate()).sum::<f64>() / rows.len().max(1) as f64
    }
}

struct Demo {
    seed: u64,
    actions: Vec<Action>,
    states: Vec<Vec<u8>>,
    success: bool,
}

/// What a probe compares after stepping.
struct Outcome {
    obs: Vec<f64>,
    objects: Vec<Vector3<f64>>,
    hand: Vector3<f64>,
    reward: f64,
    success: bool,
}

fn outcome(env: &mut Env, reward: f64, success: bool) -> Outcome {
    let obs = env.observe().to_vec();
    let objects = env
        .task()
        .objects()
        .iter()
        .map(|o| from_pose(env.scene().world.bodies[o.body].position()).translation.vector)
        .collect();
    let hand = env.scene().tcp_pose().translation.vector;
    Outcome { obs, objects, hand, reward, success }
}

fn rotate_point(g: &PlanarRotation, p: &Vector3<f64>) -> Vector3<f64> {
    (g.isometry(ROTATION_CENTRE) * Point3::from(*p)).coords
}

/// Run both probes.
pub fn measure(config: &BreakingConfig) -> Result<BreakingReport> {
    if config.episodes == 0 || config.probe_steps == 0 {
        return Err(EnvError::InvalidConfig("episodes and probe_steps must be positive".into()).into());
    }
    let group = Group::cyclic(config.group_order)?;
    let env_options = EnvOptions { reward: RewardKind::Dense, ..config.env.clone() };
    let env_config = env_options.into_config(&config.task)?;
    let mut env = Env::new(env_config)?;
    let sym = TaskSymmetry::for_env(&env, group, 1)?;
    let elements = group.elements()?;

    let demos = record_demos(&mut env, config)?;
    let invariance = invariance_rows(&mut env, &sym, &elements, &demos, config)?;
    let replay = replay_rows(&mut env, &sym, &elements, &demos, config)?;
    Ok(BreakingReport {
        config: config.clone(),
        expert_episodes: demos.len(),
        expert_successes: demos.iter().filter(|d| d.success).count(),
        invariance,
        replay,
    })
}

/// Expert demonstrations from seeds `config.seed ..`, with every visited state.
fn record_demos(env: &mut Env, config: &BreakingConfig) -> Result<Vec<Demo>> {
    let mut demos = Vec::new();
    for k in 0..config.episodes {
        let seed = config.seed + k as u64;
        let mut expert = make_expert(&config.task, ExpertOptions::default())?;
        env.reset(seed)?;
        expert.reset(env, seed);
        let mut demo = Demo { seed, actions: Vec::new(), states: Vec::new(), success: false };
        for _ in 0..env.horizon() {
            demo.states.push(env.get_state()?);
            let action = expert.act(env);
            demo.actions.push(action);
            if env.step(&action)?.evaluation.success() {
                demo.success = true;
                break;
            }
        }
        demos.push(demo);
    }
    Ok(demos)
}

/// Transition invariance on sampled (state, action sequence) pairs of the demonstrations.
fn invariance_rows(
    env: &mut Env,
    sym: &TaskSymmetry,
    elements: &[PlanarRotation],
    demos: &[Demo],
    config: &BreakingConfig,
) -> Result<Vec<InvarianceRow>> {
    let mut rng = EpisodeRng::for_use(config.seed, SeedUse::SymmetryProbe);
    let mut sums = vec![[0.0f64; 9]; elements.len()];
    let mut counts = vec![0usize; elements.len()];
    for demo in demos {
        let usable = demo.actions.len().saturating_sub(config.probe_steps - 1);
        if usable == 0 {
            continue;
        }
        for _ in 0..config.states_per_episode {
            let t = (rng.uniform(0.0, usable as f64) as usize).min(usable - 1);
            let actions = &demo.actions[t..t + config.probe_steps];
            env.set_state(&demo.states[t])?;
            let mut last = None;
            for a in actions {
                last = Some(env.step(a)?);
            }
            let last = last.expect("probe_steps > 0");
            let reference = outcome(env, last.reward, last.evaluation.success());
            for (e, g) in elements.iter().enumerate() {
                env.set_state(&demo.states[t])?;
                let fit = transform_state(env, g)?;
                let mut last = None;
                for a in actions {
                    let mut ga = *a;
                    sym.act_action(g, &mut ga)?;
                    last = Some(env.step(&ga)?);
                }
                let last = last.expect("probe_steps > 0");
                let rotated = outcome(env, last.reward, last.evaluation.success());
                let mut expected = reference.obs.clone();
                sym.act_observation(g, &mut expected)?;
                let obs_err = rotated.obs.iter().zip(&expected).map(|(a, b)| (a - b).powi(2)).sum::<f64>().sqrt();
                let obj_err = rotated
                    .objects
                    .iter()
                    .zip(&reference.objects)
                    .map(|(p, q)| (p - rotate_point(g, q)).norm())
                    .fold(0.0, f64::max);
                let hand_err = (rotated.hand - rotate_point(g, &reference.hand)).norm();
                let s = &mut sums[e];
                s[0] += obs_err;
                s[1] = s[1].max(obs_err);
                s[2] += obj_err;
                s[3] = s[3].max(obj_err);
                s[4] += hand_err;
                s[5] += (rotated.reward - reference.reward).abs();
                s[6] += (rotated.success != reference.success) as u8 as f64;
                s[7] += (fit.position_error > 1e-3) as u8 as f64;
                counts[e] += 1;
            }
        }
    }
    Ok(elements
        .iter()
        .enumerate()
        .map(|(e, g)| {
            let n = counts[e].max(1) as f64;
            let s = &sums[e];
            InvarianceRow {
                element: e,
                angle_deg: g.angle().to_degrees(),
                samples: counts[e],
                observation_error_mean: s[0] / n,
                observation_error_max: s[1],
                object_error_mean: s[2] / n,
                object_error_max: s[3],
                hand_error_mean: s[4] / n,
                reward_error_mean: s[5] / n,
                success_mismatch: s[6] / n,
                unreachable: s[7] / n,
            }
        })
        .collect())
}

/// Rotated open-loop replay of the successful demonstrations.
fn replay_rows(
    env: &mut Env,
    sym: &TaskSymmetry,
    elements: &[PlanarRotation],
    demos: &[Demo],
    config: &BreakingConfig,
) -> Result<Vec<ReplayRow>> {
    let mut replay: Vec<ReplayRow> = elements
        .iter()
        .enumerate()
        .map(|(e, g)| ReplayRow { element: e, angle_deg: g.angle().to_degrees(), demos: 0, successes: 0 })
        .collect();
    for demo in demos.iter().filter(|d| d.success) {
        for (e, g) in elements.iter().enumerate() {
            env.reset(demo.seed)?;
            transform_state(env, g)?;
            let last = *demo.actions.last().expect("a successful demo has actions");
            let budget = (demo.actions.len() + config.replay_slack).min(env.horizon());
            let mut success = false;
            for t in 0..budget {
                let mut ga = *demo.actions.get(t).unwrap_or(&last);
                sym.act_action(g, &mut ga)?;
                if env.step(&ga)?.evaluation.success() {
                    success = true;
                    break;
                }
            }
            replay[e].demos += 1;
            replay[e].successes += success as usize;
        }
    }
    Ok(replay)
}
