//! Lift: pick a small cube up from the table (robosuite Lift).
//!
//! - Table 0.8 x 0.8, top at z = 0.80; robot base at x = -0.56.
//! - Cube half-size U[0.020, 0.022], centre x, y in U[-0.03, 0.03], yaw in U[0, 2 pi).
//! - Success: the cube's centre is more than 4 cm above the table top.
//! - Observation (22, the paper's Lift table): cube position (3), cube 6D rotation (6), the
//!   planar vector from the gripper to the cube (2, cube minus gripper), gripper position (3),
//!   gripper 6D rotation (6), finger positions (2).

use nalgebra::{Isometry3, Vector3};
use rapier3d::prelude::*;

use super::{common, tabletop};
use super::{range_option, Evaluation, Measures, SceneSpec, Task, TaskObject, TaskOptions};
use crate::error::{EnvError, Result};
use crate::layout::{FieldKind, Layout};
use crate::math::rot6d;
use crate::rng::EpisodeRng;
use crate::scene::Scene;

pub const TABLE_TOP: f64 = 0.80;
/// Height above the table top that counts as lifted.
pub const LIFT_HEIGHT: f64 = 0.04;

pub struct Lift {
    layout: Layout,
    objects: Vec<TaskObject>,
    half_size: f64,
    size_range: (f64, f64),
    xy_range: (f64, f64),
    yaw_range: (f64, f64),
}

impl Lift {
    pub fn new(options: &TaskOptions) -> Result<Self> {
        let size_range = range_option(options, "cube_half_size", (0.020, 0.022))?;
        if size_range.0 <= 0.005 || size_range.1 > 0.04 {
            return Err(EnvError::InvalidConfig("cube_half_size must lie in (0.005, 0.04]".into()));
        }
        super::check_range_names("lift", options, &["cube_half_size", "cube_xy", "cube_yaw"])?;
        super::variant("lift", options, "D0", &["D0"])?;
        Ok(Self {
            layout: common::with_gripper_fields(
                Layout::new()
                    .with("cube_pos", FieldKind::Position, 3)
                    .with("cube_rot6d", FieldKind::Rotation6d, 6)
                    .with("gripper_to_cube_xy", FieldKind::PlanarVector, 2),
            ),
            objects: Vec::new(),
            half_size: 0.021,
            size_range,
            xy_range: range_option(options, "cube_xy", (-0.03, 0.03))?,
            yaw_range: range_option(options, "cube_yaw", (0.0, std::f64::consts::TAU))?,
        })
    }

    fn cube(&self) -> &TaskObject {
        &self.objects[0]
    }

    fn resize(&mut self, scene: &mut Scene, half: f64) {
        self.half_size = half;
        let h = half as f32;
        for c in &self.objects[0].colliders {
            scene.world.colliders[*c].set_shape(SharedShape::cuboid(h, h, h));
        }
        self.objects[0].half_extents = Vector3::repeat(half);
        // Mass follows the new volume (colliders carry the density).
        scene.world.bodies[self.objects[0].body].recompute_mass_properties_from_colliders(&scene.world.colliders);
    }

    fn cube_pose(&self, scene: &Scene) -> Isometry3<f64> {
        common::pose_of(scene, self.cube())
    }

    fn grasped(&self, scene: &Scene) -> bool {
        common::grasped(scene, self.cube())
    }
}

/// What Lift measures of a state: the source of its success, `info` and dense reward.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LiftMeasures {
    /// The cube's centre is above the table by more than the lift height.
    pub lifted: bool,
    /// Height of the cube's underside above the table.
    pub cube_height: f64,
    /// Distance from the tool centre point to the cube's centre.
    pub reach_distance: f64,
    pub grasped: bool,
}

impl LiftMeasures {
    /// Lift succeeds once the cube is lifted.
    pub fn success(&self) -> bool {
        self.lifted
    }

    /// The terms `info` reports.
    pub fn terms(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("cube_height", self.cube_height),
            ("reach_distance", self.reach_distance),
            ("grasped", self.grasped as u8 as f64),
        ]
    }

    /// The shaped reward, in [0, 1] (1 on success): reaching and grasping the cube.
    pub fn dense_reward(&self) -> f64 {
        if self.success() {
            return 1.0;
        }
        let grasp = if self.grasped { 0.25 } else { 0.0 };
        (1.0 - libm::tanh(10.0 * self.reach_distance) + grasp) / 2.25
    }
}

impl Lift {
    pub fn measure(&self, scene: &Scene) -> LiftMeasures {
        let cube = self.cube_pose(scene).translation.vector;
        LiftMeasures {
            lifted: cube.z > TABLE_TOP + LIFT_HEIGHT,
            cube_height: cube.z - self.half_size - TABLE_TOP,
            reach_distance: (scene.tcp_pose().translation.vector - cube).norm(),
            grasped: self.grasped(scene),
        }
    }
}

impl Task for Lift {
    fn id(&self) -> &'static str {
        "lift"
    }

    fn observation_layout(&self) -> &Layout {
        &self.layout
    }

    fn scene_spec(&self) -> SceneSpec {
        tabletop::scene_spec(TABLE_TOP)
    }

    fn load_scene(&mut self, scene: &mut Scene) {
        let cube = common::add_box(scene, "cube", Vector3::repeat(self.half_size), [200, 30, 30]);
        self.objects = vec![cube];
    }

    fn initialise_episode(&mut self, scene: &mut Scene, rng: &mut EpisodeRng) {
        let half = rng.uniform(self.size_range.0, self.size_range.1);
        let x = rng.uniform(self.xy_range.0, self.xy_range.1);
        let y = rng.uniform(self.xy_range.0, self.xy_range.1);
        let yaw = rng.uniform(self.yaw_range.0, self.yaw_range.1);
        self.resize(scene, half);
        common::place(scene, &self.objects[0], &common::yaw_pose(x, y, TABLE_TOP + half, yaw));
    }

    fn observe(&self, scene: &Scene, out: &mut [f64]) {
        let cube = self.cube_pose(scene);
        let c = cube.translation.vector;
        let g = scene.tcp_pose().translation.vector;
        out[0..3].copy_from_slice(c.as_slice());
        out[3..9].copy_from_slice(&rot6d(&cube.rotation));
        out[9] = c.x - g.x;
        out[10] = c.y - g.y;
        common::observe_gripper(scene, &mut out[11..22]);
    }

    fn evaluate(&self, scene: &Scene) -> Evaluation {
        Measures::Lift(self.measure(scene)).into()
    }

    fn objects(&self) -> &[TaskObject] {
        &self.objects
    }

    fn episode_params(&self) -> Vec<f64> {
        vec![self.half_size]
    }

    fn set_episode_params(&mut self, _scene: &mut Scene, params: &[f64]) -> Result<()> {
        match params {
            [h] if h.is_finite() && *h > 0.0 && *h < 0.1 => {
                // The collider already has this size: it is part of the restored physics state.
                self.half_size = *h;
                self.objects[0].half_extents = Vector3::repeat(*h);
                Ok(())
            }
            _ => Err(EnvError::InvalidState(format!("lift expects one cube half-size, got {params:?}"))),
        }
    }
}
