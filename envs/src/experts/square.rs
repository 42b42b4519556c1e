//! Square expert: grasp the nut by its handle, the fingers closing across it next to the ring;
//! lift the nut above the peg, turn it so the hole lines up with the peg (the hole is square:
//! period pi/2), centre the hole over the peg from the measured nut pose, lower it down the
//! peg, release and retreat.
//!
//! Why this grasp: the handle is 2.4 cm wide, so the open fingers (8 cm) clear it by 2.8 cm a
//! side, and a hand a few millimetres off still closes on it. A grasp across the whole ring
//! (7.6 cm, centred on the nut's centre of mass, so that the weight makes no torque about the
//! grip) clears the walls by 2 mm a side: the expert itself then succeeded on 45 of 80 starts
//! when its commands were executed with 5 mm of correlated noise (the DART demos' noise), most
//! failures a finger landing on a wall, and a learned policy, whose commands are off by
//! millimetres, rarely lifted the nut. Held by the handle next to the ring, the weight's lever
//! arm about the grip is about 3 cm; the squeezed pads' friction holds it (the same noise test:
//! 34 of 40).

use crate::layout::Action;
use nalgebra::{Point3, UnitQuaternion, Vector3};
use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

use super::{object_pose, top_down_turn, turned_home, Expert, ExpertOptions, Phase, Waypoints};
use crate::env::Env;
use crate::math::from_vector;
use crate::tasks::square::{HANDLE_HALF, HOLE_HALF, NUT_HALF_HEIGHT, PEG_HALF, WALL};

/// Largest turn of the commanded hand rotation per control step (rad).
const MAX_TURN: f64 = 0.04;
/// Commanded gripper width while holding the nut, 1.6 cm less than the handle's width
/// (2 * `HANDLE_HALF[1]`) so that the finger motors squeeze it with a moderate force (their
/// stiffness times the difference). Commanding a closed gripper would press the 15 g fingers
/// into the handle with the motors' full force, where contacts this soft let the pads sink deep.
const GRIP_WIDTH: f64 = 2.0 * HANDLE_HALF[1] - 0.016;
/// Distance of the grip centre from the ring's outer face along the handle (m): as close to the
/// ring (and the nut's centre of mass, inside the hole) as the pads allow without touching the
/// wall.
const GRIP_FROM_WALL: f64 = 0.014;
/// Largest turn of the hand about the vertical from its home posture when lining the nut up
/// with the peg (rad); beyond it the last wrist joint nears its limit.
const MAX_WRIST_TURN: f64 = 2.0;
/// Acceleration limit of the commanded point (m per control step, per control step: 1.2 m/s^2).
/// The nut is held by friction; a sudden start or stop of the hand shakes it in the grip.
const MAX_ACCEL: f64 = 0.003;

pub struct SquareExpert {
    way: Waypoints,
    phase: Phase,
    timer: usize,
    /// Commanded hand rotation.
    rotation: UnitQuaternion<f64>,
    /// Hand rotation that lines the hole up with the peg (set when the nut is lifted).
    carry_rotation: UnitQuaternion<f64>,
    /// Turn of the grasp rotation about the world z axis from the home posture.
    grasp_turn: f64,
    /// Distance the commanded point moved in the last control step.
    speed: f64,
}

impl SquareExpert {
    pub fn new(options: ExpertOptions) -> Self {
        Self {
            way: Waypoints::new(options),
            phase: Phase::Approach,
            timer: 0,
            rotation: UnitQuaternion::identity(),
            carry_rotation: UnitQuaternion::identity(),
            grasp_turn: 0.0,
            speed: 0.0,
        }
    }

    fn next(&mut self, phase: Phase) {
        self.phase = phase;
        self.timer = 0;
    }

    /// Move the commanded point towards `goal` at up to `max_speed` per step, accelerating and
    /// braking smoothly; true when it is there.
    fn advance(&mut self, goal: Vector3<f64>, max_speed: f64) -> bool {
        let d = (goal - self.way.commanded).norm();
        let brake = (2.0 * MAX_ACCEL * d).sqrt();
        self.speed = max_speed.min(self.speed + MAX_ACCEL).min(brake);
        let arrived = self.way.advance(goal, self.speed.max(1e-4));
        if arrived {
            self.speed = 0.0;
        }
        arrived
    }

    /// Turn the commanded rotation towards `goal` by at most MAX_TURN; true when it is there.
    fn turn_towards(&mut self, goal: UnitQuaternion<f64>) -> bool {
        let angle = self.rotation.angle_to(&goal);
        if angle <= MAX_TURN {
            self.rotation = goal;
            true
        } else {
            self.rotation = self.rotation.slerp(&goal, MAX_TURN / angle);
            false
        }
    }
}

/// Where the grip centre goes, in the nut frame: on the handle's axis, [`GRIP_FROM_WALL`]
/// beyond the ring's outer face, at the height of the nut's centre of mass.
fn grip_point(env: &Env) -> Vector3<f64> {
    let body = env.task().objects()[0].body;
    let com = from_vector(env.scene().world.bodies[body].local_center_of_mass());
    Vector3::new(HOLE_HALF + WALL + GRIP_FROM_WALL, 0.0, com.z)
}

