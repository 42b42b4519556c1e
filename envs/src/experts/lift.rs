//! Lift expert: above the cube, down, close, lift.

use crate::layout::Action;
use nalgebra::{UnitQuaternion, Vector3};

use super::{object_pose, top_down_grasp, Expert, ExpertOptions, Phase, Waypoints};
use crate::env::Env;

pub struct LiftExpert {
    way: Waypoints,
    phase: Phase,
    timer: usize,
    rotation: UnitQuaternion<f64>,
    grasp_xy: Vector3<f64>,
}

impl LiftExpert {
    pub fn new(options: ExpertOptions) -> Self {
        Self {
            way: Waypoints::new(options),
            phase: Phase::Approach,
            timer: 0,
            rotation: UnitQuaternion::identity(),
            grasp_xy: Vector3::zeros(),
        }
    }
}

impl Expert for LiftExpert {
    fn reset(&mut self, env: &Env, seed: u64) {
        self.way.reset(env, seed);
        self.phase = Phase::Approach;
        self.timer = 0;
        let cube = object_pose(env, 0);
        let yaw = Waypoints::yaw(&cube) + self.way.options.yaw_noise * self.way.rng.normal();
        self.rotation = top_down_grasp(env, yaw, std::f64::consts::FRAC_PI_2);
    }

    fn act(&mut self, env: &Env) -> Action {
        let cube = object_pose(env, 0).translation.vector;
        let half = env.task().objects()[0].half_extents.z;
        let tcp = env.scene().tcp_pose().translation.vector;
        let open = env.max_gripper_width();
        self.timer += 1;
        let (goal, speed, width) = match self.phase {
            Phase::Approach => (cube + Vector3::new(0.0, 0.0, 0.08), 0.03, open),
            Phase::Descend => (cube + Vector3::new(0.0, 0.0, -0.2 * half), 0.015, open),
            Phase::Close => (self.way.commanded, 0.0, 0.0),
            // Lift ends in this phase; the place phases of the shared enum never occur here.
            _ => (self.grasp_xy + Vector3::new(0.0, 0.0, 0.2), 0.02, 0.0),
        };
        let arrived = self.way.advance(goal, speed);
        let near = (tcp - goal).norm() < 0.01;
        match self.phase {
            Phase::Approach if arrived && near => self.phase = Phase::Descend,
            Phase::Descend if arrived && (tcp - goal).norm() < 0.006 || self.timer > 150 => {
                self.phase = Phase::Close;
                self.timer = 0;
            }
            Phase::Close if self.timer >= 8 => {
                self.phase = Phase::Lift;
                self.grasp_xy =
                    Vector3::new(self.way.commanded.x, self.way.commanded.y, env.task().scene_spec().table.top);
            }
            _ => {}
        }
        self.way.action(&self.rotation, width)
    }

    fn phase(&self) -> &'static str {
        self.phase.name()
    }
}
