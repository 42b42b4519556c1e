//! The static world: physics settings, the table and the floor, collision groups, and the
//! conversion of URDF-style primitive shapes into rapier colliders.
//!
//! The solver settings are chosen so that objects held by friction stay held
//! (`envs/tests/physics.rs` measures a 20 s hold) and contacts stay shallow; what each setting
//! buys and costs is written next to it.
//!
//! The arm's mass matrix once per physics step: rapier rebuilds and factorises the 9-dof
//! multibody's joint-space mass matrices before every solver substep, which was ~60 % of a
//! control step; the patched rapier (`vendor/rapier3d/PATCH.md`) lets the substeps of a step
//! reuse the step's first build (`MultibodyMassMatrixUpdate::EveryStep`, set here unless
//! `PhysicsConfig::mass_matrix_every_substep`), with fresh Jacobians, velocities, free
//! accelerations and joint constraints at every substep. What it changes is measured in
//! `tests/mass_matrix_reuse.rs` (energy of a free chain, the arm's joint path) and
//! `docs/physics.md` (the adversarial depths). The figures below were measured with a rebuild
//! per substep.
//!
//! Substeps against PGS sweeps: a PGS sweep inside a substep reuses the substep's matrices. The
//! defaults (3 substeps of 2 sweeps; around objects 1 more substep and 8 more sweeps) keep the
//! depths and holds of the earlier 4 substeps of 1 sweep with 8 more substeps around objects
//! (`examples/depth_probe.rs`, 3 tasks x 20 episodes: deepest object 1.7 / 2.7 / 0.5 mm against
//! 2.1 / 1.5 / 2.5 mm, deepest robot collider 2.3 / 3.8 / 3.6 mm against 2.2 / 3.8 / 3.6 mm for
//! lift / stack / square) at about 1.35x the adversarial steps/s (`examples/physics_sweep.rs`).
//! Two substeps were faster again but let an arm link 22-30 mm into an object or the peg in a
//! few episodes (measured before [`penetration_depth`] stopped trusting parry's `contact` query
//! alone, which over-reported such grazes; not re-measured).
//!
//! The robot's island gets 2 more substeps (`robot_extra_substeps`): a finger held at its travel
//! limit and pulled by the arm against the fixed Square peg sank 6.1, 7.3, 7.7 mm into it over
//! the last three steps of an adversarial episode (`DEPTH_TRACE=square:16:398 depth_probe 20
//! rsub=0`; the finger's limit projection, `RobotRig::enforce_position_limits`, puts back what
//! the solver lets through). Over 3 tasks x 60 adversarial episodes (`depth_probe 60 rsub=N`,
//! lift / stack / square), deepest object in the table and deepest robot collider in the table
//! or an object: none 2.49 / 3.07 / 1.13 and 3.50 / 3.43 / 5.09 mm; 1 more 2.93 / 2.80 / 0.65
//! and 2.71 / 4.13 / 4.15 mm; 2 more 1.90 / 1.95 / 0.92 and 2.06 / 2.37 / 3.91 mm. Cost
//! (`physics_sweep 6 rsub=0 rsub=1 "" ...`, two alternating rounds on a loaded machine):
//! adversarial control steps/s 735 / 658 with none, 528 / 639 with 1, 464 / 512 with 2 (about
//! 0.7x), and the 20 s hold slip max 0.59 / 0.58 / 1.04 mm (test bound 2 mm).
//!
//! Soft CCD (`soft_ccd_prediction`) stays off: with 10 mm (and no extra robot substeps), the
//! same 60-episode probe put objects 3.94 / 2.76 / 1.85 mm into the table and robot colliders
//! 4.31 / 3.90 / 3.09 mm into objects (measured before the depth query's GJK check, which can
//! only lower them), no better than without it.

use rapier3d::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{EnvError, Result};

/// Membership of every robot collider (objects and the table filter on it).
pub const GROUP_ROBOT: Group = Group::GROUP_1;
/// Membership of the task objects.
pub const GROUP_OBJECT: Group = Group::GROUP_2;
/// Membership of the table, the floor and fixed task parts (a peg).
pub const GROUP_STATIC: Group = Group::GROUP_3;
/// First of the per-link membership bits used for self-collision filtering (link k gets bit
/// `FIRST_LINK_GROUP_BIT + k`).
pub const FIRST_LINK_GROUP_BIT: u32 = 4;

