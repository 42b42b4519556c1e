//! Behaviour of the Lift environment: expert success, determinism, state round trips,
//! robustness to adversarial actions, and typed errors on bad input.

use equigym_envs::experts::{make_expert, ExpertOptions};
use equigym_envs::rng::EpisodeRng;
use equigym_envs::{Action, Env, EnvConfig, EnvError, RewardKind, ACTION_DIM};

fn lift() -> Env {
    Env::new(EnvConfig::new("lift")).unwrap()
}

fn random_action(env: &Env, rng: &mut EpisodeRng) -> Action {
    let (lo, hi) = env.action_bounds();
    let mut a = [0.0; ACTION_DIM];
    for k in 0..10 {
        a[k] = rng.uniform(lo[k], hi[k]);
    }
    a
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// Run the expert for one episode; true if the cube was lifted at any step.
fn expert_episode(env: &mut Env, seed: u64, options: ExpertOptions) -> bool {
    let mut expert = make_expert("lift", options).unwrap();
    env.reset(seed).unwrap();
    expert.reset(env, seed);
    for _ in 0..env.horizon() {
        let a = expert.act(env);
        if env.step(&a).unwrap().evaluation.success() {
            return true;
        }
    }
    false
}

#[test]
fn expert_lifts_the_cube_in_at_least_95_percent_of_200_seeds() {
    let mut env = lift();
    let wins = (0..200).filter(|s| expert_episode(&mut env, *s, ExpertOptions::default())).count();
    assert!(wins >= 190, "expert succeeded on {wins}/200 seeds");
}

#[test]
fn noisy_expert_still_mostly_succeeds() {
    let mut env = lift();
    let noisy = ExpertOptions { position_noise: 0.003, yaw_noise: 0.05 };
    let wins = (0..20).filter(|s| expert_episode(&mut env, 1000 + *s, noisy)).count();
    assert!(wins >= 15, "noisy expert succeeded on {wins}/20 seeds");
}

#[test]
fn same_seed_and_actions_give_bitwise_equal_rollouts() {
    let run = |warm_up_first: bool| {
        let mut env = lift();
        if warm_up_first {
            // A different earlier episode must not leak into the next one.
            env.reset(99).unwrap();
            let mut rng = EpisodeRng::from_seed(5);
            for _ in 0..30 {
                let a = random_action(&env, &mut rng);
                env.step(&a).unwrap();
            }
        }
        let mut trace = bits(env.reset(7).unwrap());
        let mut rng = EpisodeRng::from_seed(11);
        for _ in 0..60 {
            let a = random_action(&env, &mut rng);
            let r = env.step(&a).unwrap();
            trace.extend(bits(env.observe()));
            trace.push(r.reward.to_bits());
        }
        trace
    };
    let a = run(false);
    assert_eq!(a, run(false));
    assert_eq!(a, run(true));
    let mut env = lift();
    let other = bits(env.reset(8).unwrap());
    assert_ne!(a[..other.len()], other[..], "different seeds must give different episodes");
}

#[test]
fn state_round_trip_restores_bitwise() {
    let mut env = lift();
    env.reset(3).unwrap();
    let mut expert = make_expert("lift", ExpertOptions::default()).unwrap();
    expert.reset(&env, 3);
    for _ in 0..12 {
        let a = expert.act(&env);
        env.step(&a).unwrap();
    }
    let state = env.get_state().unwrap();
    let actions: Vec<Action> = (0..30)
        .map(|_| {
            let a = expert.act(&env);
            env.step(&a).unwrap();
            a
        })
        .collect();
    let end = bits(env.observe());
    // Restore in the same env and in a fresh one: both continue identically.
    for mut target in [env, lift()] {
        target.set_state(&state).unwrap();
        for a in &actions {
            target.step(a).unwrap();
        }
        assert_eq!(bits(target.observe()), end);
        assert_eq!(target.elapsed_steps(), 42);
    }
}

#[test]
fn bad_states_are_rejected_and_leave_the_env_unchanged() {
    let mut env = lift();
    env.reset(1).unwrap();
    let before = bits(env.observe());
    let state = env.get_state().unwrap();
    assert!(matches!(env.set_state(&[1, 2, 3]), Err(EnvError::InvalidState(_))));
    assert!(matches!(env.set_state(&state[..state.len() / 2]), Err(EnvError::InvalidState(_))));
    assert_eq!(bits(env.observe()), before);
    env.set_state(&state).unwrap();
    assert_eq!(bits(env.observe()), before);
}

#[test]
fn adversarial_actions_never_explode_or_push_the_cube_into_the_table() {
    let mut env = lift();
    let mut rng = EpisodeRng::from_seed(2024);
    let table_top = env.task().scene_spec().table.top;
    let mut deepest: f64 = 0.0;
    for episode in 0..8 {
        env.reset(episode).unwrap();
        for t in 0..400 {
            let cube = env.observe()[0..3].to_vec();
            let mut a = random_action(&env, &mut rng);
            if t % 3 != 0 {
                // Drive the fingers at or through the cube and into the table.
                a[0] = cube[0] + rng.uniform(-0.03, 0.03);
                a[1] = cube[1] + rng.uniform(-0.03, 0.03);
                a[2] = table_top - rng.uniform(0.0, 0.1);
                a[9] = if rng.uniform(0.0, 1.0) < 0.5 { 0.0 } else { 0.08 };
            }
            env.step(&a).unwrap();
            let obs = env.observe();
            assert!(obs.iter().all(|v| v.is_finite()), "non-finite observation at episode {episode} step {t}");
            let cube = &env.task().objects()[0];
            let body = &env.scene().world.bodies[cube.body];
            let pose = equigym_envs::math::from_pose(body.position());
            // Lowest corner of the cube below the table top.
            let h = cube.half_extents;
            let mut lowest = f64::INFINITY;
            for sx in [-1.0, 1.0] {
                for sy in [-1.0, 1.0] {
                    for sz in [-1.0, 1.0] {
                        let p = pose * nalgebra::Point3::new(sx * h.x, sy * h.y, sz * h.z);
                        // Only a cube over the table counts (it can be pushed off onto the floor).
                        if p.x.abs() < 0.4
                            && p.y.abs() < 0.4
                            && pose.translation.x.abs() < 0.37
                            && pose.translation.y.abs() < 0.37
                        {
                            lowest = lowest.min(p.z);
                        }
                    }
                }
            }
            if table_top - lowest > deepest {
                deepest = table_top - lowest;
                eprintln!("episode {episode} step {t}: cube {:?} sinks {deepest}", pose.translation.vector);
            }
            assert!(body.linvel().length() < 20.0, "cube speed exploded: {}", body.linvel().length());
        }
        if episode == 0 {
            assert!(env.step(&random_action(&env, &mut rng)).is_err(), "stepping after the horizon must fail");
        }
    }
    assert!(deepest < 0.005, "cube sank {deepest} m into the table");
}

#[test]
fn joint_limits_are_never_violated() {
    let mut env = lift();
    let mut rng = EpisodeRng::from_seed(77);
    env.reset(0).unwrap();
    for _ in 0..300 {
        let a = random_action(&env, &mut rng);
        env.step(&a).unwrap();
        let scene = env.scene();
        let measured = scene.joint_positions();
        for (q, j) in
            scene.controller().desired_joints().iter().chain(&measured).zip(scene.robot().joints.iter().cycle())
        {
            assert!(
                *q >= j.lower - 1e-9 && *q <= j.upper + 1e-9,
                "{} = {q} outside [{}, {}]",
                j.name,
                j.lower,
                j.upper
            );
        }
    }
}

#[test]
fn joint_limits_can_be_turned_off() {
    let mut cfg = EnvConfig::new("lift");
    cfg.physics.joint_limits = false;
    let mut env = Env::new(cfg).unwrap();
    env.reset(0).unwrap();
    // Turn the wrist far beyond q7's limit: only possible without limits.
    let mut a = env.current_target();
    let tcp = env.scene().tcp_pose();
    let mut exceeded = false;
    for k in 1..=60 {
        let turn = nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), 0.1 * k as f64);
        a[3..9].copy_from_slice(&equigym_envs::math::rot6d(&(turn * tcp.rotation)));
        env.step(&a).unwrap();
        let q7 = env.scene().joint_positions()[6];
        exceeded |= q7.abs() > 2.9;
    }
    assert!(exceeded, "without limits the wrist should pass 2.9 rad");
}

