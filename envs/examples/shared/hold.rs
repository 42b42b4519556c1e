//! The long-hold measurement of the physics tests and probes (`tests/physics.rs`,
//! `examples/physics_sweep.rs`): one definition, so that the test's threshold and the sweep's
//! figures measure the same thing.

use equigym_envs::experts::Expert;
use equigym_envs::math::from_pose;
use equigym_envs::Env;
use nalgebra::Isometry3;

/// Control steps in 20 s at 20 Hz.
pub const HOLD_STEPS: usize = 400;
/// Control steps the expert gets to reach the phase to hold.
pub const APPROACH_STEPS: usize = 400;

/// Object `object`'s pose in the TCP frame.
pub fn in_hand(env: &Env, object: usize) -> Isometry3<f64> {
    let body = env.task().objects()[object].body;
    env.scene().tcp_pose().inverse() * from_pose(env.scene().world.bodies[body].position())
}

/// Run `expert` (reset on `env`, which was just reset) until it has spent `settle` control steps
/// in `phase` (within [`APPROACH_STEPS`]), then hold its last action for [`HOLD_STEPS`]. Returns
/// how far object 0 slipped relative to the hand over the hold (m), or None when the expert never
/// got there. `env` needs a horizon of at least `APPROACH_STEPS + HOLD_STEPS`.
pub fn hold_slip(env: &mut Env, expert: &mut dyn Expert, phase: &str, settle: usize) -> Option<f64> {
    let mut action = env.current_target();
    let mut in_phase = 0;
    for _ in 0..APPROACH_STEPS {
        action = expert.act(env);
        env.step(&action).unwrap();
        if expert.phase() == phase {
            in_phase += 1;
            if in_phase >= settle {
                break;
            }
        }
    }
    if in_phase < settle {
        return None;
    }
    let start = in_hand(env, 0);
    for _ in 0..HOLD_STEPS {
        env.step(&action).unwrap();
    }
    Some((in_hand(env, 0).translation.vector - start.translation.vector).norm())
}
