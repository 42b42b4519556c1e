//! Square (MimicGen Square D2 by default): put the square nut onto the square peg.
//!
//! - The nut is a real hollow shape: a square ring of four boxes (hole 5.2 cm wide, walls
//!   1.2 cm, 2 cm tall) with a 2.4 cm wide handle box on its +x side. The peg is a fixed 3.2 x 3.2 x 20 cm
//!   box. The hole is wider than the peg's diagonal (4.5 cm), so insertion works at any relative
//!   yaw, but only through the hole: it is decided by contact physics.
//! - Reset: nut and peg positions, at least 13 cm apart. D2 (MimicGen): both x, y in +-0.25,
//!   nut yaw uniform, peg yaw in [0, pi/2]. D1: +-0.15, same yaws. D0: +-0.08, peg yaw 0.
//!   The peg is re-placed at every reset.
//! - Success: the nut's centre is within 3 cm of the peg's axis in x and y and less than 5 cm
//!   above the table, and the gripper is more than 4.2 cm from the nut's centre.
//! - Observation (the paper's Square table): nut position, nut 6D rotation, gripper position
//!   and 6D rotation in the nut's frame (invariant), peg position, then the gripper.

use nalgebra::{Isometry3, Vector3};

use super::common::{self, PlacementRange};
use super::{range_option, Evaluation, Measures, SceneSpec, Task, TaskObject, TaskOptions};
use crate::error::{EnvError, Result};
use crate::layout::{FieldKind, Layout};
use crate::math::rot6d;
use crate::rng::EpisodeRng;
use crate::scene::Scene;

pub const TABLE_TOP: f64 = 0.82;
/// Half-width of the nut's hole.
pub const HOLE_HALF: f64 = 0.026;
pub const WALL: f64 = 0.012;
/// Half-height of the nut.
pub const NUT_HALF_HEIGHT: f64 = 0.01;
/// Handle: from the ring's outer edge, 6 cm long along the nut's +x axis.
pub const HANDLE_HALF: [f64; 3] = [0.03, 0.012, NUT_HALF_HEIGHT];
pub const PEG_HALF: [f64; 3] = [0.016, 0.016, 0.1];
/// Substeps the nut's island gets beyond the other objects' extra substeps.
const NUT_EXTRA_SUBSTEPS: usize = 4;

/// Centre of the handle in the nut frame.
pub fn handle_centre() -> Vector3<f64> {
    Vector3::new(HOLE_HALF + WALL + HANDLE_HALF[0], 0.0, 0.0)
}

pub struct Square {
    layout: Layout,
    objects: Vec<TaskObject>,
    nut_range: PlacementRange,
    peg_range: PlacementRange,
}

impl Square {
    pub fn new(options: &TaskOptions) -> Result<Self> {
        use std::f64::consts::{FRAC_PI_2, TAU};
        super::check_range_names("square", options, &["nut_xy", "nut_yaw", "peg_xy", "peg_yaw"])?;
        let (r, peg_yaw) = match super::variant("square", options, "D2", &["D0", "D1", "D2"])? {
            "D0" => (0.08, (0.0, 0.0)),
            "D1" => (0.15, (0.0, FRAC_PI_2)),
            _ => (0.25, (0.0, FRAC_PI_2)),
        };
        let nut_xy = range_option(options, "nut_xy", (-r, r))?;
        let peg_xy = range_option(options, "peg_xy", (-r, r))?;
        for (name, xy) in [("nut_xy", nut_xy), ("peg_xy", peg_xy)] {
            if xy.0 < -0.3 || xy.1 > 0.3 {
                return Err(EnvError::InvalidConfig(format!("{name} must stay on the table, within [-0.3, 0.3]")));
            }
        }
        let layout = Layout::new()
            .with("nut_pos", FieldKind::Position, 3)
            .with("nut_rot6d", FieldKind::Rotation6d, 6)
            .with("gripper_to_nut_pos", FieldKind::Invariant, 3)
            .with("gripper_to_nut_rot6d", FieldKind::Invariant, 6)
            .with("peg_pos", FieldKind::Position, 3);
        Ok(Self {
            layout: common::with_gripper_fields(layout),
            objects: Vec::new(),
            nut_range: PlacementRange { x: nut_xy, y: nut_xy, yaw: range_option(options, "nut_yaw", (0.0, TAU))? },
            peg_range: PlacementRange { x: peg_xy, y: peg_xy, yaw: range_option(options, "peg_yaw", peg_yaw)? },
        })
    }

    fn on_peg(nut: &Vector3<f64>, peg: &Vector3<f64>) -> bool {
        (nut.x - peg.x).abs() < 0.03 && (nut.y - peg.y).abs() < 0.03 && nut.z < TABLE_TOP + 0.05
    }
}

/// What Square D2 measures of a state: the source of its success, `info` and dense reward.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SquareMeasures {
    /// Height of the nut's underside above the table.
    pub nut_height: f64,
    pub nut_peg_xy_distance: f64,
    /// Distance from the tool centre point to the handle's centre.
    pub reach_distance: f64,
    /// Distance from the tool centre point to the nut's centre.
    pub gripper_nut_distance: f64,
    pub grasped: bool,
    pub on_peg: bool,
}

impl SquareMeasures {
    fn of(scene: &Scene, objects: &[TaskObject]) -> Self {
        let nut_pose = common::pose_of(scene, &objects[0]);
        let nut = nut_pose.translation.vector;
        let peg = common::pose_of(scene, &objects[1]).translation.vector;
        let tcp = scene.tcp_pose().translation.vector;
        let handle = nut_pose * nalgebra::Point3::from(handle_centre());
        Self {
            nut_height: nut.z - NUT_HALF_HEIGHT - TABLE_TOP,
            nut_peg_xy_distance: (nut.xy() - peg.xy()).norm(),
            reach_distance: (tcp - handle.coords).norm(),
            gripper_nut_distance: (tcp - nut).norm(),
            grasped: common::grasped(scene, &objects[0]),
            on_peg: Square::on_peg(&nut, &peg),
        }
    }