/// Turn the wrist 6 rad about the vertical from its reset pose; the largest |q7| reached.
fn wrist_turn(cfg: EnvConfig) -> f64 {
    let mut env = Env::new(cfg).unwrap();
    env.reset(0).unwrap();
    let mut a = env.current_target();
    let tcp = env.scene().tcp_pose();
    let mut largest: f64 = 0.0;
    for k in 1..=60 {
        let turn = nalgebra::UnitQuaternion::from_axis_angle(&nalgebra::Vector3::z_axis(), 0.1 * k as f64);
        a[3..9].copy_from_slice(&equigym_envs::math::rot6d(&(turn * tcp.rotation)));
        env.step(&a).unwrap();
        largest = largest.max(env.scene().joint_positions()[6].abs());
    }
    largest
}

#[test]
fn joint_limit_scale_narrows_every_range_about_its_midpoint() {
    let q7_limit = 2.8973;
    let mut cfg = EnvConfig::new("lift");
    cfg.physics.joint_limit_scale = 0.5;
    let env = Env::new(cfg.clone()).unwrap();
    let (urdf, scaled) = (lift().scene().robot().joints.clone(), &env.scene().robot().joints);
    for (u, s) in urdf.iter().zip(scaled) {
        let (mid, half) = (0.5 * (u.lower + u.upper), 0.5 * (u.upper - u.lower));
        assert!((s.lower - (mid - 0.5 * half)).abs() < 1e-12 && (s.upper - (mid + 0.5 * half)).abs() < 1e-12);
    }
    // The physics holds the narrowed wrist range (within the limit constraints' slack), and the
    // wrist does reach it: the turn is stopped by the scaled limit, not by anything else.
    let narrowed = wrist_turn(cfg);
    assert!(narrowed < 0.5 * q7_limit + 0.03, "|q7| reached {narrowed} past the scaled limit");
    assert!(narrowed > 0.5 * q7_limit - 0.1, "|q7| only reached {narrowed}");
    assert!(wrist_turn(EnvConfig::new("lift")) > 0.5 * q7_limit + 0.5, "the URDF's range should allow more");
    let mut bad = EnvConfig::new("lift");
    bad.physics.joint_limit_scale = 0.0;
    assert!(matches!(Env::new(bad), Err(EnvError::InvalidConfig(_))));
}

