//! Arm controllers: an absolute TCP target at 20 Hz becomes joint servo targets for each
//! physics substep, and nothing else (the joints' servos, torque caps and contacts decide where
//! the arm actually goes).
//!
//! Two implementations of [`ArmController`]:
//! - [`JointSpace`] (default): the target goes through a joint-limited IK (warm-started, with
//!   restarts from a seed bank when it is stuck, see [`RobotModel::solve_ik_restarts`]); the
//!   commanded joints move towards that solution at most at their velocity limits; the servos
//!   follow the interpolated command. This is the Panda's own joint-space behaviour.
//! - [`Cartesian`]: the commanded TCP moves towards the closest reachable pose along a straight
//!   line and the rotation geodesic at bounded speed (like an operational-space controller);
//!   each substep's pose goes through IK. Without joint limits it commutes with rotations of the
//!   scene about a vertical axis, so it isolates the joint limits as the cause of symmetry
//!   breaking.
//!
//! Both bound how far the command may run ahead of the measured joints, so a blocked arm (the
//! table stops the wrist) does not wind up and leap when released.

use nalgebra::{Isometry3, UnitQuaternion};
use serde::{Deserialize, Serialize};

use super::{IkOptions, IkReport, RobotModel};
use crate::error::EnvError;
use crate::math::clamp_norm;

/// How far the commanded joints may run ahead of the measured ones (rad).
const MAX_JOINT_LEAD: f64 = 0.15;
/// Fraction of each joint's velocity limit the joint-space command moves at, leaving the
/// servos headroom to catch up their lag without passing the limit.
const JOINT_SPEED_FRACTION: f64 = 0.9;
/// Acceleration limit of the joint-space command (rad/s^2), the smallest of the Panda's
/// published joint limits (7.5-20). Without one the servos lagged a command that jumped to full
/// speed and then caught up at up to 1.14x the velocity limit over a 50 ms control step.
const MAX_JOINT_ACCELERATION: f64 = 7.5;
/// How far the commanded TCP may run ahead of the actual one (m, rad).
const MAX_TCP_LEAD: f64 = 0.05;
const MAX_TCP_LEAD_ANGLE: f64 = 0.25;
/// Speed limits of the commanded TCP (m/s, rad/s); the Panda's Cartesian limits are 1.7 m/s
/// and 2.5 rad/s.
const MAX_TCP_SPEED: f64 = 1.0;
const MAX_TCP_ANGULAR_SPEED: f64 = 2.5;

/// What a controller needs to know about the robot for one call.
pub struct ControlContext<'a> {
    pub model: &'a RobotModel,
    pub base: &'a Isometry3<f64>,
    pub ik: &'a IkOptions,
    /// Warm starts for IK restarts (home posture and its variants).
    pub seeds: &'a [Vec<f64>],
    /// Control period (s).
    pub period: f64,
}

impl ControlContext<'_> {
    fn clamp(&self, q: &mut [f64]) {
        if self.ik.joint_limits {
            self.model.clamp_to_limits(q);
        }
    }

    fn solve(&self, target: &Isometry3<f64>, q: &mut [f64]) -> IkReport {
        let seeds: Vec<&[f64]> = self.seeds.iter().map(|s| s.as_slice()).collect();
        self.model.solve_ik_restarts(self.base, target, q, &seeds, self.ik)
    }
}

/// Turns absolute TCP targets into joint servo targets.
pub trait ArmController {
    /// Start at rest at joints `q`.
    fn reset(&mut self, ctx: &ControlContext, q: &[f64]);
    /// Plan the next control period towards `target` from the measured joints `q_meas`.
    fn plan(&mut self, ctx: &ControlContext, q_meas: &[f64], target: &Isometry3<f64>) -> IkReport;
    /// Servo targets (positions, velocities) at fraction `a` in (0, 1] of the planned period.
    fn joint_targets(&mut self, ctx: &ControlContext, a: f64, q: &mut [f64], qd: &mut [f64]);
    /// Move the commanded state rigidly by `motion` (symmetry probes); `q_meas` are the
    /// re-solved joints of the moved arm. Returns the worst IK fit.
    fn transform(&mut self, ctx: &ControlContext, motion: &Isometry3<f64>, q_meas: &[f64]) -> IkReport;
}

