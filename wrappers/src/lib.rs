//! Symmetry wrappers, EDP runtime and latent-action MDP (filled by later work).
pub use equigym_envs as envs;
