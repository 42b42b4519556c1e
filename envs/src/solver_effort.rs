//! Extra solver work only where it buys physics.
//!
//! Two cases need more than the base substeps and PGS sweeps (`PhysicsConfig::solver_iterations`,
//! `pgs_iterations`), and both are presses: a light object squeezed between the heavy arm and
//! the table (or another object, or a fixed part) is a large mass ratio for the iterative
//! solver, and a finger held at its travel limit and pushed by the arm against a fixed part is a
//! long chain of very different masses (`world` module docs). A cube carried in the hand, or an
//! arm moving through free space, is neither. So before every physics step the extra work is
//! set from the contacts the last step found:
//!
//! - a task object gets `object_extra_substeps` and `object_extra_pgs_iterations` while it is
//!   *pressed*: touched by the robot and by something else that is not the robot (the table, a
//!   fixed part, another object);
//! - the robot's bodies get `robot_extra_substeps` while the robot touches a fixed body (the
//!   table, a peg) or a pressed object.
//!
//! rapier gives an island the largest request of its bodies, so a pressed object and the arm
//! pressing it are solved together at the higher count. Contacts count when rapier keeps an
//! active contact for the pair, which includes the speculative contacts within its prediction
//! distance: the work is on one step before two bodies meet. With
//! `PhysicsConfig::extra_work_only_when_pressed` off, the robot always gets its extra substeps
//! and an object whenever anything touches it (rapier's own rule for per-body extras).

use rapier3d::prelude::*;
use serde::{Deserialize, Serialize};

use crate::world::{PhysicsConfig, GROUP_OBJECT, GROUP_ROBOT, GROUP_STATIC};

/// A movable task object whose extra solver work follows its contacts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct PressableObject {
    body: RigidBodyHandle,
    colliders: Vec<ColliderHandle>,
    /// Substeps the object always gets (a nut's grasp, `tasks::square`).
    base_substeps: usize,
}

/// Which bodies get extra solver work, and when (see the module docs).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SolverEffort {
    objects: Vec<PressableObject>,
    robot_bodies: Vec<RigidBodyHandle>,
    robot_colliders: Vec<ColliderHandle>,
}

/// What one collider touches, from the narrow phase's active contacts.
#[derive(Clone, Copy, Default)]
struct Touches {
    robot: bool,
    /// The table, a fixed part or another task object.
    support: bool,
    fixed: bool,
}

fn touches(world: &PhysicsWorld, collider: ColliderHandle, own_body: Option<RigidBodyHandle>) -> Touches {
    let mut t = Touches::default();
    for pair in world.narrow_phase.contact_pairs_with(collider) {
        if !pair.has_any_active_contact() {
            continue;
        }
        let other = if pair.collider1 == collider { pair.collider2 } else { pair.collider1 };
        let Some(c) = world.colliders.get(other) else { continue };
        if own_body.is_some() && c.parent() == own_body {
            continue;
        }
        let member = c.collision_groups().memberships;
        if member.intersects(GROUP_ROBOT) {
            t.robot = true;
        } else if member.intersects(GROUP_STATIC | GROUP_OBJECT) {
            t.support = true;
            t.fixed |= member.intersects(GROUP_STATIC);
        }
    }
    t
}

/// Set a body's extra substeps and PGS sweeps (the patched rapier's untracked setter: a body
/// marked as modified would have its island bookkeeping redone at the next step, while the
/// solver reads these counts afresh at every step anyway).
fn set_work(world: &mut PhysicsWorld, handle: RigidBodyHandle, substeps: usize, pgs: usize) {
    world.bodies.set_additional_solver_work(handle, substeps, pgs);
}

impl SolverEffort {
    /// The robot's moving bodies and colliders.
    pub fn new(robot_bodies: Vec<RigidBodyHandle>, robot_colliders: Vec<ColliderHandle>) -> Self {
        Self { objects: Vec::new(), robot_bodies, robot_colliders }
    }

    /// Follow a movable task object; it always gets `base_substeps` more.
    pub fn add_object(&mut self, body: RigidBodyHandle, colliders: Vec<ColliderHandle>, base_substeps: usize) {
        self.objects.retain(|o| o.body != body);
        self.objects.push(PressableObject { body, colliders, base_substeps });
    }

    /// Set every followed body's extra substeps and PGS sweeps for the next physics step.
    pub fn apply(&self, world: &mut PhysicsWorld, config: &PhysicsConfig) {
        let mut any_pressed = false;
        let mut pressed = Vec::with_capacity(self.objects.len());
        for o in &self.objects {
            let mut t = Touches::default();
            for c in &o.colliders {
                let ct = touches(world, *c, Some(o.body));
                t.robot |= ct.robot;
                t.support |= ct.support;
            }
            let on = if config.extra_work_only_when_pressed { t.robot && t.support } else { true };
            any_pressed |= on && t.robot;
            pressed.push(on);
        }
        for (o, on) in self.objects.iter().zip(pressed) {
            let (substeps, pgs) =
                if on { (config.object_extra_substeps, config.object_extra_pgs_iterations) } else { (0, 0) };
            set_work(world, o.body, o.base_substeps + substeps, pgs);
        }
        let robot_on = !config.extra_work_only_when_pressed
            || any_pressed
            || self.robot_colliders.iter().any(|c| touches(world, *c, None).fixed);
        let substeps = if robot_on { config.robot_extra_substeps } else { 0 };
        for b in &self.robot_bodies {
            set_work(world, *b, substeps, 0);
        }
    }
}
