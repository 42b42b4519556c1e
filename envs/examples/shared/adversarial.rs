//! The adversarial target of the physics tests and probes (`tests/physics.rs`,
//! `examples/depth_probe.rs`, `examples/physics_sweep.rs`): one definition so that they all draw
//! the same kind of targets in the same order.

use equigym_envs::rng::EpisodeRng;
use equigym_envs::{Action, ACTION_DIM};

/// A uniformly random absolute target (far outside the box, mostly near the table top `top` and
/// often below it), random rotation and width.
pub fn random_target(rng: &mut EpisodeRng, top: f64) -> Action {
    let mut a = [0.0; ACTION_DIM];
    for v in a.iter_mut().take(3) {
        *v = rng.uniform(-1.2, 1.2);
    }
    if rng.uniform(0.0, 1.0) < 0.7 {
        a[0] = rng.uniform(-0.35, 0.35);
        a[1] = rng.uniform(-0.35, 0.35);
        a[2] = top + rng.uniform(-0.15, 0.2);
    }
    for v in a.iter_mut().take(9).skip(3) {
        *v = rng.normal();
    }
    a[9] = rng.uniform(-0.05, 0.15);
    a
}