/// Joint-space interpolation towards the IK solution of the target.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointSpace {
    /// The IK solution of the last target (warm start of the next solve).
    pub q_des: Vec<f64>,
    /// Commanded joints at the start and end of the planned period.
    pub q_start: Vec<f64>,
    pub q_end: Vec<f64>,
    /// Commanded joint velocities of the planned period (acceleration limited).
    pub qd_cmd: Vec<f64>,
}

impl ArmController for JointSpace {
    fn reset(&mut self, _ctx: &ControlContext, q: &[f64]) {
        self.q_des = q.to_vec();
        self.q_start = q.to_vec();
        self.q_end = q.to_vec();
        self.qd_cmd = vec![0.0; q.len()];
    }

    fn plan(&mut self, ctx: &ControlContext, q_meas: &[f64], target: &Isometry3<f64>) -> IkReport {
        let fit = ctx.solve(target, &mut self.q_des);
        let n = q_meas.len();
        for ((start, end), meas) in self.q_start.iter_mut().zip(&self.q_end).zip(q_meas) {
            *start = end.clamp(meas - MAX_JOINT_LEAD, meas + MAX_JOINT_LEAD);
        }
        let (t, dv) = (ctx.period, MAX_JOINT_ACCELERATION * ctx.period);
        // One speed profile for all joints (scaled to the joint that needs it slowest), so the
        // commanded joints move along the straight line towards the solution and the TCP stays
        // close to the commanded path. Shaped joint by joint, joints with short ways arrived
        // early and the hand drifted up to 25 mm sideways while descending onto an object.
        let mut scale = 1.0f64;
        for k in 0..n {
            let err = self.q_des[k] - self.q_start[k];
            let wanted = (err / t).abs();
            // The fastest speed from which the joint can still stop at the target.
            let v_stop = (2.0 * MAX_JOINT_ACCELERATION * err.abs()).sqrt();
            let v_max = (JOINT_SPEED_FRACTION * ctx.model.joints[k].max_velocity).min(v_stop);
            if wanted > v_max {
                scale = scale.min(v_max / wanted);
            }
        }
        let mut accel_scale = 1.0f64;
        for k in 0..n {
            let change = ((self.q_des[k] - self.q_start[k]) / t * scale - self.qd_cmd[k]).abs();
            if change > dv {
                accel_scale = accel_scale.min(dv / change);
            }
        }
        for k in 0..n {
            let err = self.q_des[k] - self.q_start[k];
            let v_goal = err / t * scale;
            let mut v = self.qd_cmd[k] + (v_goal - self.qd_cmd[k]) * accel_scale;
            if (v * t).abs() >= err.abs() && v * err >= 0.0 {
                v = err / t;
            }
            self.qd_cmd[k] = v;
            self.q_end[k] = self.q_start[k] + v * t;
        }
        ctx.clamp(&mut self.q_end);
        fit
    }

    fn joint_targets(&mut self, ctx: &ControlContext, a: f64, q: &mut [f64], qd: &mut [f64]) {
        for k in 0..q.len() {
            let d = self.q_end[k] - self.q_start[k];
            q[k] = self.q_start[k] + d * a;
            qd[k] = d / ctx.period;
        }
    }

    fn transform(&mut self, ctx: &ControlContext, motion: &Isometry3<f64>, q_meas: &[f64]) -> IkReport {
        let mut worst = IkReport { iterations: 0, position_error: 0.0, rotation_error: 0.0, converged: true };
        for q in [&mut self.q_des, &mut self.q_end] {
            let target = motion * ctx.model.tcp_pose(ctx.base, q);
            q.copy_from_slice(q_meas);
            worst = worse(worst, ctx.solve(&target, q));
        }
        self.q_start = self.q_end.clone();
        // Joint velocities of the moved arm differ; the command restarts from rest.
        self.qd_cmd.iter_mut().for_each(|v| *v = 0.0);
        worst
    }
}

