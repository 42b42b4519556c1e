//! Solver settings on the command line of the physics probes (`examples/depth_probe.rs`,
//! `examples/physics_sweep.rs`): `it=4,sub=12,pgs=1,osub=8,opgs=0,ccd=10,stab=1,rsub=0,mmsub=1`, any subset,
//! the rest from the shipped defaults (the empty string is the shipped setting).
//!
//! - `it`: solver substeps per physics step (`PhysicsConfig::solver_iterations`);
//! - `sub`: physics steps per 50 ms control step (`PhysicsConfig::substeps`; the timestep
//!   follows);
//! - `pgs`: PGS sweeps per substep (`PhysicsConfig::pgs_iterations`);
//! - `osub`, `opgs`: extra substeps and PGS sweeps of a task object's island
//!   (`PhysicsConfig::object_extra_substeps`, `object_extra_pgs_iterations`);
//! - `ccd`: soft-CCD prediction distance in mm (`PhysicsConfig::soft_ccd_prediction`; 0: off);
//! - `rsub`: extra substeps of the robot's island (`PhysicsConfig::robot_extra_substeps`);
//! - `mmsub`: 1 rebuilds the arm's mass matrices before every substep, 0 once per physics step
//!   (`PhysicsConfig::mass_matrix_every_substep`);
//! - `stab`: rapier's stabilisation iterations per substep (not a `PhysicsConfig` field).

use equigym_envs::world::PhysicsConfig;
use equigym_envs::{Env, EnvConfig};

/// A parsed setting: the physics config and the two world-level overrides.
#[derive(Clone, Debug)]
pub struct Setting {
    pub name: String,
    pub physics: PhysicsConfig,
    pub stabilization: Option<usize>,
}

impl Setting {
    pub fn parse(text: &str) -> Result<Setting, String> {
        let mut physics = PhysicsConfig::default();
        let period = physics.control_period();
        let mut stabilization = None;
        for kv in text.split(',').filter(|kv| !kv.is_empty()) {
            let (k, v) = kv.split_once('=').ok_or_else(|| format!("{kv:?} is not key=value"))?;
            let v: usize = v.parse().map_err(|_| format!("{v:?} is not a count"))?;
            match k {
                "it" => physics.solver_iterations = v,
                "sub" => {
                    physics.substeps = v;
                    physics.timestep = period / v as f64;
                }
                "pgs" => physics.pgs_iterations = v,
                "osub" => physics.object_extra_substeps = v,
                "opgs" => physics.object_extra_pgs_iterations = v,
                "stab" => stabilization = Some(v),
                "rsub" => physics.robot_extra_substeps = v,
                "ccd" => physics.soft_ccd_prediction = v as f64 * 1e-3,
                "mmsub" => physics.mass_matrix_every_substep = v != 0,
                _ => return Err(format!("unknown key {k:?} (it, sub, pgs, osub, opgs, ccd, stab, rsub, mmsub)")),
            }
        }
        physics.validate().map_err(|e| e.to_string())?;
        Ok(Setting { name: text.to_string(), physics, stabilization })
    }

    /// Settings from the command-line arguments from `first` on (the shipped one if none).
    pub fn from_args(first: usize) -> Vec<Setting> {
        let mut settings: Vec<Setting> = std::env::args()
            .skip(first)
            .map(|text| {
                Setting::parse(&text).unwrap_or_else(|e| {
                    eprintln!("bad setting {text:?}: {e}");
                    std::process::exit(2)
                })
            })
            .collect();
        if settings.is_empty() {
            settings.push(Setting::parse("").unwrap());
        }
        settings
    }

    /// The config of `task` with this setting's physics (the world-level overrides go on with
    /// [`Setting::apply`] after each reset).
    pub fn env_config(&self, task: &str) -> EnvConfig {
        let mut config = EnvConfig::new(task);
        config.physics = self.physics.clone();
        config
    }

    /// Apply the world-level overrides after a reset (the config goes into `EnvConfig`).
    pub fn apply(&self, env: &mut Env) {
        let world = &mut env.scene_mut().world;
        if let Some(s) = self.stabilization {
            world.integration_parameters.num_internal_stabilization_iterations = s;
        }
    }
}