/// Penetration rapier leaves uncorrected (m).
pub const ALLOWED_PENETRATION: f32 = 0.0002;
/// Natural frequency (Hz) of contacts between two moving bodies.
pub const CONTACT_FREQUENCY: f32 = 480.0;
/// Natural frequency (Hz) of contacts against the table and other fixed bodies.
pub const STATIC_CONTACT_FREQUENCY: f32 = 1920.0;

/// Default soft-CCD prediction distance (m) of moving robot bodies and task objects.
pub const SOFT_CCD_PREDICTION: f64 = 0.0;

/// Physics and actuation settings. The defaults are the ones the shipped tasks are tuned for.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PhysicsConfig {
    /// Physics timestep (s).
    pub timestep: f64,
    /// Physics steps per control step (control period = timestep * substeps; 20 Hz by default).
    pub substeps: usize,
    /// Solver substeps per physics step (rapier's `num_solver_iterations`: each one solves
    /// the velocity constraints and integrates positions at `timestep / solver_iterations`;
    /// the arm's 9-dof mass matrix is rebuilt before each, see `benches/results/profile.md`).
    pub solver_iterations: usize,
    /// PGS sweeps over the constraints inside each substep (rapier's
    /// `num_internal_pgs_iterations`): cheap convergence without a mass-matrix rebuild.
    pub pgs_iterations: usize,
    /// Extra substeps for the island of a movable task object (only while something touches
    /// it). A light object squeezed between the heavy arm and the table is a large mass ratio
    /// for the iterative solver; see `tasks::common::add_boxes`.
    pub object_extra_substeps: usize,
    /// Extra PGS sweeps per substep for the island of a movable task object.
    pub object_extra_pgs_iterations: usize,
    /// Extra substeps for the robot's island (always: the arm is one island). A finger held at
    /// its travel limit and pressed against the fixed peg by the arm is a long chain of very
    /// different masses for the iterative solver; see the module docs.
    pub robot_extra_substeps: usize,
    /// Soft continuous collision detection on every moving robot body and movable task object
    /// (rapier's `soft_ccd_prediction`, m; 0 turns it off): contacts are created ahead of the
    /// motion, up to this far along each body's velocity over a physics step, so that a finger
    /// closing on an edge or a hand swept onto an object meets a contact before it overlaps.
    /// See the module docs for what it changed.
    pub soft_ccd_prediction: f64,
    /// Friction coefficient of objects and table (finger pads get a multiple of it).
    pub friction: f64,
    /// Stiffness of the arm's joint position servos (N m / rad).
    pub joint_stiffness: f64,
    /// Damping of the arm's joint servos (N m s / rad).
    pub joint_damping: f64,
    /// Reflected rotor inertia of each arm joint (kg m^2), added to the joint-space inertia
    /// (MuJoCo's `armature`).
    pub joint_armature: f64,
    /// Reflected inertia of each finger's drive (kg).
    pub finger_armature: f64,
    /// Cap on each finger's force (N); the URDF effort limit caps it too.
    pub max_finger_force: f64,
    /// Finger travel speed (m/s); the URDF velocity limit caps it too.
    pub finger_speed: f64,
    /// Whether the arm's joint limits are enforced (turn off for symmetry ablations).
    pub joint_limits: bool,
    /// Each arm joint's range scaled about its midpoint by this factor (1: the URDF's; below 1
    /// narrower, above 1 wider). The symmetry-breaking dial: joint limits are what breaks the
    /// scene's rotation symmetry, so their width sets how much it breaks. Physics, IK and the
    /// reset clamp all see the scaled ranges. Ignored when `joint_limits` is off.
    pub joint_limit_scale: f64,
    /// Whether non-adjacent arm links collide with each other.
    pub self_collision: bool,
    /// Rebuild the arm's joint-space mass matrices before every solver substep (rapier's own
    /// behaviour) instead of once per physics step (the patched rapier's
    /// `MultibodyMassMatrixUpdate::EveryStep`; see the module docs and
    /// `vendor/rapier3d/PATCH.md`). Slower; kept to measure what the reuse changes.
    pub mass_matrix_every_substep: bool,
}

