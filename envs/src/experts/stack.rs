//! Stack expert: grasp cube A, lift it clear of B, carry it over B, lower it onto B, release.

use crate::layout::Action;
use nalgebra::{UnitQuaternion, Vector3};

use super::{object_pose, top_down_grasp, Expert, ExpertOptions, Phase, Waypoints};
use crate::env::Env;
use crate::tasks::stack::{HALF_A, HALF_B};

pub struct StackExpert {
    way: Waypoints,
    phase: Phase,
    timer: usize,
    rotation: UnitQuaternion<f64>,
}

impl StackExpert {
    pub fn new(options: ExpertOptions) -> Self {
        Self { way: Waypoints::new(options), phase: Phase::Approach, timer: 0, rotation: UnitQuaternion::identity() }
    }

    fn next(&mut self, phase: Phase) {
        self.phase = phase;
        self.timer = 0;
    }
}

impl Expert for StackExpert {
    fn reset(&mut self, env: &Env, seed: u64) {
        self.way.reset(env, seed);
        self.next(Phase::Approach);
        let yaw = Waypoints::yaw(&object_pose(env, 0)) + self.way.options.yaw_noise * self.way.rng.normal();
        self.rotation = top_down_grasp(env, yaw, std::f64::consts::FRAC_PI_2);
    }

    fn act(&mut self, env: &Env) -> Action {
        let a = object_pose(env, 0).translation.vector;
        let b = object_pose(env, 1).translation.vector;
        let tcp = env.scene().tcp_pose().translation.vector;
        let table = env.task().scene_spec().table.top;
        let open = env.max_gripper_width();
        let carry_z = table + 2.0 * HALF_B + 0.07;
        // Where the TCP must be for A's centre to sit at `spot`, given how A hangs in the hand.
        let held = |spot: Vector3<f64>| spot + (tcp - a);
        self.timer += 1;
        let (goal, speed, width) = match self.phase {
            Phase::Approach => (a + Vector3::new(0.0, 0.0, 0.08), 0.03, open),
            Phase::Descend => (a - Vector3::new(0.0, 0.0, 0.2 * HALF_A), 0.015, open),
            Phase::Close => (self.way.commanded, 0.0, 0.0),
            Phase::Lift => (Vector3::new(self.way.commanded.x, self.way.commanded.y, carry_z), 0.02, 0.0),
            Phase::Carry => {
                let g = held(Vector3::new(b.x, b.y, a.z));
                (Vector3::new(g.x, g.y, carry_z), 0.025, 0.0)
            }
            Phase::Lower => (held(b + Vector3::new(0.0, 0.0, HALF_B + HALF_A + 0.004)), 0.008, 0.0),
            Phase::Release => (self.way.commanded, 0.0, open),
            Phase::Retreat => (Vector3::new(self.way.commanded.x, self.way.commanded.y, carry_z + 0.05), 0.02, open),
        };
        let arrived = self.way.advance(goal, speed);
        let near = (tcp - goal).norm();
        let grip_a = a.z > table + HALF_A + 0.01;
        match self.phase {
            Phase::Approach if arrived && near < 0.01 => self.next(Phase::Descend),
            Phase::Descend if (arrived && near < 0.006) || self.timer > 150 => self.next(Phase::Close),
            Phase::Close if self.timer >= 8 => self.next(Phase::Lift),
            Phase::Lift if arrived && near < 0.015 => self.next(if grip_a { Phase::Carry } else { Phase::Approach }),
            Phase::Carry if arrived && (a.xy() - b.xy()).norm() < 0.006 => self.next(Phase::Lower),
            Phase::Carry if self.timer > 120 => self.next(Phase::Lower),
            Phase::Lower if arrived && (near < 0.004 || self.timer > 60) => self.next(Phase::Release),
            Phase::Release if self.timer >= 6 => self.next(Phase::Retreat),
            _ => {}
        }
        self.way.action(&self.rotation, width)
    }

    fn phase(&self) -> &'static str {
        self.phase.name()
    }
}
