//! Quick physical probes of the articulated arm (development aid): forward kinematics of the
//! rig against the model, a hold at home, the Lift expert and a timing.
//!
//! `cargo run --release -p equigym-envs --example arm_probe`

use std::time::Instant;

use equigym_envs::experts::{make_expert, ExpertOptions};
use equigym_envs::{Env, EnvConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut env = Env::new(EnvConfig::new("lift"))?;
    env.reset(0)?;
    let q = env.scene().joint_positions();
    let fk = env.scene().robot().tcp_pose(env.scene().base(), &q);
    let tcp = env.scene().tcp_pose();
    println!("q = {q:?}\nfk-vs-body {:.2e} m", (fk.translation.vector - tcp.translation.vector).norm());
    let hold = env.current_target();
    for _ in 0..40 {
        env.step(&hold)?;
    }
    let end = env.scene().tcp_pose();
    println!(
        "hold drift {:.2e} m, fingers {:?}",
        (end.translation.vector - tcp.translation.vector).norm(),
        env.scene().finger_positions()
    );
    let mut expert = make_expert("lift", ExpertOptions::default())?;
    let mut ok = 0;
    let mut steps = 0;
    let start = Instant::now();
    let n = 20;
    for seed in 0..n {
        env.reset(seed)?;
        expert.reset(&env, seed);
        let mut success = false;
        for _ in 0..env.horizon() {
            let a = expert.act(&env);
            let s = env.step(&a)?;
            steps += 1;
            success |= s.evaluation.success();
        }
        let cube = env.observe()[0..3].to_vec();
        println!("seed {seed}: success {success} phase {} cube {:?}", expert.phase(), cube);
        ok += success as usize;
    }
    println!("lift expert {ok}/{n}, {:.0} control steps/s", steps as f64 / start.elapsed().as_secs_f64());
    Ok(())
}