impl Default for PhysicsConfig {
    fn default() -> Self {
        Self {
            timestep: 1.0 / 240.0,
            substeps: 12,
            solver_iterations: 3,
            pgs_iterations: 2,
            object_extra_substeps: 1,
            object_extra_pgs_iterations: 8,
            robot_extra_substeps: 2,
            soft_ccd_prediction: SOFT_CCD_PREDICTION,
            friction: 1.0,
            joint_stiffness: 2000.0,
            joint_damping: 100.0,
            joint_armature: 0.1,
            finger_armature: 0.1,
            max_finger_force: 70.0,
            finger_speed: 0.2,
            joint_limits: true,
            joint_limit_scale: 1.0,
            self_collision: true,
            mass_matrix_every_substep: false,
        }
    }
}

impl PhysicsConfig {
    pub fn control_period(&self) -> f64 {
        self.timestep * self.substeps as f64
    }

    pub fn validate(&self) -> Result<()> {
        let positive = [
            ("timestep", self.timestep),
            ("friction", self.friction),
            ("joint_stiffness", self.joint_stiffness),
            ("max_finger_force", self.max_finger_force),
            ("finger_speed", self.finger_speed),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(EnvError::InvalidConfig(format!("{name} must be positive and finite, got {v}")));
            }
        }
        for (name, v) in [
            ("soft_ccd_prediction", self.soft_ccd_prediction),
            ("joint_damping", self.joint_damping),
            ("joint_armature", self.joint_armature),
            ("finger_armature", self.finger_armature),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(EnvError::InvalidConfig(format!("{name} must be finite and >= 0, got {v}")));
            }
        }
        if self.timestep > 0.05 {
            return Err(EnvError::InvalidConfig(format!("timestep must be at most 0.05 s, got {}", self.timestep)));
        }
        if self.substeps == 0 || self.substeps > 1000 || self.solver_iterations == 0 || self.solver_iterations > 100 {
            return Err(EnvError::InvalidConfig(
                "substeps must be in 1..=1000 and solver_iterations in 1..=100".into(),
            ));
        }
        for (name, v) in [
            ("pgs_iterations", self.pgs_iterations),
            ("object_extra_substeps", self.object_extra_substeps),
            ("object_extra_pgs_iterations", self.object_extra_pgs_iterations),
            ("robot_extra_substeps", self.robot_extra_substeps),
        ] {
            if v > 100 {
                return Err(EnvError::InvalidConfig(format!("{name} must be at most 100, got {v}")));
            }
        }
        if self.pgs_iterations == 0 {
            return Err(EnvError::InvalidConfig("pgs_iterations must be at least 1".into()));
        }
        if !(self.joint_limit_scale.is_finite() && self.joint_limit_scale > 0.0 && self.joint_limit_scale <= 10.0) {
            return Err(EnvError::InvalidConfig(format!(
                "joint_limit_scale must be in (0, 10], got {}",
                self.joint_limit_scale
            )));
        }
        Ok(())
    }
}

/// Where the table stands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TableSpec {
    /// Height of the table top (m).
    pub top: f64,
    /// Half extents of the top in x and y (m).
    pub half_extents: [f64; 2],
}

/// Rendering colour of a collider, kept in its user data.
pub fn colour_code(rgb: [u8; 3]) -> u128 {
    ((rgb[0] as u128) << 16) | ((rgb[1] as u128) << 8) | rgb[2] as u128 | (1u128 << 32)
}

/// Colliders of the static world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldColliders {
    pub table: ColliderHandle,
    pub floor: ColliderHandle,
}

