//! The group acting on simulator states: observation consistency and transition equivariance.

use equigym_envs::{Controller, Env, EnvConfig};
use equigym_wrappers::breaking::{measure, BreakingConfig};
use equigym_wrappers::{transform_state, Group, TaskSymmetry};

fn env(task: &str, joint_limits: bool) -> Env {
    let mut c = EnvConfig::new(task);
    c.physics.joint_limits = joint_limits;
    // Without limits, the Cartesian controller is the setting whose physics commutes with the group.
    c.controller = if joint_limits { Controller::Joint } else { Controller::Cartesian };
    Env::new(c).unwrap()
}

fn max_err(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}

/// Observing the rotated state gives the rotated observation, for every task and element.
#[test]
fn observation_of_rotated_state_is_rotated_observation() {
    for task in ["lift", "stack", "square"] {
        let mut env = env(task, false);
        let sym = TaskSymmetry::for_env(&env, Group::cyclic(8).unwrap(), 4).unwrap();
        env.reset(3).unwrap();
        let state = env.get_state().unwrap();
        let obs = env.observe().to_vec();
        for g in sym.group.elements().unwrap() {
            env.set_state(&state).unwrap();
            let fit = transform_state(&mut env, &g).unwrap();
            assert!(fit.position_error < 1e-4, "{task}: the arm reaches the rotated start without limits");
            let mut expected = obs.clone();
            sym.act_observation(&g, &mut expected).unwrap();
            // Poses pass through rapier's f32 storage.
            assert!(max_err(env.observe(), &expected) < 1e-5, "{task} at {} deg", g.angle().to_degrees());
        }
    }
}

/// With limits on, some rotated Lift states cannot be reached and the transitions break the
/// symmetry; without limits (Cartesian control) the same probe is far smaller.
#[test]
#[ignore = "articulated arm: no rotated Lift state is unreachable any more (IK restarts), and one-step errors are dominated by the arm's configuration-dependent servo dynamics with limits on or off (docs/symmetry/breaking.md); the limits show in rotated-demo replay, asserted by tests/test_symmetry.py::test_joint_limits_make_rotated_lift_demos_fail (too slow for this crate's debug test run)"]
fn joint_limits_break_the_symmetry() {
    let mut config = BreakingConfig::new("lift");
    config.episodes = 3;
    config.states_per_episode = 3;
    let on = measure(&config).unwrap();
    config.env.joint_limits = Some(false);
    config.env.controller = Some(Controller::Cartesian);
    let off = measure(&config).unwrap();
    let err = |r: &equigym_wrappers::breaking::BreakingReport| r.mean_over_rotations(|row| row.hand_error_mean);
    assert!(on.invariance.iter().any(|r| r.unreachable > 0.0));
    assert!(off.invariance.iter().all(|r| r.unreachable == 0.0));
    assert!(err(&off) * 5.0 < err(&on), "limits off {} vs on {}", err(&off), err(&on));
    // The joint controller re-solves the commanded joints within the IK tolerance: a small floor.
    assert!(on.invariance[0].observation_error_max < 2e-3);
    assert_eq!(off.replay[0].successes, off.replay[0].demos, "the identity replay reproduces the demos");
}
