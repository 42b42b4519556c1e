//! How deep task objects get pushed into the table under adversarial targets, per task, for a
//! choice of solver settings: the same random targets as `tests/physics.rs` (uniform absolute
//! targets, mostly near the table and often below it, random widths), and what of the robot
//! touches the object at the deepest moment, and the deepest any robot collider gets into the
//! table or an object. Used to choose the solver settings of `PhysicsConfig`.
//!
//! `cargo run --release -p equigym-envs --example depth_probe -- [episodes] [setting...]`
//!
//! Defaults: 40 episodes per task, the shipped setting. Settings as in `shared/settings.rs`,
//! e.g. `it=2,pgs=3,osub=2,opgs=8`, or `stab=2` / `rsub=4` for a second stabilisation
//! iteration / extra substeps on the robot.

use std::time::Instant;

use equigym_envs::rng::EpisodeRng;
use equigym_envs::world::deepest_penetration;
use equigym_envs::Env;

mod shared;
use shared::adversarial::random_target;
use shared::settings::Setting;

fn main() {
    let episodes: u64 = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(40);
    for setting in Setting::from_args(2) {
        println!("setting `{}`, {episodes} episodes per task", setting.name);
        probe(&setting, episodes);
    }
}

fn probe(setting: &Setting, episodes: u64) {
    let mut rng = EpisodeRng::from_seed(4242);
    for task in ["lift", "stack", "square"] {
        let mut env = Env::new(setting.env_config(task)).unwrap();
        let start = Instant::now();
        // (depth, episode, step, deepest robot contact with an object at that moment)
        let mut worst = (0.0f64, 0u64, 0usize, 0.0f64);
        // (depth of a robot collider in the table or an object, episode, step, in the table?)
        let mut worst_robot = (0.0f64, 0u64, 0usize, false);
        for episode in 0..episodes {
            env.reset(1000 + episode).unwrap();
            setting.apply(&mut env);
            let objects: Vec<_> = env.task().objects().iter().flat_map(|o| o.colliders.clone()).collect();
            let table = env.scene().statics.table;
            let top = env.task().scene_spec().table.top;
            let mut a = random_target(&mut rng, top);
            for t in 0..400 {
                if t % 8 == 0 {
                    a = random_target(&mut rng, top);
                }
                env.step(&a).unwrap();
                let scene = env.scene();
                let depth = deepest_penetration(&scene.world, objects.iter().copied(), &[table]);
                let in_objects = deepest_penetration(&scene.world, scene.rig.colliders(), &objects);
                let in_table = deepest_penetration(&scene.world, scene.rig.colliders(), &[table]);
                if in_objects.max(in_table) > worst_robot.0 {
                    worst_robot = (in_objects.max(in_table), episode, t, in_table > in_objects);
                }
                if depth > worst.0 {
                    let pressed = deepest_penetration(&scene.world, scene.rig.colliders(), &objects);
                    worst = (depth, episode, t, pressed);
                }
            }
        }
        println!(
            "{task:>6}: deepest object {:.2} mm into the table (episode {}, step {}; robot {:.2} mm into an object then); \
             deepest robot {:.2} mm into {} (episode {}, step {}); {:.0} steps/s",
            worst.0 * 1e3,
            worst.1,
            worst.2,
            worst.3 * 1e3,
            worst_robot.0 * 1e3,
            if worst_robot.3 { "the table" } else { "an object" },
            worst_robot.1,
            worst_robot.2,
            (episodes * 400) as f64 / start.elapsed().as_secs_f64()
        );
    }
}