/// Straight-line TCP motion at bounded speed, each substep solved by IK.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Cartesian {
    /// The IK solution of the last target (its reachable part).
    pub q_des: Vec<f64>,
    /// Commanded TCP at the start and end of the planned period.
    pub tcp_start: Isometry3<f64>,
    pub tcp_end: Isometry3<f64>,
    /// Joints of the last substep's commanded pose (warm start of the next).
    pub q_cmd: Vec<f64>,
}

impl ArmController for Cartesian {
    fn reset(&mut self, ctx: &ControlContext, q: &[f64]) {
        self.q_des = q.to_vec();
        self.q_cmd = q.to_vec();
        self.tcp_start = ctx.model.tcp_pose(ctx.base, q);
        self.tcp_end = self.tcp_start;
    }

    fn plan(&mut self, ctx: &ControlContext, q_meas: &[f64], target: &Isometry3<f64>) -> IkReport {
        let fit = ctx.solve(target, &mut self.q_des);
        // A target reached within the IK tolerance is used as is, so the path does not depend on
        // where the solver started.
        let reachable = if fit.converged { *target } else { ctx.model.tcp_pose(ctx.base, &self.q_des) };
        let now = ctx.model.tcp_pose(ctx.base, q_meas);
        self.tcp_start = approach(&now, &self.tcp_end, MAX_TCP_LEAD, MAX_TCP_LEAD_ANGLE);
        self.tcp_end =
            approach(&self.tcp_start, &reachable, MAX_TCP_SPEED * ctx.period, MAX_TCP_ANGULAR_SPEED * ctx.period);
        for (cmd, meas) in self.q_cmd.iter_mut().zip(q_meas) {
            *cmd = cmd.clamp(meas - MAX_JOINT_LEAD, meas + MAX_JOINT_LEAD);
        }
        fit
    }

    fn joint_targets(&mut self, ctx: &ControlContext, a: f64, q: &mut [f64], qd: &mut [f64]) {
        let pose = Isometry3::from_parts(
            self.tcp_start.translation.vector.lerp(&self.tcp_end.translation.vector, a).into(),
            self.tcp_start.rotation.slerp(&self.tcp_end.rotation, a),
        );
        q.copy_from_slice(&self.q_cmd);
        ctx.solve(&pose, q);
        // Feed-forward velocity of the straight-line path through the joint-space tangent.
        let n = q.len();
        let mut ahead = q.to_vec();
        let next = (a + 1e-3).min(1.0);
        if next > a {
            let pose_next = Isometry3::from_parts(
                self.tcp_start.translation.vector.lerp(&self.tcp_end.translation.vector, next).into(),
                self.tcp_start.rotation.slerp(&self.tcp_end.rotation, next),
            );
            ctx.model.solve_ik(ctx.base, &pose_next, &mut ahead, ctx.ik);
        }
        for k in 0..n {
            qd[k] = if next > a { (ahead[k] - q[k]) / ((next - a) * ctx.period) } else { 0.0 };
        }
        self.q_cmd.copy_from_slice(q);
    }

    fn transform(&mut self, ctx: &ControlContext, motion: &Isometry3<f64>, q_meas: &[f64]) -> IkReport {
        let target = motion * ctx.model.tcp_pose(ctx.base, &self.q_des);
        self.q_des.copy_from_slice(q_meas);
        let fit = ctx.solve(&target, &mut self.q_des);
        self.tcp_start = motion * self.tcp_start;
        self.tcp_end = motion * self.tcp_end;
        self.q_cmd.copy_from_slice(q_meas);
        fit
    }
}

/// Which arm controller turns absolute pose targets into motion (the `controller` option).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase", try_from = "String")]
pub enum Controller {
    /// IK, then joint-space interpolation at the joints' speed limits (the default).
    #[default]
    Joint,
    /// Straight-line TCP paths at bounded speed; without joint limits it commutes with rotations
    /// of the scene about a vertical axis.
    Cartesian,
}

impl Controller {
    /// The option's spelling (`"joint"`, `"cartesian"`).
    pub fn name(self) -> &'static str {
        match self {
            Controller::Joint => "joint",
            Controller::Cartesian => "cartesian",
        }
    }
}

