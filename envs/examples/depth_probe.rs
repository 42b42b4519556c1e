//! How deep task objects get pushed into the table under adversarial targets, per task, for a
//! choice of solver settings: the same random targets as `tests/physics.rs` (uniform absolute
//! targets, mostly near the table and often below it, random widths), and what of the robot
//! touches the object at the deepest moment, and the deepest any robot collider gets into the
//! table or an object, and how many control steps had an object more than 2 mm or a robot
//! collider more than 3 mm deep (the tail beyond the single deepest step). Used to choose the
//! solver settings of `PhysicsConfig`.
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
use rapier3d::parry::query;
use rapier3d::prelude::{ColliderHandle, PhysicsWorld};

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
    // DEPTH_TRACE=task:episode:step prints the 12 control steps up to that step of that episode.
    let trace: Option<(String, u64, usize)> = std::env::var("DEPTH_TRACE").ok().and_then(|v| {
        let mut it = v.split(':');
        Some((it.next()?.to_string(), it.next()?.parse().ok()?, it.next()?.parse().ok()?))
    });
    let mut rng = EpisodeRng::from_seed(4242);
    for task in ["lift", "stack", "square"] {
        let mut env = Env::new(setting.env_config(task)).unwrap();
        let start = Instant::now();
        // (depth, episode, step, deepest robot contact with an object at that moment)
        let mut worst = (0.0f64, 0u64, 0usize, 0.0f64);
        // (depth of a robot collider in the table or an object, episode, step, in the table?,
        // which robot collider: its index in the rig's collider list)
        let mut worst_robot = (0.0f64, 0u64, 0usize, false, 0usize);
        // Control steps with an object deeper than 2 mm in the table / a robot collider deeper
        // than 3 mm in the table or an object: the tails beyond the single deepest step.
        let (mut deep_objects, mut deep_robot) = (0usize, 0usize);
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
                if trace.as_ref().is_some_and(|(k, e, s)| k == task && *e == episode && t + 12 >= *s && t <= *s) {
                    let tcp = scene.tcp_pose();
                    let fingers = scene.finger_positions();
                    let depths: Vec<String> = scene
                        .rig
                        .colliders()
                        .enumerate()
                        .map(|(i, c)| (i, c, deepest_penetration(&scene.world, [c], &objects)))
                        .filter(|(_, _, d)| *d > 1e-4)
                        .map(|(i, c, d)| {
                            let pairs: Vec<String> = objects
                                .iter()
                                .filter(|o| deepest_penetration(&scene.world, [c], &[**o]) > 1e-4)
                                .map(|o| raw_readings(&scene.world, c, *o))
                                .collect();
                            format!("c{i} {:.1} ({})", d * 1e3, pairs.join("; "))
                        })
                        .collect();
                    let objs: Vec<String> = env
                        .task()
                        .objects()
                        .iter()
                        .map(|o| {
                            let b = &scene.world.bodies[o.body];
                            let p = b.translation();
                            format!("{} ({:.3},{:.3},{:.3}) v {:.2}", o.name, p.x, p.y, p.z, b.linvel().length())
                        })
                        .collect();
                    println!(
                        "  t {t}: action xyz ({:.3},{:.3},{:.3}) w {:.3}; tcp ({:.3},{:.3},{:.3}) z-axis z {:.2}; fingers {:.4} {:.4}; depths mm [{}]; {}",
                        a[0], a[1], a[2], a[9], tcp.translation.x, tcp.translation.y, tcp.translation.z,
                        (tcp.rotation * nalgebra::Vector3::z()).z, fingers[0], fingers[1], depths.join(", "), objs.join("; ")
                    );
                }
                let depth = deepest_penetration(&scene.world, objects.iter().copied(), &[table]);
                let in_objects = deepest_penetration(&scene.world, scene.rig.colliders(), &objects);
                let in_table = deepest_penetration(&scene.world, scene.rig.colliders(), &[table]);
                deep_objects += (depth > 0.002) as usize;
                deep_robot += (in_objects.max(in_table) > 0.003) as usize;
                if in_objects.max(in_table) > worst_robot.0 {
                    let mut obstacles = objects.clone();
                    obstacles.push(table);
                    let which = scene
                        .rig
                        .colliders()
                        .enumerate()
                        .map(|(i, c)| (deepest_penetration(&scene.world, [c], &obstacles), i))
                        .fold((0.0, 0), |a, b| if b.0 > a.0 { b } else { a })
                        .1;
                    worst_robot = (in_objects.max(in_table), episode, t, in_table > in_objects, which);
                }
                if depth > worst.0 {
                    let pressed = deepest_penetration(&scene.world, scene.rig.colliders(), &objects);
                    worst = (depth, episode, t, pressed);
                }
            }
        }
        println!(
            "{task:>6}: deepest object {:.2} mm into the table (episode {}, step {}; robot {:.2} mm into an object then); \
             deepest robot {:.2} mm into {} (episode {}, step {}, rig collider {}); steps with an object > 2 mm \
             deep {deep_objects}, with a robot collider > 3 mm deep {deep_robot} (of {}); {:.0} steps/s",
            worst.0 * 1e3,
            worst.1,
            worst.2,
            worst.3 * 1e3,
            worst_robot.0 * 1e3,
            if worst_robot.3 { "the table" } else { "an object" },
            worst_robot.1,
            worst_robot.2,
            worst_robot.4,
            episodes * 400,
            (episodes * 400) as f64 / start.elapsed().as_secs_f64()
        );
    }
}

/// What each query says about robot collider `c` and object `o`, for `DEPTH_TRACE`: rapier's
/// narrow phase (its deepest contact distance, negative when overlapping), parry's `contact` in
/// the swapped order, GJK's intersection test and, for a capsule, its radius minus the distance
/// from its segment (the readings `world::penetration_depth` weighs against each other).
fn raw_readings(world: &PhysicsWorld, c: ColliderHandle, o: ColliderHandle) -> String {
    let (ca, cb) = (&world.colliders[c], &world.colliders[o]);
    let narrow = world.narrow_phase.contact_pair(c, o).map(|p| p.find_deepest_contact().map(|(_, k)| k.dist));
    let swapped =
        query::contact(cb.position(), cb.shape(), ca.position(), ca.shape(), 0.0).ok().flatten().map(|k| k.dist);
    let gjk = query::intersection_test(ca.position(), ca.shape(), cb.position(), cb.shape()).map(|i| i.intersecting);
    let capsule = ca.shape().as_capsule().and_then(|cap| {
        let d = query::distance(ca.position(), &cap.segment, cb.position(), cb.shape()).ok()?;
        Some(cap.radius - d.distance)
    });
    format!("narrow phase {narrow:?}, swapped {swapped:?}, gjk intersecting {gjk:?}, capsule overlap {capsule:?}")
}
