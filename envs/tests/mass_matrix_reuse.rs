//! What reusing a multibody's mass matrix across the substeps of a physics step (the patched
//! rapier's `MultibodyMassMatrixUpdate::EveryStep`, `vendor/rapier3d/PATCH.md`) does to the
//! dynamics, against rebuilding it before every substep (rapier's own behaviour):
//!
//! - energy: a free, undamped 6-link pendulum released from the horizontal swings for 10 s
//!   under gravity; its total energy may not grow, and it loses no more than with a rebuild
//!   every substep (beyond a small allowance), at the arm's substep count and at a coarse step;
//! - stability: the same chain at a coarse step of 1/60 s stays finite and bounded;
//! - agreement: the Panda driven to the same targets by its servos follows the same joint
//!   path within a small fraction of a degree either way;
//! - the mass matrix itself, built over each link's own Jacobian columns (`PATCH.md` part 4),
//!   against the textbook one of a branched tree.

use equigym_envs::math::rot6d;
use equigym_envs::rng::EpisodeRng;
use equigym_envs::{Env, EnvConfig, ACTION_DIM};
use rapier3d::prelude::*;

/// Links of the test pendulum, each a 0.2 m capsule of 1 kg.
const LINKS: usize = 6;
const LINK_LENGTH: f32 = 0.2;

/// The pendulum: a fixed root, `LINKS` links along +x joined by revolute joints about y, so the
/// chain starts horizontal and at rest, and falls under gravity.
fn pendulum(update: MultibodyMassMatrixUpdate, dt: f32, substeps: usize) -> (PhysicsWorld, Vec<RigidBodyHandle>) {
    let mut world = PhysicsWorld::new();
    world.gravity = Vector::new(0.0, 0.0, -9.81);
    let ip = &mut world.integration_parameters;
    ip.dt = dt;
    ip.num_solver_iterations = substeps;
    ip.multibody_mass_matrix_update = update;
    let root = world.insert_body(RigidBodyBuilder::fixed());
    let mut parent = root;
    let mut links = Vec::new();
    for k in 0..LINKS {
        let body = world.insert_body(RigidBodyBuilder::dynamic().translation(Vector::new(
            LINK_LENGTH * (k as f32 + 0.5),
            0.0,
            0.0,
        )));
        world.insert_collider(
            ColliderBuilder::capsule_x(LINK_LENGTH / 2.0, 0.02).mass(1.0).collision_groups(InteractionGroups::none()),
            Some(body),
        );
        let anchor_parent = if k == 0 { Vector::ZERO } else { Vector::new(LINK_LENGTH / 2.0, 0.0, 0.0) };
        let joint = RevoluteJointBuilder::new(Vector::Y).local_anchor1(anchor_parent).local_anchor2(Vector::new(
            -LINK_LENGTH / 2.0,
            0.0,
            0.0,
        ));
        world.insert_multibody_joint(parent, body, joint).expect("a chain has no cycle");
        links.push(body);
        parent = body;
    }
    (world, links)
}

fn energy(world: &PhysicsWorld, links: &[RigidBodyHandle]) -> f64 {
    let dt = world.integration_parameters.dt;
    links
        .iter()
        .map(|h| {
            let b = &world.bodies[*h];
            (b.kinetic_energy() + b.gravitational_potential_energy(dt, world.gravity)) as f64
        })
        .sum()
}

/// (largest energy gain, energy lost at the end), both as fractions of the potential energy
/// the chain releases falling from the horizontal to hanging (`m g` times the drop of the
/// centres of mass), over `seconds`; `None` if a velocity went non-finite or beyond 100 m/s.
fn swing(update: MultibodyMassMatrixUpdate, dt: f32, substeps: usize, seconds: f32) -> Option<(f64, f64)> {
    let (mut world, links) = pendulum(update, dt, substeps);
    let e0 = energy(&world, &links);
    let released: f64 = (0..LINKS).map(|k| 9.81 * (LINK_LENGTH as f64) * (k as f64 + 0.5)).sum();
    let mut gain = 0.0f64;
    let steps = (seconds / dt).round() as usize;
    for _ in 0..steps {
        world.step();
        for h in &links {
            let v = world.bodies[*h].linvel();
            if !(v.length().is_finite() && v.length() < 100.0) {
                return None;
            }
        }
        gain = gain.max((energy(&world, &links) - e0) / released);
    }
    let lost = (e0 - energy(&world, &links)) / released;
    Some((gain, lost))
}

