//! Mapping rollout costs to sample weights (paper Sec. V-B, eq. 55, and Fig. 3).

/// How costs become likelihoods.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LikelihoodMapping {
    /// exp(−λ J): collapses onto one sample at high cost scale.
    Naive { lambda: f64 },
    /// exp(−λ (J − J_min)) (Williams et al.): still scale-dependent.
    Baseline { lambda: f64 },
    /// exp(−h (J − J_min)/(J_max − J_min)) (55): invariant to the cost scale.
    Invariant { h: f64 },
}

/// Normalised weights of `costs`; non-finite costs weigh zero. If no cost is finite, or every finite
/// sample underflows to zero (possible only for the naive mapping), all weights are zero.
pub fn weights(costs: &[f64], mapping: LikelihoodMapping, out: &mut Vec<f64>) {
    out.clear();
    out.resize(costs.len(), 0.0);
    let finite = costs.iter().copied().filter(|c| c.is_finite());
    let (min, max) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), c| (lo.min(c), hi.max(c)));
    if !min.is_finite() {
        return;
    }
    for (w, &c) in out.iter_mut().zip(costs) {
        if !c.is_finite() {
            continue;
        }
        *w = match mapping {
            LikelihoodMapping::Naive { lambda } => (-lambda * c).exp(),
            LikelihoodMapping::Baseline { lambda } => (-lambda * (c - min)).exp(),
            LikelihoodMapping::Invariant { h } => {
                let span = max - min;
                if span > 0.0 && span.is_finite() {
                    (-h * (c - min) / span).exp()
                } else if span > 0.0 {
                    // Costs so far apart that their span overflows (1e308 − (−1e308)): halved, it
                    // cannot, and (55) only sees the ratio.
                    (-h * ((0.5 * c - 0.5 * min) / (0.5 * max - 0.5 * min))).exp()
                } else {
                    1.0
                }
            }
        };
    }
    let sum: f64 = out.iter().sum();
    if sum > 0.0 && sum.is_finite() {
        out.iter_mut().for_each(|w| *w /= sum);
    } else {
        out.iter_mut().for_each(|w| *w = 0.0);
    }
}

/// Effective sample size 1 / Σ w² of normalised weights (0 if all weights are zero).
pub fn effective_sample_size(weights: &[f64]) -> f64 {
    let s: f64 = weights.iter().map(|w| w * w).sum();
    if s > 0.0 {
        1.0 / s
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invariant_weights_do_not_change_with_cost_scale_or_offset() {
        let costs = [3.0, 4.0, 5.5, 7.0];
        let mut a = Vec::new();
        let mut b = Vec::new();
        weights(&costs, LikelihoodMapping::Invariant { h: 10.0 }, &mut a);
        let scaled: Vec<f64> = costs.iter().map(|c| 1e4 * c + 17.0).collect();
        weights(&scaled, LikelihoodMapping::Invariant { h: 10.0 }, &mut b);
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() < 1e-12);
        }
        // exp(−h) between best and worst.
        assert!((a[3] / a[0] - (-10.0f64).exp()).abs() < 1e-12);
    }

    #[test]
    fn non_finite_costs_weigh_zero() {
        let mut w = Vec::new();
        weights(
            &[1.0, f64::NAN, 2.0, f64::INFINITY],
            LikelihoodMapping::Invariant { h: 10.0 },
            &mut w,
        );
        assert_eq!(w[1], 0.0);
        assert_eq!(w[3], 0.0);
        assert!((w[0] + w[2] - 1.0).abs() < 1e-12);
        weights(&[f64::NAN, f64::INFINITY], LikelihoodMapping::Invariant { h: 10.0 }, &mut w);
        assert!(w.iter().all(|&x| x == 0.0));
    }
}
