//! Sweep solver iterations and hand force: worst cube penetration under adversarial actions,
//! expert success and throughput. Used to choose the defaults in `PhysicsConfig`.
use std::time::Instant;
use equigym_envs::experts::{make_expert, ExpertOptions};
use equigym_envs::rng::EpisodeRng;
use equigym_envs::{Env, EnvConfig};

fn main() {
    for (iters, force, substeps) in [(4, 25.0, 12), (4, 40.0, 12), (6, 25.0, 12), (4, 25.0, 16)] {
        let mut cfg = EnvConfig::new("lift");
        cfg.physics.solver_iterations = iters;
        cfg.physics.max_hand_force = force;
        cfg.physics.substeps = substeps;
        cfg.physics.timestep = 0.05 / substeps as f64;
        let mut env = Env::new(cfg).unwrap();
        let mut rng = EpisodeRng::from_seed(2024);
        let top = env.scene().table_top;
        let mut deepest: f64 = 0.0;
        let t0 = Instant::now();
        let mut n = 0;
        for ep in 0..40 {
            env.reset(ep).unwrap();
            let (lo, hi) = env.action_bounds();
            for t in 0..400 {
                let c = env.observe()[0..3].to_vec();
                let mut a: [f64; 10] = std::array::from_fn(|k| rng.uniform(lo[k], hi[k]));
                if t % 3 != 0 {
                    a[0] = c[0] + rng.uniform(-0.03, 0.03);
                    a[1] = c[1] + rng.uniform(-0.03, 0.03);
                    a[2] = top - rng.uniform(0.0, 0.1);
                    a[9] = if rng.uniform(0.0, 1.0) < 0.5 { 0.0 } else { 0.08 };
                }
                env.step(&a).unwrap();
                n += 1;
                let cube = &env.task().objects()[0];
                let pose = equigym_envs::math::from_pose(env.scene().world.bodies[cube.body].position());
                let h = cube.half_extents;
                for sx in [-1.0, 1.0] { for sy in [-1.0, 1.0] { for sz in [-1.0, 1.0] {
                    let p = pose * nalgebra::Point3::new(sx * h.x, sy * h.y, sz * h.z);
                    if p.x.abs() < 0.4 && p.y.abs() < 0.4 && pose.translation.x.abs() < 0.37 && pose.translation.y.abs() < 0.37 { deepest = deepest.max(top - p.z); }
                }}}
            }
        }
        let adv_rate = n as f64 / t0.elapsed().as_secs_f64();
        let mut wins = 0;
        let t1 = Instant::now();
        let mut steps = 0;
        for seed in 0..100 {
            let mut ex = make_expert("lift", ExpertOptions::default()).unwrap();
            env.reset(seed).unwrap();
            ex.reset(&env, seed);
            for _ in 0..150 {
                let a = ex.act(&env);
                steps += 1;
                if env.step(&a).unwrap().evaluation.success { wins += 1; break; }
            }
        }
        println!("iters {iters} force {force} substeps {substeps}: deepest {:.2} mm, adversarial {adv_rate:.0} steps/s, expert {wins}/100 at {:.0} steps/s",
            deepest * 1e3, steps as f64 / t1.elapsed().as_secs_f64());
    }
}
