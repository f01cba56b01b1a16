//! A plan as the inner loop follows it: the reference sequence on its time grid, the predicted port
//! dissipation for the tank's refill and the gain inertia floor of its task phase, validated once.

use crate::error::{ensure_finite, Result, SabreError};

/// A plan as the inner loop follows it: the reference sequence (K × nu, row-major; row k applies
/// at t0 + k·dt), optionally the port dissipation −τ_extᵀu (W) the rollout model predicts on the
/// same grid (K values, for the tank's refill) and the gain inertia floor of the plan's task
/// phase. Validated on construction and immutable after it: the planner hands a new plan over,
/// the inner loop never edits one.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    reference: Vec<f64>,
    nu: usize,
    t0: f64,
    dt: f64,
    predicted_dissipation: Option<Vec<f64>>,
    gain_inertia_floor: Option<f64>,
}

impl Plan {
    /// The plan of `reference` (K × nu, K ≥ 1, finite) starting at `t0` (finite) with steps of
    /// `dt` (finite, positive).
    pub fn new(reference: Vec<f64>, nu: usize, t0: f64, dt: f64) -> Result<Self> {
        if nu == 0 || reference.is_empty() || !reference.len().is_multiple_of(nu) {
            return Err(SabreError::shape(
                "reference",
                format!("(K, {nu})"),
                format!("{} elements", reference.len()),
            ));
        }
        ensure_finite("reference", &reference)?;
        if !(dt.is_finite() && dt > 0.0 && t0.is_finite()) {
            return Err(SabreError::invalid("reference timing", "t0 must be finite and dt positive"));
        }
        Ok(Self {
            reference,
            nu,
            t0,
            dt,
            predicted_dissipation: None,
            gain_inertia_floor: None,
        })
    }

    /// This plan with the predicted port dissipation `predicted` (K finite values on its grid).
    pub fn with_predicted_dissipation(mut self, predicted: Vec<f64>) -> Result<Self> {
        let k = self.steps();
        if predicted.len() != k {
            return Err(SabreError::shape(
                "predicted_dissipation",
                format!("({k},)"),
                format!("{} elements", predicted.len()),
            ));
        }
        ensure_finite("predicted_dissipation", &predicted)?;
        self.predicted_dissipation = Some(predicted);
        Ok(self)
    }

    /// This plan with the low-level gain inertia floor `floor` (kg m², finite, non-negative) of
    /// its task phase, used instead of the controller's own while the plan is followed.
    pub fn with_gain_inertia_floor(mut self, floor: f64) -> Result<Self> {
        if !(floor.is_finite() && floor >= 0.0) {
            return Err(SabreError::invalid(
                "gain_inertia_floor",
                format!("must be finite and non-negative, got {floor}"),
            ));
        }
        self.gain_inertia_floor = Some(floor);
        Ok(self)
    }

    /// The reference at time `t` into `out` (nu): linear between grid points, held at both ends.
    ///
    /// # Panics
    /// If `out` does not have nu elements.
    pub fn reference_at(&self, t: f64, out: &mut [f64]) {
        assert_eq!(out.len(), self.nu, "reference_at: the output needs nu elements");
        crate::mppi::interpolate(&self.reference, self.nu, self.grid_position(t), out);
    }

    /// The predicted port dissipation (W) at time `t`, interpolated as the reference; None if
    /// the plan has none.
    pub fn predicted_dissipation_at(&self, t: f64) -> Option<f64> {
        let predicted = self.predicted_dissipation.as_deref()?;
        let mut now = [0.0];
        crate::mppi::interpolate(predicted, 1, self.grid_position(t), &mut now);
        Some(now[0])
    }

    /// (t − t0) / dt: the fractional grid index of time t.
    fn grid_position(&self, t: f64) -> f64 {
        (t - self.t0) / self.dt
    }