/// An empty world with the solver settings of `config`, a table and a floor.
pub fn build_world(config: &PhysicsConfig, table: &TableSpec) -> (PhysicsWorld, WorldColliders) {
    let mut world = PhysicsWorld::new();
    world.gravity = Vector::new(0.0, 0.0, -9.81);
    let ip = &mut world.integration_parameters;
    ip.dt = config.timestep as f32;
    ip.num_solver_iterations = config.solver_iterations;
    ip.num_internal_pgs_iterations = config.pgs_iterations;
    ip.multibody_mass_matrix_update = if config.mass_matrix_every_substep {
        MultibodyMassMatrixUpdate::EverySubstep
    } else {
        MultibodyMassMatrixUpdate::EveryStep
    };
    // A finger must not "hold" an object across a gap, which recycled contacts allow.
    ip.contact_recycling = false;
    // Solve friction in the biased (position-correcting) pass too. Without it, that pass moves
    // bodies with velocities friction has not yet acted on, and anything held by friction
    // alone creeps under gravity by g * dt / iterations (about 1 cm/s).
    ip.friction_in_bias_pass = true;
    // rapier tolerates 5 mm of penetration by default; objects of 4 cm need tighter contact
    // (at 1 mm a cube crushed onto the table by the arm settled 3.6 mm deep).
    ip.normalized_allowed_linear_error = ALLOWED_PENETRATION;
    // Contact stiffness scales with the lighter body's mass (k = m (2 pi f)^2), so a 70 g cube
    // crushed by the arm's 87 N m joints needs stiff contacts: at rapier's defaults (30 Hz
    // between bodies, 60 Hz against the table) an arm link went 37 mm into a cube and a cube
    // 11 mm into the table (`examples/physics_sweep.rs`).
    ip.contact_softness.natural_frequency = CONTACT_FREQUENCY;
    ip.static_contact_softness.natural_frequency = STATIC_CONTACT_FREQUENCY;

    let static_groups = InteractionGroups::new(GROUP_STATIC, GROUP_ROBOT | GROUP_OBJECT, InteractionTestMode::And);
    // The table is a solid block down to the floor: a thin top lets a squeezed object tunnel
    // through, while a block always pushes it back out through the top.
    let thickness = table.top as f32;
    let body = world.insert_body(RigidBodyBuilder::fixed().translation(Vector::new(
        0.0,
        0.0,
        table.top as f32 - thickness / 2.0,
    )));
    let table = world.insert_collider(
        ColliderBuilder::cuboid(table.half_extents[0] as f32, table.half_extents[1] as f32, thickness / 2.0)
            .friction(config.friction as f32)
            .collision_groups(static_groups)
            .user_data(colour_code([196, 164, 124])),
        Some(body),
    );
    // A floor far below catches anything that falls off the table.
    let floor = world.insert_body(RigidBodyBuilder::fixed().translation(Vector::new(0.0, 0.0, -0.05)));
    let floor = world.insert_collider(
        ColliderBuilder::cuboid(3.0, 3.0, 0.05).collision_groups(static_groups).user_data(colour_code([90, 90, 100])),
        Some(floor),
    );
    (world, WorldColliders { table, floor })
}

/// Penetration depth (m) of two colliders at their current poses, from exact shape queries
/// (rapier's reported contact depths lag by a step and miss pairs the narrow phase has not
/// seen yet); 0 when they are apart.
///
/// parry's `contact` query alone is not trusted: on touching or nearly touching shapes it
/// reported an arm link grazing the Square peg as 14.3 mm deep (the segment-to-box distance:
/// 6 micrometres apart) and a finger pad next to a Stack cube as 17.4 mm deep (the same query
/// with the shapes swapped, GJK and rapier's own contact: 4 mm apart); `examples/depth_probe.rs`
/// with `DEPTH_TRACE` prints all four. So a depth counts only where GJK's intersection test
/// agrees that the shapes overlap, it is the smaller of the query's two readings (both orders
/// of the shapes), and a capsule (every arm link) is measured as what it is, a
/// segment swept by a ball: its radius minus the distance from its segment, exact while the
/// segment itself is outside the other shape.
pub fn penetration_depth(world: &PhysicsWorld, a: ColliderHandle, b: ColliderHandle) -> f64 {
    use rapier3d::parry::query;
    let (Some(ca), Some(cb)) = (world.colliders.get(a), world.colliders.get(b)) else {
        return 0.0;
    };
    let overlap = query::intersection_test(ca.position(), ca.shape(), cb.position(), cb.shape());
    if !overlap.is_ok_and(|o| o.intersecting) {
        return 0.0;
    }
    for (capsule, other) in [(ca, cb), (cb, ca)] {
        if let Some(cap) = capsule.shape().as_capsule() {
            if let Ok(d) = query::distance(capsule.position(), &cap.segment, other.position(), other.shape()) {
                if d.distance > 0.0 {
                    return (cap.radius - d.distance).max(0.0) as f64;
                }
            }
        }
    }
    // The true depth does not depend on the order of the shapes; the query's over-reports did.
    contact_depth(ca, cb).min(contact_depth(cb, ca))
}

