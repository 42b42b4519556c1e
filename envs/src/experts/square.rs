//! Square expert: grasp the nut's handle across its width, lift the nut above the peg, centre the
//! ring over the peg, lower it down the peg, release and retreat.

use nalgebra::{Point3, UnitQuaternion, Vector3};

use super::{object_pose, top_down_grasp, Expert, ExpertOptions, Phase, Waypoints};
use crate::env::Env;
use crate::tasks::square::{handle_centre, NUT_HALF_HEIGHT, PEG_HALF};

pub struct SquareExpert {
    way: Waypoints,
    phase: Phase,
    timer: usize,
    rotation: UnitQuaternion<f64>,
}

impl SquareExpert {
    pub fn new(options: ExpertOptions) -> Self {
        Self { way: Waypoints::new(options), phase: Phase::Approach, timer: 0, rotation: UnitQuaternion::identity() }
    }

    fn next(&mut self, phase: Phase) {
        self.phase = phase;
        self.timer = 0;
    }
}

impl Expert for SquareExpert {
    fn reset(&mut self, env: &Env, seed: u64) {
        self.way.reset(env, seed);
        self.next(Phase::Approach);
        // Fingers close across the handle: along the nut's y axis, which is a bar (period pi).
        let yaw = Waypoints::yaw(&object_pose(env, 0)) + std::f64::consts::FRAC_PI_2;
        let yaw = yaw + self.way.options.yaw_noise * self.way.rng.normal();
        self.rotation = top_down_grasp(env, yaw, std::f64::consts::PI);
    }

    fn act(&mut self, env: &Env) -> [f64; 10] {
        let nut_pose = object_pose(env, 0);
        let nut = nut_pose.translation.vector;
        let handle = (nut_pose * Point3::from(handle_centre())).coords;
        let peg = object_pose(env, 1).translation.vector;
        let tcp = env.scene().tcp_pose().translation.vector;
        let table = env.scene().table_top;
        let open = env.max_gripper_width();
        let carry_z = table + 2.0 * PEG_HALF[2] + 0.06;
        // TCP position that puts the ring's centre at `spot`, given how the nut hangs.
        let held = |spot: Vector3<f64>| spot + (tcp - nut);
        self.timer += 1;
        let (goal, speed, width) = match self.phase {
            Phase::Approach => (handle + Vector3::new(0.0, 0.0, 0.08), 0.03, open),
            // Grip the upper part of the handle so the finger pads stay clear of the table.
            Phase::Descend => (Vector3::new(handle.x, handle.y, table + 1.6 * NUT_HALF_HEIGHT), 0.015, open),
            Phase::Close => (self.way.commanded, 0.0, 0.0),
            Phase::Lift => (Vector3::new(self.way.commanded.x, self.way.commanded.y, carry_z), 0.025, 0.0),
            Phase::Carry => {
                let g = held(Vector3::new(peg.x, peg.y, nut.z));
                (Vector3::new(g.x, g.y, carry_z), 0.025, 0.0)
            }
            Phase::Lower => {
                let g = held(Vector3::new(peg.x, peg.y, table + NUT_HALF_HEIGHT + 0.01));
                (g, 0.012, 0.0)
            }
            Phase::Release => (self.way.commanded, 0.0, open),
            Phase::Retreat => (Vector3::new(self.way.commanded.x, self.way.commanded.y, carry_z), 0.02, open),
        };
        let arrived = self.way.advance(goal, speed);
        let near = (tcp - goal).norm();
        match self.phase {
            Phase::Approach if arrived && near < 0.01 => self.next(Phase::Descend),
            Phase::Descend if (arrived && near < 0.006) || self.timer > 150 => self.next(Phase::Close),
            Phase::Close if self.timer >= 8 => self.next(Phase::Lift),
            Phase::Lift if arrived && near < 0.02 => {
                let lifted = nut.z > table + NUT_HALF_HEIGHT + 0.05;
                self.next(if lifted { Phase::Carry } else { Phase::Approach })
            }
            Phase::Carry if arrived && (nut.xy() - peg.xy()).norm() < 0.004 => self.next(Phase::Lower),
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