    /// K × nu, row-major.
    pub fn reference(&self) -> &[f64] {
        &self.reference
    }
    pub fn nu(&self) -> usize {
        self.nu
    }
    /// K, the number of grid points.
    pub fn steps(&self) -> usize {
        self.reference.len() / self.nu
    }
    pub fn t0(&self) -> f64 {
        self.t0
    }
    pub fn dt(&self) -> f64 {
        self.dt
    }
    pub fn predicted_dissipation(&self) -> Option<&[f64]> {
        self.predicted_dissipation.as_deref()
    }
    pub fn gain_inertia_floor(&self) -> Option<f64> {
        self.gain_inertia_floor
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// K = 3 rows of nu = 2 on the grid t = 1.0, 1.5, 2.0.
    fn small_plan() -> Plan {
        Plan::new(vec![0.0, 10.0, 1.0, 20.0, 3.0, 40.0], 2, 1.0, 0.5).unwrap()
    }

    fn reference_at(plan: &Plan, t: f64) -> Vec<f64> {
        let mut out = vec![0.0; plan.nu()];
        plan.reference_at(t, &mut out);
        out
    }

    #[test]
    fn a_plan_is_its_rows_on_the_grid_linear_between_and_held_outside() {
        let plan = small_plan().with_predicted_dissipation(vec![1.0, 2.0, 4.0]).unwrap();
        assert_eq!((plan.steps(), plan.nu(), plan.t0(), plan.dt()), (3, 2, 1.0, 0.5));
        assert_eq!(reference_at(&plan, 1.0), [0.0, 10.0]);
        assert_eq!(reference_at(&plan, 1.5), [1.0, 20.0]);
        assert_eq!(reference_at(&plan, 2.0), [3.0, 40.0]);
        assert_eq!(reference_at(&plan, 1.25), [0.5, 15.0]);
        assert_eq!(reference_at(&plan, 1.75), [2.0, 30.0]);
        assert_eq!(reference_at(&plan, -3.0), [0.0, 10.0]);
        assert_eq!(reference_at(&plan, 9.0), [3.0, 40.0]);
        assert_eq!(plan.predicted_dissipation_at(1.5), Some(2.0));
        assert_eq!(plan.predicted_dissipation_at(1.25), Some(1.5));
        assert_eq!(plan.predicted_dissipation_at(0.0), Some(1.0));
        assert_eq!(plan.predicted_dissipation_at(7.0), Some(4.0));
        assert_eq!(small_plan().predicted_dissipation_at(1.25), None);
        assert_eq!(small_plan().gain_inertia_floor(), None);
        assert_eq!(
            small_plan().with_gain_inertia_floor(0.3).unwrap().gain_inertia_floor(),
            Some(0.3)
        );
        let single = Plan::new(vec![2.0, -1.0], 2, 0.0, 0.1).unwrap();
        assert_eq!(reference_at(&single, 0.05), [2.0, -1.0]);
        assert_eq!(reference_at(&single, -1.0), [2.0, -1.0]);
    }

    #[test]
    fn a_plan_rejects_bad_shapes_timing_and_values() {
        let shape = |r: Result<Plan>| matches!(r, Err(SabreError::Shape { .. }));
        let invalid = |r: Result<Plan>| matches!(r, Err(SabreError::InvalidValue { .. }));
        assert!(shape(Plan::new(vec![], 2, 0.0, 0.1)));
        assert!(shape(Plan::new(vec![1.0, 2.0, 3.0], 2, 0.0, 0.1)));
        assert!(shape(Plan::new(vec![1.0, 2.0], 0, 0.0, 0.1)));
        assert!(invalid(Plan::new(vec![1.0, f64::NAN], 2, 0.0, 0.1)));
        assert!(invalid(Plan::new(vec![1.0, f64::INFINITY], 2, 0.0, 0.1)));
        for dt in [0.0, -0.1, f64::NAN, f64::INFINITY] {
            assert!(invalid(Plan::new(vec![1.0, 2.0], 2, 0.0, dt)), "dt = {dt}");
        }
        for t0 in [f64::NAN, f64::NEG_INFINITY] {
            assert!(invalid(Plan::new(vec![1.0, 2.0], 2, t0, 0.1)), "t0 = {t0}");
        }
        assert!(shape(small_plan().with_predicted_dissipation(vec![1.0, 2.0])));
        assert!(shape(small_plan().with_predicted_dissipation(vec![1.0; 4])));
        assert!(invalid(small_plan().with_predicted_dissipation(vec![1.0, f64::NAN, 2.0])));
        for floor in [-0.1, f64::NAN, f64::INFINITY] {
            assert!(invalid(small_plan().with_gain_inertia_floor(floor)), "floor = {floor}");
        }
    }
}