impl std::str::FromStr for Controller {
    type Err = EnvError;
    fn from_str(s: &str) -> crate::error::Result<Self> {
        match s {
            "joint" => Ok(Controller::Joint),
            "cartesian" => Ok(Controller::Cartesian),
            other => Err(EnvError::InvalidConfig(format!("controller must be 'joint' or 'cartesian', got '{other}'"))),
        }
    }
}

impl TryFrom<String> for Controller {
    type Error = String;
    fn try_from(s: String) -> std::result::Result<Self, String> {
        s.parse().map_err(|_| format!("controller must be 'joint' or 'cartesian', got '{s}'"))
    }
}

/// The running controller of a scene, with its state (serialisable with the physics state).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum ActiveController {
    Joint(JointSpace),
    Cartesian(Cartesian),
}

impl ActiveController {
    /// A controller of kind `kind` at rest at joints `q`.
    pub fn new(kind: Controller, ctx: &ControlContext, q: &[f64]) -> Self {
        let mut c = if kind == Controller::Cartesian {
            ActiveController::Cartesian(Cartesian {
                q_des: Vec::new(),
                tcp_start: Isometry3::identity(),
                tcp_end: Isometry3::identity(),
                q_cmd: Vec::new(),
            })
        } else {
            ActiveController::Joint(JointSpace::default())
        };
        c.get().reset(ctx, q);
        c
    }

    /// Which controller this is.
    pub fn kind(&self) -> Controller {
        match self {
            ActiveController::Joint(_) => Controller::Joint,
            ActiveController::Cartesian(_) => Controller::Cartesian,
        }
    }

    pub fn get(&mut self) -> &mut dyn ArmController {
        match self {
            ActiveController::Joint(c) => c,
            ActiveController::Cartesian(c) => c,
        }
    }

    /// The IK solution of the last target.
    pub fn desired_joints(&self) -> &[f64] {
        match self {
            ActiveController::Joint(c) => &c.q_des,
            ActiveController::Cartesian(c) => &c.q_des,
        }
    }

    /// Number of joints the state holds (for validating restored states).
    pub fn dof(&self) -> usize {
        self.desired_joints().len()
    }
}

/// The worse of two IK fits.
pub fn worse(a: IkReport, b: IkReport) -> IkReport {
    IkReport {
        iterations: a.iterations.max(b.iterations),
        position_error: a.position_error.max(b.position_error),
        rotation_error: a.rotation_error.max(b.rotation_error),
        converged: a.converged && b.converged,
    }
}

/// Move pose `from` towards `to` by at most `max_step` metres and `max_angle` radians (a pose
/// on the straight line and the geodesic between them). Commutes with rigid motions.
pub fn approach(from: &Isometry3<f64>, to: &Isometry3<f64>, max_step: f64, max_angle: f64) -> Isometry3<f64> {
    let dp = clamp_norm(to.translation.vector - from.translation.vector, max_step);
    let turn = to.rotation * from.rotation.inverse();
    let angle = turn.angle();
    let turn = if angle > max_angle {
        UnitQuaternion::from_scaled_axis(turn.scaled_axis() * (max_angle / angle))
    } else {
        turn
    };
    Isometry3::from_parts((from.translation.vector + dp).into(), turn * from.rotation)
}

/// Warm starts for IK restarts: the home posture and its wrist turned by a quarter and a half
/// turn each way (joint 7), and the same with the forearm (joint 5) turned, which covers the
/// branches a continuous yaw sweep of a top-down grasp needs once joint 7 reaches a limit.
pub fn seed_bank(model: &RobotModel, home: &[f64]) -> Vec<Vec<f64>> {
    use std::f64::consts::{FRAC_PI_2, PI};
    let mut out = Vec::new();
    let n = home.len();
    for d7 in [0.0, FRAC_PI_2, -FRAC_PI_2, PI, -PI] {
        for d5 in [0.0, FRAC_PI_2, -FRAC_PI_2] {
            let mut q = home.to_vec();
            if n >= 7 {
                q[6] += d7;
                q[4] += d5;
            }
            model.clamp_to_limits(&mut q);
            if !out.contains(&q) {
                out.push(q);
            }
        }
    }
    out
}
