//! Stack and Square: experts, and success decided by contact physics.

use equigym_envs::experts::{make_expert, ExpertOptions};
use equigym_envs::tasks::common::{place, pose_of, yaw_pose};
use equigym_envs::tasks::{square, stack};
use equigym_envs::{Env, EnvConfig};

fn hold_steps(env: &mut Env, n: usize) -> bool {
    let hold = env.current_target();
    let mut success = false;
    for _ in 0..n {
        success = env.step(&hold).unwrap().evaluation.success();
    }
    success
}

/// Successes of a task's expert over `seeds`.
fn expert_wins(task: &str, options: ExpertOptions, seeds: std::ops::Range<u64>) -> usize {
    let mut env = Env::new(EnvConfig::new(task)).unwrap();
    let mut expert = make_expert(task, options).unwrap();
    let mut wins = 0;
    for seed in seeds {
        env.reset(seed).unwrap();
        expert.reset(&env, seed);
        for _ in 0..env.horizon() {
            let a = expert.act(&env);
            if env.step(&a).unwrap().evaluation.success() {
                wins += 1;
                break;
            }
        }
    }
    wins
}

#[test]
fn stack_expert_succeeds_on_at_least_90_percent_of_200_seeds() {
    let wins = expert_wins("stack", ExpertOptions::default(), 0..200);
    assert!(wins >= 180, "stack expert: {wins}/200");
}

#[test]
fn square_expert_puts_the_nut_on_the_peg_in_at_least_80_percent_of_50_seeds() {
    // D2 (the default).
    let wins = expert_wins("square", ExpertOptions::default(), 0..50);
    assert!(wins >= 40, "square expert: {wins}/50");
}

#[test]
fn noisy_square_expert_still_succeeds_often() {
    let noisy = ExpertOptions { position_noise: 0.002, yaw_noise: 0.03 };
    let wins = expert_wins("square", noisy, 1000..1020);
    assert!(wins >= 14, "noisy square expert: {wins}/20");
}

#[test]
fn stack_success_needs_cube_a_resting_on_cube_b() {
    let mut env = Env::new(EnvConfig::new("stack")).unwrap();
    env.reset(0).unwrap();
    let objects = env.task().objects().to_vec();
    let top = env.task().scene_spec().table.top;
    // A beside B, on the table: no success.
    place(env.scene_mut(), &objects[1], &yaw_pose(0.1, 0.1, top + stack::HALF_B, 0.0));
    place(env.scene_mut(), &objects[0], &yaw_pose(0.1, -0.1, top + stack::HALF_A, 0.0));
    assert!(!hold_steps(&mut env, 5));
    // A dropped onto B: success once it rests there.
    place(env.scene_mut(), &objects[0], &yaw_pose(0.1, 0.1, top + 2.0 * stack::HALF_B + stack::HALF_A + 0.01, 0.3));
    assert!(hold_steps(&mut env, 10));
}

#[test]
fn the_nut_goes_down_the_peg_only_through_its_hole() {
    let mut env = Env::new(EnvConfig::new("square")).unwrap();
    env.reset(0).unwrap();
    let objects = env.task().objects().to_vec();
    let top = env.task().scene_spec().table.top;
    let peg = pose_of(env.scene(), &objects[1]).translation.vector;
    let above = top + 2.0 * square::PEG_HALF[2] + 0.03;
    // Dropped with the hole over the peg (any yaw), the nut slides down onto the table.
    place(env.scene_mut(), &objects[0], &yaw_pose(peg.x, peg.y, above, 0.7));
    assert!(hold_steps(&mut env, 30), "the nut should slide down the peg");
    let nut = pose_of(env.scene(), &objects[0]).translation.vector;
    assert!(nut.z < top + 0.03, "nut at {nut:?}");
    // Dropped with its solid handle onto the peg, it cannot pass the peg: it tips off beside it.
    env.reset(0).unwrap();
    let handle = square::handle_centre().x;
    place(env.scene_mut(), &objects[0], &yaw_pose(peg.x - handle, peg.y, above, 0.0));
    assert!(!hold_steps(&mut env, 40));
    let nut = pose_of(env.scene(), &objects[0]).translation.vector;
    assert!((nut.xy() - peg.xy()).norm() > 0.03, "the nut went through the peg: {nut:?}");
}