#[test]
fn holding_the_current_pose_keeps_the_arm_still() {
    let mut env = lift();
    env.reset(5).unwrap();
    let hold = env.current_target();
    let start = env.scene().tcp_pose();
    for _ in 0..40 {
        env.step(&hold).unwrap();
    }
    let end = env.scene().tcp_pose();
    assert!((end.translation.vector - start.translation.vector).norm() < 0.002);
    assert!(end.rotation.angle_to(&start.rotation) < 0.01);
}

#[test]
fn absolute_targets_are_tracked() {
    let mut env = lift();
    env.reset(5).unwrap();
    let mut a = env.current_target();
    a[0] = 0.1;
    a[1] = -0.15;
    a[2] = 0.95;
    for _ in 0..40 {
        env.step(&a).unwrap();
    }
    let p = env.scene().tcp_pose().translation.vector;
    assert!((p - nalgebra::Vector3::new(0.1, -0.15, 0.95)).norm() < 0.005, "tcp at {p:?}");
}

#[test]
fn bad_actions_give_typed_errors() {
    let mut env = lift();
    assert!(matches!(env.step(&[0.0; ACTION_DIM]), Err(EnvError::CallOrder(_))));
    env.reset(0).unwrap();
    assert!(matches!(env.step(&[0.0; 9]), Err(EnvError::WrongLength { expected: 10, got: 9, .. })));
    let mut a = env.current_target();
    a[4] = f64::NAN;
    let err = env.step(&a).unwrap_err();
    assert!(matches!(err, EnvError::NonFinite { index: 4, .. }), "{err}");
    a[4] = f64::INFINITY;
    assert!(env.step(&a).is_err());
    // Degenerate rotations are not errors: the previous orientation is kept.
    let mut a = env.current_target();
    a[3..9].copy_from_slice(&[0.0; 6]);
    env.step(&a).unwrap();
}

#[test]
fn dense_and_sparse_rewards() {
    let mut cfg = EnvConfig::new("lift");
    cfg.reward = RewardKind::Dense;
    let mut env = Env::new(cfg).unwrap();
    let mut expert = make_expert("lift", ExpertOptions::default()).unwrap();
    env.reset(4).unwrap();
    expert.reset(&env, 4);
    let mut rewards = Vec::new();
    loop {
        let a = expert.act(&env);
        let r = env.step(&a).unwrap();
        rewards.push(r.reward);
        assert!((0.0..=1.0).contains(&r.reward));
        if r.evaluation.success() {
            break;
        }
    }
    assert_eq!(*rewards.last().unwrap(), 1.0);
    assert!(rewards[0] < rewards[rewards.len() - 2], "shaped reward should grow as the gripper reaches");
    // Sparse (the default): the same episode pays 0 until the successful step, which pays 1.
    let mut env = Env::new(EnvConfig::new("lift")).unwrap();
    env.reset(4).unwrap();
    expert.reset(&env, 4);
    let mut sparse = Vec::new();
    loop {
        let r = env.step(&expert.act(&env)).unwrap();
        sparse.push(r.reward);
        if r.evaluation.success() {
            break;
        }
    }
    assert_eq!(sparse.len(), rewards.len(), "the reward kind does not change the rollout");
    assert!(sparse[..sparse.len() - 1].iter().all(|r| *r == 0.0), "{sparse:?}");
    assert_eq!(*sparse.last().unwrap(), 1.0);
}

#[test]
fn bad_configuration_is_rejected() {
    assert!(matches!(Env::new(EnvConfig::new("juggle")), Err(EnvError::InvalidConfig(_))));
    let mut cfg = EnvConfig::new("lift");
    cfg.physics.timestep = -1.0;
    assert!(matches!(Env::new(cfg), Err(EnvError::InvalidConfig(_))));
    let mut cfg = EnvConfig::new("lift");
    cfg.urdf = Some("/nonexistent/robot.urdf".into());
    let err = Env::new(cfg).err().unwrap();
    assert!(matches!(&err, EnvError::FileNotFound { path, .. } if path == "/nonexistent/robot.urdf"), "{err}");
}