#[test]
fn reusing_the_mass_matrix_keeps_a_free_chain_conservative_and_stable() {
    // The arm's island: 1/240 s steps of 5 substeps; then a coarse 1/60 s step of 4 substeps.
    for (dt, substeps) in [(1.0 / 240.0, 5), (1.0 / 60.0, 4)] {
        let every_substep = swing(MultibodyMassMatrixUpdate::EverySubstep, dt, substeps, 10.0).expect("diverged");
        let every_step = swing(MultibodyMassMatrixUpdate::EveryStep, dt, substeps, 10.0)
            .unwrap_or_else(|| panic!("reuse diverged at dt {dt}, {substeps} substeps"));
        eprintln!(
            "dt {dt:.4} s, {substeps} substeps: largest gain / energy lost after 10 s, every substep {:.4} / {:.4}, every step {:.4} / {:.4}",
            every_substep.0, every_substep.1, every_step.0, every_step.1
        );
        assert!(every_step.0 <= every_substep.0 + 0.01, "reuse gained energy: {every_step:?} vs {every_substep:?}");
        assert!(every_step.1 <= every_substep.1 + 0.02, "reuse lost more energy: {every_step:?} vs {every_substep:?}");
    }
}

#[test]
fn the_arm_follows_the_same_joint_path_either_way() {
    let run = |every_substep: bool| {
        let mut config = EnvConfig::new("lift");
        config.physics.mass_matrix_every_substep = every_substep;
        let mut env = Env::new(config).unwrap();
        env.reset(3).unwrap();
        let home = env.scene().tcp_pose();
        let mut rng = EpisodeRng::from_seed(11);
        let mut path = Vec::new();
        // Targets within 10 cm of the home TCP (free space above the table), 4 control steps each.
        let mut a = [0.0; ACTION_DIM];
        for t in 0..80 {
            if t % 4 == 0 {
                let p = home.translation.vector;
                a[..3].copy_from_slice(&[
                    p.x + rng.uniform(-0.1, 0.1),
                    p.y + rng.uniform(-0.1, 0.1),
                    p.z + rng.uniform(-0.1, 0.05),
                ]);
                a[3..9].copy_from_slice(&rot6d(&home.rotation));
                a[9] = 0.08;
            }
            env.step(&a).unwrap();
            path.push(env.scene().joint_positions());
        }
        path
    };
    let (rebuilt, reused) = (run(true), run(false));
    let worst = rebuilt
        .iter()
        .zip(&reused)
        .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
        .fold(0.0f64, f64::max);
    eprintln!("largest joint difference over 80 control steps: {:.2e} rad", worst);
    assert!(worst < 5e-4, "joint paths differ by {worst} rad");
    assert!(worst > 0.0, "the two settings gave the same bits: is the option wired in?");
}

