//! The table-top setting every task shares (robosuite's): a 0.8 x 0.8 table, the Panda on its
//! mount at x = -0.56 facing +x, and robosuite's home posture. Tasks import these facts from
//! here and never from each other.

use nalgebra::Isometry3;

use super::SceneSpec;
use crate::world::TableSpec;

/// Half extents of the table top in x and y (m).
pub const TABLE_HALF_EXTENTS: [f64; 2] = [0.4, 0.4];
/// x of the robot base (m), behind the table's near edge.
pub const ROBOT_BASE_X: f64 = -0.56;
/// Height of the robot base above the table top (its mount, m).
pub const MOUNT_HEIGHT: f64 = 0.112;

/// Episode length in control steps of every table-top task: the evaluation horizon of EquiDiff
/// and MimicGen for Lift, Stack D1 and Square D2.
pub const HORIZON: usize = 400;

/// The Panda's home posture in robosuite.
pub fn panda_home() -> Vec<f64> {
    use std::f64::consts::PI;
    vec![0.0, PI / 16.0, 0.0, -PI / 2.0 - PI / 3.0, 0.0, PI - 0.2, PI / 4.0]
}

/// Robot base pose for a table whose top is at `table_top`.
pub fn robot_base(table_top: f64) -> Isometry3<f64> {
    Isometry3::translation(ROBOT_BASE_X, 0.0, table_top + MOUNT_HEIGHT)
}

/// The scene of a task whose table top is at `table_top`.
pub fn scene_spec(table_top: f64) -> SceneSpec {
    SceneSpec {
        table: TableSpec { top: table_top, half_extents: TABLE_HALF_EXTENTS },
        robot_base: robot_base(table_top),
        home_q: panda_home(),
    }
}
