//! Stack (MimicGen Stack D1 by default): put cube A (red, half-size 0.02) on cube B (green,
//! half-size 0.025).
//!
//! - Reset: both cubes uniform in x, y of the variant's range with uniform yaw, centres at
//!   least 9 cm apart. D0: +-0.08 (robosuite), D1: +-0.20 (MimicGen), D2: +-0.25 (equigym's
//!   wider variant, the same range as Square D2).
//! - Success (decided by contact): A is not grasped, A's centre is more than 4 cm above the
//!   table, and A touches B.
//! - Observation (the paper's Stack table, each cube field given for A then B): cube positions,
//!   cube 6D rotations, gripper-to-cube vectors (cube minus gripper, 3-d), then the gripper.

use nalgebra::Vector3;

use super::common::{self, PlacementRange};
use super::{range_option, Evaluation, Measures, SceneSpec, Task, TaskObject, TaskOptions};
use crate::error::{EnvError, Result};
use crate::layout::{FieldKind, Layout};
use crate::math::rot6d;
use crate::rng::EpisodeRng;
use crate::scene::Scene;

pub const TABLE_TOP: f64 = 0.80;
pub const HALF_A: f64 = 0.02;
pub const HALF_B: f64 = 0.025;

pub struct Stack {
    layout: Layout,
    objects: Vec<TaskObject>,
    placement: PlacementRange,
}

impl Stack {
    pub fn new(options: &TaskOptions) -> Result<Self> {
        super::check_range_names("stack", options, &["cube_xy", "cube_yaw"])?;
        let r = match super::variant("stack", options, "D1", &["D0", "D1", "D2"])? {
            "D0" => 0.08,
            "D1" => 0.20,
            _ => 0.25,
        };
        let xy = range_option(options, "cube_xy", (-r, r))?;
        let yaw = range_option(options, "cube_yaw", (0.0, std::f64::consts::TAU))?;
        if xy.0 < -0.35 || xy.1 > 0.35 {
            return Err(EnvError::InvalidConfig("cube_xy must stay on the table, within [-0.35, 0.35]".into()));
        }
        let layout = Layout::new()
            .with("cubeA_pos", FieldKind::Position, 3)
            .with("cubeB_pos", FieldKind::Position, 3)
            .with("cubeA_rot6d", FieldKind::Rotation6d, 6)
            .with("cubeB_rot6d", FieldKind::Rotation6d, 6)
            .with("gripper_to_cubeA_pos", FieldKind::Position, 3)
            .with("gripper_to_cubeB_pos", FieldKind::Position, 3);
        Ok(Self {
            layout: common::with_gripper_fields(layout),
            objects: Vec::new(),
            placement: PlacementRange { x: xy, y: xy, yaw },
        })
    }
}

/// What Stack D1 measures of a state: the source of its success, `info` and dense reward.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StackMeasures {
    /// Height of cube A's underside above the table.
    pub cube_a_height: f64,
    /// Distance from the tool centre point to cube A's centre.
    pub reach_distance: f64,
    pub cubes_xy_distance: f64,
    /// Cube A is held by the fingers.
    pub grasped: bool,
    /// Cube A touches cube B.
    pub touching: bool,
    /// Cube A's centre is more than 4 cm above the table.
    pub lifted: bool,
}

impl StackMeasures {
    fn of(scene: &Scene, objects: &[TaskObject]) -> Self {
        let a = common::pose_of(scene, &objects[0]).translation.vector;
        let b = common::pose_of(scene, &objects[1]).translation.vector;
        Self {
            cube_a_height: a.z - HALF_A - TABLE_TOP,
            reach_distance: (scene.tcp_pose().translation.vector - a).norm(),
            cubes_xy_distance: (a.xy() - b.xy()).norm(),
            grasped: common::grasped(scene, &objects[0]),
            touching: common::touching(scene, &objects[0], &objects[1]),
            lifted: a.z > TABLE_TOP + 0.04,
        }
    }

    /// Cube A rests on cube B and the hand has let go.
    pub fn success(&self) -> bool {
        self.lifted && self.touching && !self.grasped
    }

    /// The terms `info` reports.
    pub fn terms(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("cubeA_height", self.cube_a_height),
            ("reach_distance", self.reach_distance),
            ("cubes_xy_distance", self.cubes_xy_distance),
            ("grasped", self.grasped as u8 as f64),
            ("cubes_touching", self.touching as u8 as f64),
        ]
    }

    /// robosuite's staged Stack reward, scaled to [0, 1]: reach and grasp A (<= 0.5), lift and
    /// align A over B (<= 1.5), stacked (2).
    pub fn dense_reward(&self) -> f64 {
        if self.success() {
            return 1.0;
        }
        let reach = 0.25 * (1.0 - libm::tanh(10.0 * self.reach_distance)) + if self.grasped { 0.25 } else { 0.0 };
        let lift = if self.grasped && self.cube_a_height > 0.01 {
            1.0 + 0.5 * (1.0 - libm::tanh(10.0 * self.cubes_xy_distance))
        } else {
            0.0
        };
        reach.max(lift) / 2.0
    }
}

impl Stack {
    /// The state's measurements ([`StackMeasures`]).
    pub fn measure(&self, scene: &Scene) -> StackMeasures {
        StackMeasures::of(scene, &self.objects)
    }
}

impl Task for Stack {
    fn id(&self) -> &'static str {
        "stack"
    }

    fn observation_layout(&self) -> &Layout {
        &self.layout
    }

    fn scene_spec(&self) -> SceneSpec {
        super::tabletop::scene_spec(TABLE_TOP)
    }

    fn load_scene(&mut self, scene: &mut Scene) {
        let a = common::add_box(scene, "cubeA", Vector3::repeat(HALF_A), [200, 30, 30]);
        let b = common::add_box(scene, "cubeB", Vector3::repeat(HALF_B), [30, 160, 40]);
        self.objects = vec![a, b];
    }

    fn initialise_episode(&mut self, scene: &mut Scene, rng: &mut EpisodeRng) {
        let spots = common::sample_separated(rng, &[self.placement, self.placement], &[0.045, 0.045]);
        for (object, (x, y, yaw), half) in [(0, spots[0], HALF_A), (1, spots[1], HALF_B)] {
            let pose = common::yaw_pose(x, y, TABLE_TOP + half, yaw);
            common::place(scene, &self.objects[object], &pose);
        }
    }

    fn observe(&self, scene: &Scene, out: &mut [f64]) {
        let a = common::pose_of(scene, &self.objects[0]);
        let b = common::pose_of(scene, &self.objects[1]);
        let g = scene.tcp_pose().translation.vector;
        out[0..3].copy_from_slice(a.translation.vector.as_slice());
        out[3..6].copy_from_slice(b.translation.vector.as_slice());
        out[6..12].copy_from_slice(&rot6d(&a.rotation));
        out[12..18].copy_from_slice(&rot6d(&b.rotation));
        out[18..21].copy_from_slice((a.translation.vector - g).as_slice());
        out[21..24].copy_from_slice((b.translation.vector - g).as_slice());
        common::observe_gripper(scene, &mut out[24..35]);
    }

    fn evaluate(&self, scene: &Scene) -> Evaluation {
        Measures::Stack(self.measure(scene)).into()
    }

    fn objects(&self) -> &[TaskObject] {
        &self.objects
    }
}