/// The patched rapier builds each link's share of the multibody mass matrix over the leading
/// columns of its Jacobian only (`vendor/rapier3d/PATCH.md` part 4). Checked against the textbook mass matrix of a planar tree with a branch: a link on a
/// revolute joint at the origin and two children hinged at its far end, all about y, each body a
/// ball centred on its centre of mass (inertia 2/5 m r^2 about any axis). With `q_a`, `q_b` the
/// children's angles relative to the first link, `l` the first link's joint-to-joint length and
/// `c` each body's joint-to-centre distance:
/// `M11 = I1 + m1 c1^2 + sum_x [Ix + mx (l^2 + cx^2 + 2 l cx cos q_x)]`,
/// `M1x = Ix + mx (cx^2 + l cx cos q_x)`, `Mxx = Ix + mx cx^2`, and the two children do not
/// couple (`Mab = 0`): the second child's Jacobian has a zero column for the first, which is
/// where a product over the wrong columns would show.
#[test]
fn the_multibody_mass_matrix_is_the_textbook_one_for_a_branched_tree() {
    use rapier3d::na::{DMatrix, DVector};
    let mut world = PhysicsWorld::new();
    let root = world.insert_body(RigidBodyBuilder::fixed());
    // (mass, ball radius, joint-to-centre distance); the first link's next joint is at L1.
    let (m1, r1, c1) = (2.0f32, 0.05f32, 0.15f32);
    let l1 = 0.3f32;
    let children = [(1.5f32, 0.04f32, 0.12f32, 0.7f32), (0.8, 0.03, 0.2, -1.1)]; // + angle
    let ball = |world: &mut PhysicsWorld, x: f32, m: f32, r: f32| {
        let body = world.insert_body(RigidBodyBuilder::dynamic().translation(Vector::new(x, 0.0, 0.0)));
        world.insert_collider(ColliderBuilder::ball(r).mass(m).collision_groups(InteractionGroups::none()), Some(body));
        body
    };
    let link1 = ball(&mut world, c1, m1, r1);
    let hinge = |a1: Vector, a2: Vector| RevoluteJointBuilder::new(Vector::Y).local_anchor1(a1).local_anchor2(a2);
    let first = world
        .insert_multibody_joint(root, link1, hinge(Vector::ZERO, Vector::new(-c1, 0.0, 0.0)))
        .expect("a tree has no cycle");
    for (m, r, c, _) in children {
        let child = ball(&mut world, l1 + c, m, r);
        world
            .insert_multibody_joint(link1, child, hinge(Vector::new(l1 - c1, 0.0, 0.0), Vector::new(-c, 0.0, 0.0)))
            .expect("a tree has no cycle");
    }
    let (mb, _) = world.multibody_joints.get_mut(first).expect("the first joint is in the set");
    mb.forward_kinematics(&world.bodies, false); // settles the fixed root's (zero) dofs
    assert_eq!(mb.ndofs(), 3);
    mb.apply_displacements(&[0.4, children[0].3, children[1].3]);
    mb.dof_inverse_inertia(&world.bodies); // forward kinematics, then the mass matrix
    let inv = DMatrix::from_columns(
        &(0..3)
            .map(|k| {
                let mut e = DVector::zeros(3);
                e[k] = 1.0f32;
                mb.inv_augmented_mass().solve(&e).expect("the mass matrix is invertible")
            })
            .collect::<Vec<_>>(),
    );
    let got = inv.try_inverse().expect("M^-1 is invertible");

    let ball_inertia = |m: f32, r: f32| 0.4 * m * r * r;
    let mut want = DMatrix::from_element(3, 3, 0.0f64);
    want[(0, 0)] = (ball_inertia(m1, r1) + m1 * c1 * c1) as f64;
    for (x, (m, r, c, q)) in children.iter().enumerate() {
        let (m, i, c, l, cos) = (*m as f64, ball_inertia(*m, *r) as f64, *c as f64, l1 as f64, libm::cos(*q as f64));
        want[(0, 0)] += i + m * (l * l + c * c + 2.0 * l * c * cos);
        want[(0, x + 1)] = i + m * (c * c + l * c * cos);
        want[(x + 1, 0)] = want[(0, x + 1)];
        want[(x + 1, x + 1)] = i + m * c * c;
    }
    let scale = want.amax();
    for a in 0..3 {
        for b in 0..3 {
            let err = (got[(a, b)] as f64 - want[(a, b)]).abs() / scale;
            assert!(err < 1e-4, "M[{a},{b}] = {} against the textbook {}", got[(a, b)], want[(a, b)]);
        }
    }
}