    /// The nut sits on the peg and the hand is away from it.
    pub fn success(&self) -> bool {
        self.on_peg && self.gripper_nut_distance > 0.042
    }

    /// The terms `info` reports.
    pub fn terms(&self) -> Vec<(&'static str, f64)> {
        vec![
            ("nut_height", self.nut_height),
            ("nut_peg_xy_distance", self.nut_peg_xy_distance),
            ("reach_distance", self.reach_distance),
            ("gripper_nut_distance", self.gripper_nut_distance),
            ("grasped", self.grasped as u8 as f64),
            ("on_peg", self.on_peg as u8 as f64),
        ]
    }

    /// robosuite's NutAssembly staging, scaled to [0, 1]: reach and grasp the handle (<= 0.35),
    /// lift and hover over the peg (<= 0.7), on the peg (1).
    pub fn dense_reward(&self) -> f64 {
        if self.success() {
            return 1.0;
        }
        let reach = 0.1 * (1.0 - libm::tanh(10.0 * self.reach_distance)) + if self.grasped { 0.25 } else { 0.0 };
        let lift = if self.grasped && self.nut_height > 0.01 {
            0.35 + 0.35 * (1.0 - libm::tanh(10.0 * self.nut_peg_xy_distance))
        } else {
            0.0
        };
        reach.max(lift)
    }
}

impl Square {
    /// The state's measurements ([`SquareMeasures`]).
    pub fn measure(&self, scene: &Scene) -> SquareMeasures {
        SquareMeasures::of(scene, &self.objects)
    }
}

impl Task for Square {
    fn id(&self) -> &'static str {
        "square"
    }

    fn observation_layout(&self) -> &Layout {
        &self.layout
    }

    fn scene_spec(&self) -> SceneSpec {
        super::tabletop::scene_spec(TABLE_TOP)
    }

    fn load_scene(&mut self, scene: &mut Scene) {
        let (w, t, h) = (HOLE_HALF, WALL, NUT_HALF_HEIGHT);
        let side = Vector3::new(t / 2.0, w + t, h);
        let front = Vector3::new(w, t / 2.0, h);
        let parts = [
            (Isometry3::translation(w + t / 2.0, 0.0, 0.0), side),
            (Isometry3::translation(-(w + t / 2.0), 0.0, 0.0), side),
            (Isometry3::translation(0.0, w + t / 2.0, 0.0), front),
            (Isometry3::translation(0.0, -(w + t / 2.0), 0.0), front),
            (
                Isometry3::from_parts(handle_centre().into(), nalgebra::UnitQuaternion::identity()),
                Vector3::from(HANDLE_HALF),
            ),
        ];
        let nut = common::add_boxes(scene, "nut", &parts, [150, 110, 40], false);
        // Extra solver iterations on the nut let the friction of a grasp on it converge: with
        // none the expert's grip does not lift it, with 4 it slips out of the hand more often.
        scene.world.bodies[nut.body]
            .set_additional_solver_iterations(scene.config.object_extra_substeps + NUT_EXTRA_SUBSTEPS);
        let peg =
            common::add_boxes(scene, "peg", &[(Isometry3::identity(), Vector3::from(PEG_HALF))], [120, 120, 130], true);
        self.objects = vec![nut, peg];
    }

    fn initialise_episode(&mut self, scene: &mut Scene, rng: &mut EpisodeRng) {
        // Resample placements that would start inside the robot (the peg is as tall as the hand
        // is high at home).
        let mut nut = Isometry3::identity();
        let mut peg = Isometry3::identity();
        for _ in 0..common::MAX_PLACEMENT_DRAWS {
            let spots = common::sample_separated(rng, &[self.nut_range, self.peg_range], &[0.1, 0.03]);
            let (x, y, yaw) = spots[0];
            nut = common::yaw_pose(x, y, TABLE_TOP + NUT_HALF_HEIGHT, yaw);
            let (x, y, yaw) = spots[1];
            peg = common::yaw_pose(x, y, TABLE_TOP + PEG_HALF[2], yaw);
            if common::clear_of_robot(scene, &self.objects[0], &nut)
                && common::clear_of_robot(scene, &self.objects[1], &peg)
            {
                break;
            }
        }
        common::place(scene, &self.objects[0], &nut);
        // A fixed body is moved by setting its pose; its colliders follow at the next step.
        common::place(scene, &self.objects[1], &peg);
    }

    fn observe(&self, scene: &Scene, out: &mut [f64]) {
        let nut = common::pose_of(scene, &self.objects[0]);
        let peg = common::pose_of(scene, &self.objects[1]);
        let tcp = scene.tcp_pose();
        let in_nut = nut.inverse() * tcp;
        out[0..3].copy_from_slice(nut.translation.vector.as_slice());
        out[3..9].copy_from_slice(&rot6d(&nut.rotation));
        out[9..12].copy_from_slice(in_nut.translation.vector.as_slice());
        out[12..18].copy_from_slice(&rot6d(&in_nut.rotation));
        out[18..21].copy_from_slice(peg.translation.vector.as_slice());
        common::observe_gripper(scene, &mut out[21..32]);
    }

    fn evaluate(&self, scene: &Scene) -> Evaluation {
        Measures::Square(self.measure(scene)).into()
    }

    fn objects(&self) -> &[TaskObject] {
        &self.objects
    }
}