/// How deep parry's `contact` query says `a` is in `b` (0 when apart).
fn contact_depth(a: &Collider, b: &Collider) -> f64 {
    match rapier3d::parry::query::contact(a.position(), a.shape(), b.position(), b.shape(), 0.0) {
        Ok(Some(c)) => (-c.dist as f64).max(0.0),
        _ => 0.0,
    }
}

/// The deepest penetration between any collider of `a` and any of `b`.
pub fn deepest_penetration(
    world: &PhysicsWorld,
    a: impl IntoIterator<Item = ColliderHandle>,
    b: &[ColliderHandle],
) -> f64 {
    let mut deepest: f64 = 0.0;
    for x in a {
        for y in b {
            deepest = deepest.max(penetration_depth(world, x, *y));
        }
    }
    deepest
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A world holding two parentless colliders at the given centres.
    fn pair(
        a: ColliderBuilder,
        pa: [f32; 3],
        b: ColliderBuilder,
        pb: [f32; 3],
    ) -> (PhysicsWorld, ColliderHandle, ColliderHandle) {
        let mut world = PhysicsWorld::new();
        let ha = world.insert_collider(a.translation(Vector::new(pa[0], pa[1], pa[2])), None);
        let hb = world.insert_collider(b.translation(Vector::new(pb[0], pb[1], pb[2])), None);
        (world, ha, hb)
    }

    fn depth_both_ways(world: &PhysicsWorld, a: ColliderHandle, b: ColliderHandle) -> f64 {
        let (ab, ba) = (penetration_depth(world, a, b), penetration_depth(world, b, a));
        assert!((ab - ba).abs() < 1e-9, "depth depends on the order: {ab} vs {ba}");
        ab
    }

    #[test]
    fn boxes_overlapping_apart_and_touching() {
        let cube = || ColliderBuilder::cuboid(0.02, 0.02, 0.02);
        for (gap, want) in [(-0.002f32, 0.002), (-0.0005, 0.0005), (0.001, 0.0), (0.0, 0.0)] {
            let (w, a, b) = pair(cube(), [0.0, 0.0, 0.0], cube(), [0.04 + gap, 0.01, 0.0]);
            let got = depth_both_ways(&w, a, b);
            assert!((got - want).abs() < 2e-5, "gap {gap}: depth {got}, want {want}");
        }
    }

    #[test]
    fn a_capsule_is_measured_from_its_segment() {
        // An upright arm-link capsule (radius 5 cm) beside a 3.2 cm square peg, overlapping by
        // 3 mm, grazing 1 micrometre apart, and crossing the peg's vertical edge diagonally.
        let capsule = || ColliderBuilder::capsule_z(0.1, 0.05);
        let peg = || ColliderBuilder::cuboid(0.016, 0.016, 0.1);
        for (x, want) in [(0.066 - 0.003, 0.003), (0.066 + 1e-6, 0.0)] {
            let (w, a, b) = pair(capsule(), [x, 0.0, 0.0], peg(), [0.0, 0.0, 0.0]);
            let got = depth_both_ways(&w, a, b);
            assert!((got - want).abs() < 2e-5, "capsule at x = {x}: depth {got}, want {want}");
        }
        // Towards the peg's edge along the diagonal: the segment is 0.05 - 0.002 from the edge.
        let d = 0.048 / std::f32::consts::SQRT_2 + 0.016;
        let (w, a, b) = pair(capsule(), [d, d, 0.0], peg(), [0.0, 0.0, 0.0]);
        let got = depth_both_ways(&w, a, b);
        assert!((got - 0.002).abs() < 2e-5, "diagonal capsule: depth {got}, want 0.002");
    }
}
