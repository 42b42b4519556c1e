//! Adam (PyTorch's `torch.optim.Adam`, L2 penalty added to the gradient) and AdamW (decoupled
//! decay), over one flat parameter vector split into segments with their own weight decay
//! (residual pathway priors decay the equivariant and the plain path differently).

use serde::{Deserialize, Serialize};

use crate::Real;

/// Hyperparameters (PyTorch's defaults except the learning rate).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AdamConfig {
    pub lr: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub eps: f64,
    /// AdamW: decay the weights directly instead of adding `decay * w` to the gradient.
    pub decoupled: bool,
}

impl AdamConfig {
    pub fn new(lr: f64) -> Self {
        Self { lr, beta1: 0.9, beta2: 0.999, eps: 1e-8, decoupled: false }
    }
}

/// Optimiser state for one parameter vector.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Adam<T> {
    pub config: AdamConfig,
    m: Vec<T>,
    v: Vec<T>,
    /// Steps taken.
    pub step: u64,
    /// (end index, weight decay) per segment, in order; the last end is the vector's length.
    segments: Vec<(usize, f64)>,
}

impl<T: Real> Adam<T> {
    /// State for `len` parameters; `segments` gives (end, weight decay) in order (empty: no decay).
    pub fn new(config: AdamConfig, len: usize, segments: Vec<(usize, f64)>) -> Self {
        let segments = if segments.is_empty() { vec![(len, 0.0)] } else { segments };
        Self { config, m: vec![T::ZERO; len], v: vec![T::ZERO; len], step: 0, segments }
    }

    /// One update of `params` with `grads`.
    pub fn update(&mut self, params: &mut [T], grads: &[T]) {
        self.step += 1;
        let c = self.config;
        let t = self.step as i32;
        let bc1 = 1.0 - c.beta1.powi(t);
        let bc2_sqrt = (1.0 - c.beta2.powi(t)).sqrt();
        let step_size = T::from_f64(c.lr / bc1);
        let (b1, b2) = (T::from_f64(c.beta1), T::from_f64(c.beta2));
        let (ob1, ob2) = (T::from_f64(1.0 - c.beta1), T::from_f64(1.0 - c.beta2));
        let inv_bc2 = T::from_f64(1.0 / bc2_sqrt);
        let eps = T::from_f64(c.eps);
        let mut start = 0;
        for &(end, decay) in &self.segments {
            let wd = T::from_f64(decay);
            let shrink = T::from_f64(1.0 - c.lr * decay);
            for i in start..end {
                let mut g = grads[i];
                if decay != 0.0 {
                    if c.decoupled {
                        params[i] *= shrink;
                    } else {
                        g = params[i] * wd + g;
                    }
                }
                self.m[i] = b1 * self.m[i] + ob1 * g;
                self.v[i] = b2 * self.v[i] + ob2 * g * g;
                let denom = self.v[i].sqrt() * inv_bc2 + eps;
                params[i] = params[i] - step_size * self.m[i] / denom;
            }
            start = end;
        }
    }
}
