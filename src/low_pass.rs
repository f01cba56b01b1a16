//! The first-order low-pass every measurement in sabre goes through (τ_ext, an estimated rate): the exact
//! exponential update over a measured step, so irregular sample spacing is handled.

use std::f64::consts::PI;

/// The blend 1 − e^(−2π f_c dt) of a first-order low-pass at `cutoff` Hz over a step of `dt` s: the
/// filtered value moves this fraction of the way to the new sample.
pub fn blend(cutoff: f64, dt: f64) -> f64 {
    1.0 - (-2.0 * PI * cutoff * dt).exp()
}

/// A first-order low-pass on a vector: the first sample passes through, each later one is blended in
/// over its step; no cutoff passes every sample through.
#[derive(Debug, Clone, PartialEq)]
pub struct LowPass {
    cutoff: Option<f64>,
    value: Vec<f64>,
    started: bool,
}

impl LowPass {
    /// A low-pass of `n` values at `cutoff` Hz (None, zero or negative: none).
    pub fn new(n: usize, cutoff: Option<f64>) -> Self {
        Self {
            cutoff: cutoff.filter(|c| *c > 0.0),
            value: vec![0.0; n],
            started: false,
        }
    }

    pub fn cutoff(&self) -> Option<f64> {
        self.cutoff
    }

    /// Blends `sample` (n values) in over the step `dt` (s; a negative step counts as none) and returns
    /// the filtered value.
    ///
    /// # Panics
    /// If `sample` does not have the filter's n values.
    pub fn update(&mut self, sample: &[f64], dt: f64) -> &[f64] {
        assert_eq!(sample.len(), self.value.len(), "LowPass::update: the sample needs n values");
        match (self.cutoff, self.started) {
            (Some(cutoff), true) => {
                let a = blend(cutoff, dt.max(0.0));
                for (v, &s) in self.value.iter_mut().zip(sample) {
                    *v += a * (s - *v);
                }
            }
            _ => {
                self.value.copy_from_slice(sample);
                self.started = true;
            }
        }
        &self.value
    }

    /// The filtered value (zeros before the first sample).
    pub fn value(&self) -> &[f64] {
        &self.value
    }

    /// Forgets the samples: the next one passes through.
    pub fn reset(&mut self) {
        self.value.iter_mut().for_each(|v| *v = 0.0);
        self.started = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_input_approaches_it_as_the_exponential_does() {
        // x(t) = 1 − e^(−t/τ), τ = 1/(2π f_c): the exact discretisation is exact at every sample,
        // whatever the spacing.
        let cutoff = 3.0;
        let tau = 1.0 / (2.0 * PI * cutoff);
        let mut filter = LowPass::new(1, Some(cutoff));
        filter.update(&[0.0], 0.0);
        let mut t = 0.0;
        for dt in [0.001, 0.02, 0.005, 0.1, 0.0007] {
            t += dt;
            let y = filter.update(&[1.0], dt)[0];
            assert!((y - (1.0 - (-t / tau).exp())).abs() < 1e-12, "t = {t}: {y}");
        }
    }

    #[test]
    fn the_first_sample_and_a_filter_without_cutoff_pass_through() {
        let mut filter = LowPass::new(2, Some(10.0));
        assert_eq!(filter.update(&[3.0, -1.0], 0.001), [3.0, -1.0]);
        assert_ne!(filter.update(&[0.0, 0.0], 0.001), [0.0, 0.0]);
        filter.reset();
        assert_eq!(filter.value(), [0.0, 0.0]);
        assert_eq!(filter.update(&[5.0, 5.0], 0.001), [5.0, 5.0]);
        for cutoff in [None, Some(0.0), Some(-1.0)] {
            let mut none = LowPass::new(1, cutoff);
            assert_eq!(none.cutoff(), None);
            none.update(&[1.0], 0.001);
            assert_eq!(none.update(&[7.0], 0.001), [7.0]);
        }
        assert_eq!(blend(5.0, 0.0), 0.0);
        assert!((blend(1.0, 1e9) - 1.0).abs() < 1e-15);
    }
}
