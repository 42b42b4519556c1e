//! Solver settings against physical honesty and speed: for each setting, adversarial random
//! targets (the deepest robot and object contacts, from exact shape queries, and how far a
//! finger passes its travel), the slip of a lifted cube held for 20 s, and control steps/s.
//! Used to choose the defaults in `PhysicsConfig` and `world::build_world`.
//!
//! `cargo run --release -p equigym-envs --example physics_sweep -- [episodes] [setting...]`
//! e.g. `-- 4 "" it=2,pgs=3 osub=2,opgs=8` (settings as in `shared/settings.rs`; the empty
//! one is the shipped setting).

use std::time::Instant;

use equigym_envs::experts::{make_expert, ExpertOptions};
use equigym_envs::rng::EpisodeRng;
use equigym_envs::world::deepest_penetration;
use equigym_envs::{Env, EnvConfig, ACTION_DIM};
use rapier3d::prelude::ColliderHandle;

mod shared;
use shared::adversarial::random_target;
use shared::hold;
use shared::settings::Setting;

fn config(s: &Setting, horizon: usize) -> EnvConfig {
    let mut cfg = s.env_config("lift");
    cfg.horizon = Some(horizon);
    cfg
}

fn main() {
    let episodes: u64 = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(4);
    let settings = Setting::from_args(2);
    println!("| setting | deepest robot (mm) | deepest object (mm) | finger past travel (mm) | 20 s hold slip, max (mm) | adversarial steps/s |");
    println!("|---|---|---|---|---|---|");
    for s in &settings {
        let mut env = Env::new(config(s, 400)).unwrap();
        let mut rng = EpisodeRng::from_seed(4242);
        let (mut robot, mut object, mut finger) = (0.0f64, 0.0f64, 0.0f64);
        let mut steps = 0usize;
        let t0 = Instant::now();
        for ep in 0..episodes {
            env.reset(1000 + ep).unwrap();
            s.apply(&mut env);
            let objects: Vec<ColliderHandle> = env.task().objects().iter().flat_map(|o| o.colliders.clone()).collect();
            let table = env.scene().statics.table;
            let top = env.task().scene_spec().table.top;
            let mut a = [0.0; ACTION_DIM];
            for t in 0..400 {
                if t % 8 == 0 {
                    a = random_target(&mut rng, top);
                }
                env.step(&a).unwrap();
                steps += 1;
                let scene = env.scene();
                let mut obstacles = objects.clone();
                obstacles.push(table);
                robot = robot.max(deepest_penetration(&scene.world, scene.rig.colliders(), &obstacles));
                object = object.max(deepest_penetration(&scene.world, objects.iter().copied(), &[table]));
                for (f, x) in scene.robot().fingers.iter().zip(scene.finger_positions()) {
                    finger = finger.max((f.lower - x).max(x - f.upper));
                }
            }
        }
        let rate = steps as f64 / t0.elapsed().as_secs_f64();
        // Hold: lift, then 20 s holding the last action (the physics test's measurement).
        let mut slip: f64 = 0.0;
        let mut env = Env::new(config(s, hold::APPROACH_STEPS + hold::HOLD_STEPS)).unwrap();
        let mut expert = make_expert("lift", ExpertOptions::default()).unwrap();
        for seed in 100..100 + episodes {
            env.reset(seed).unwrap();
            s.apply(&mut env);
            expert.reset(&env, seed);
            if let Some(d) = hold::hold_slip(&mut env, expert.as_mut(), "lift", 40) {
                slip = slip.max(d);
            }
        }
        println!(
            "| `{}` | {:.2} | {:.2} | {:.2} | {:.2} | {:.0} |",
            s.name,
            robot * 1e3,
            object * 1e3,
            finger.max(0.0) * 1e3,
            slip * 1e3,
            rate
        );
    }
}