impl Expert for SquareExpert {
    fn reset(&mut self, env: &Env, seed: u64) {
        self.way.reset(env, seed);
        self.next(Phase::Approach);
        self.speed = 0.0;
        // The fingers close across the handle's axis, i.e. along the nut's y axis; a pair of
        // fingers is symmetric under a half turn.
        let yaw = Waypoints::yaw(&object_pose(env, 0)) + FRAC_PI_2 + self.way.options.yaw_noise * self.way.rng.normal();
        self.grasp_turn = top_down_turn(env, yaw, PI);
        self.rotation = turned_home(env, self.grasp_turn);
        self.carry_rotation = self.rotation;
    }

    fn act(&mut self, env: &Env) -> Action {
        let nut_pose = object_pose(env, 0);
        let nut = nut_pose.translation.vector;
        let grip = (nut_pose * Point3::from(grip_point(env))).coords;
        let peg_pose = object_pose(env, 1);
        let peg = peg_pose.translation.vector;
        let tcp = env.scene().tcp_pose().translation.vector;
        let table = env.task().scene_spec().table.top;
        let open = env.max_gripper_width();
        let carry_z = table + 2.0 * PEG_HALF[2] + 0.06;
        // TCP position that puts the ring's centre at `spot`, given how the nut hangs.
        let held = |spot: Vector3<f64>| spot + (tcp - nut);
        self.timer += 1;
        let mut turned = true;
        if matches!(self.phase, Phase::Carry | Phase::Lower) {
            turned = self.turn_towards(self.carry_rotation);
        }
        let (goal, speed, width) = match self.phase {
            // Above the peg's height: the way there may pass over the peg.
            Phase::Approach => (Vector3::new(grip.x, grip.y, carry_z), 0.03, open),
            // The pads reach 1.35 cm below the TCP: stop them just above the table.
            Phase::Descend => (Vector3::new(grip.x, grip.y, table + 1.6 * NUT_HALF_HEIGHT), 0.025, open),
            Phase::Close => (self.way.commanded, 0.0, GRIP_WIDTH),
            Phase::Lift => (Vector3::new(self.way.commanded.x, self.way.commanded.y, carry_z), 0.025, GRIP_WIDTH),
            Phase::Carry => {
                let g = held(Vector3::new(peg.x, peg.y, nut.z));
                (Vector3::new(g.x, g.y, carry_z), 0.025, GRIP_WIDTH)
            }
            Phase::Lower => (held(Vector3::new(peg.x, peg.y, table + NUT_HALF_HEIGHT + 0.008)), 0.012, GRIP_WIDTH),
            Phase::Release => (self.way.commanded, 0.0, open),
            Phase::Retreat => (Vector3::new(self.way.commanded.x, self.way.commanded.y, carry_z), 0.02, open),
        };
        let arrived = self.advance(goal, speed);
        let near = (tcp - goal).norm();
        let xy_error = (nut.xy() - peg.xy()).norm();
        // The nut has left the hand (knocked off, or slipped): start over from where it lies.
        let lost = (tcp - grip).norm() > 0.02;
        match self.phase {
            Phase::Carry | Phase::Lower if lost => self.next(Phase::Approach),
            // The open fingers clear the ring by only 2 mm a side: settle before going down.
            Phase::Approach if arrived && near < 0.002 => self.next(Phase::Descend),
            Phase::Approach if arrived && self.timer > 100 => self.next(Phase::Descend),
            Phase::Descend if (arrived && near < 0.006) || self.timer > 150 => self.next(Phase::Close),
            Phase::Close if self.timer >= 8 => self.next(Phase::Lift),
            Phase::Lift if arrived && near < 0.02 => {
                let lifted = nut.z > table + NUT_HALF_HEIGHT + 0.05;
                if lifted {
                    // Turn the hand so that the nut's yaw matches the peg's modulo pi/2: by the
                    // smallest turn, unless that takes the wrist too far from its home posture.
                    let d = (Waypoints::yaw(&peg_pose) - Waypoints::yaw(&nut_pose) + FRAC_PI_4).rem_euclid(FRAC_PI_2)
                        - FRAC_PI_4;
                    let mut turn = self.grasp_turn + d;
                    if turn.abs() > MAX_WRIST_TURN {
                        turn -= FRAC_PI_2 * turn.signum();
                    }
                    self.carry_rotation = turned_home(env, turn);
                    self.next(Phase::Carry);
                } else {
                    self.next(Phase::Approach);
                }
            }
            Phase::Carry if arrived && turned && xy_error < 0.003 => self.next(Phase::Lower),
            Phase::Carry if self.timer > 150 => self.next(Phase::Lower),
            Phase::Lower if arrived && (near < 0.005 || self.timer > 80) => self.next(Phase::Release),
            Phase::Release if self.timer >= 6 => self.next(Phase::Retreat),
            _ => {}
        }
        self.way.action(&self.rotation, width)
    }

    fn phase(&self) -> &'static str {
        self.phase.name()
    }
}
