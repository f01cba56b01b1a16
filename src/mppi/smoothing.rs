//! Savitzky–Golay smoothing of input sequences (local least-squares polynomial fits, paper Sec. V-D).

use nalgebra::DMatrix;

/// A K × K linear smoother: row k holds the weights that give the value at k of the polynomial of
/// degree `order` fitted by least squares to the `window` samples around k (the window is shifted,
/// not shrunk, at the ends of the sequence, as in scipy's `mode="interp"`).
#[derive(Debug, Clone, PartialEq)]
pub struct SavitzkyGolay {
    len: usize,
    matrix: Vec<f64>,
}

impl SavitzkyGolay {
    pub fn new(len: usize, window: usize, order: usize) -> Self {
        let window = window.min(len).max(1);
        let order = order.min(window - 1);
        let mut matrix = vec![0.0; len * len];
        let half = window / 2;
        for k in 0..len {
            let start = k.saturating_sub(half).min(len - window);
            // Vandermonde in the local coordinate s = i − k; the fitted value at k is coefficient 0.
            let a = DMatrix::from_fn(window, order + 1, |r, c| ((start + r) as f64 - k as f64).powi(c as i32));
            let ata = a.transpose() * &a;
            let Some(inv) = ata.try_inverse() else {
                matrix[k * len + k] = 1.0;
                continue;
            };
            let rows = inv * a.transpose(); // (order+1) × window
            for r in 0..window {
                matrix[k * len + start + r] = rows[(0, r)];
            }
        }
        Self { len, matrix }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Smooths `data` (len × dims, row-major) column by column into `out`.
    pub fn apply(&self, data: &[f64], dims: usize, out: &mut [f64]) {
        debug_assert_eq!(data.len(), self.len * dims);
        out.fill(0.0);
        for k in 0..self.len {
            let row = &self.matrix[k * self.len..(k + 1) * self.len];
            for (j, &w) in row.iter().enumerate() {
                if w != 0.0 {
                    for d in 0..dims {
                        out[k * dims + d] += w * data[j * dims + d];
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cubic_polynomials_pass_through_unchanged() {
        let sg = SavitzkyGolay::new(66, 30, 3);
        let data: Vec<f64> = (0..66)
            .map(|i| {
                let t = i as f64 * 0.1;
                0.5 - t + 0.3 * t * t - 0.02 * t * t * t
            })
            .collect();
        let mut out = vec![0.0; 66];
        sg.apply(&data, 1, &mut out);
        for (a, b) in data.iter().zip(&out) {
            assert!((a - b).abs() < 1e-8, "{a} vs {b}");
        }
    }

    #[test]
    fn white_noise_is_attenuated() {
        // Alternating ±1 is the highest frequency; a 30-sample cubic fit removes almost all of it.
        let data: Vec<f64> = (0..66).map(|i| if i % 2 == 0 { 1.0 } else { -1.0 }).collect();
        let mut out = vec![0.0; 66];
        SavitzkyGolay::new(66, 30, 3).apply(&data, 1, &mut out);
        let rms = (out.iter().map(|v| v * v).sum::<f64>() / 66.0).sqrt();
        assert!(rms < 0.2, "rms {rms}");
    }
}
