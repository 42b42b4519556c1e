use equigym_envs::experts::{make_expert, ExpertOptions};
use equigym_envs::{Env, EnvConfig};
fn main() {
    let seed: u64 = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(0);
    let mut env = Env::new(EnvConfig::new("square")).unwrap();
    let mut ex = make_expert("square", ExpertOptions::default()).unwrap();
    env.reset(seed).unwrap();
    ex.reset(&env, seed);
    let (o0x, o0y) = { let o = env.observe(); (o[0] + 0.07, o[1] + 0.06) };
    for t in 0..200 {
        let a = ex.act(&env);
        let r = env.step(&a).unwrap();
        if t % 4 == 0 {
            let o = env.observe();
            println!("t={t} {} tgt=({:.3},{:.3},{:.3}) tcp=({:.3},{:.3},{:.3}) nut=({:.3},{:.3},{:.3}) peg=({:.3},{:.3}) f=({:.3},{:.3}) {:?}", ex.phase(), a[0], a[1], a[2], o[21], o[22], o[23], o[0], o[1], o[2], o[18], o[19], o[30], o[31], r.evaluation.terms.iter().map(|t| (t.0, (t.1 * 1000.0).round() / 1000.0)).collect::<Vec<_>>());
        }
        if r.evaluation.success { println!("success at {t}"); break; }
        if [22usize, 25, 27, 29].contains(&t) {
            let cam = equigym_envs::render::Camera { eye: nalgebra::Vector3::new(o0x + 0.25, o0y + 0.2, 0.95), target: nalgebra::Vector3::new(o0x, o0y, 0.84), fov_y: 40.0 };
            equigym_envs::render::save_png(&env.render_from(&cam, 320, 240).unwrap(), format!("/tmp/sq_{t}.png")).unwrap();
        }
    }
    equigym_envs::render::save_png(&env.render(320, 240).unwrap(), "/tmp/square.png").unwrap();
}
