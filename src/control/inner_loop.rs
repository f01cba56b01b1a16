//! One step of the inner loop (the 1 kHz tick): a plan interpolated at the measured time, the
//! optional safety stage (FILTER-QP, energy tank and its refill), the low-level torque.

use crate::error::{ensure_finite, ensure_len, Result, SabreError};
use crate::safety::{EnergyTank, FilterStatus, SafetyFilter};

use super::low_level::LowLevelController;

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

/// What one tick produced; the buffers are reused from tick to tick.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TickOutput {
    /// The plan's reference at the tick's time (nu).
    pub reference: Vec<f64>,
    /// The command after the filter (nu): the reference itself without a filter.
    pub command: Vec<f64>,
    /// The low-level controller's joint torques tracking the command (nq).
    pub torque: Vec<f64>,
    /// The tank's energy after the tick (J); None without a tank.
    pub tank_energy: Option<f64>,
    /// The filter's status; None without a filter.
    pub status: Option<FilterStatus>,
}

impl TickOutput {
    /// Buffers for a robot with nu inputs and nq joints.
    pub fn new(nu: usize, nq: usize) -> Self {
        Self {
            reference: vec![0.0; nu],
            command: vec![0.0; nu],
            torque: vec![0.0; nq],
            tank_energy: None,
            status: None,
        }
    }

    /// The filter status's name, or "unfiltered" without a filter.
    pub fn status_name(&self) -> &'static str {
        self.status.map_or("unfiltered", FilterStatus::name)
    }
}

/// The inner loop's stages for one tick, borrowed from their owners: the low-level controller
/// and the optional FILTER-QP and energy tank.
pub struct InnerLoop<'a> {
    controller: &'a mut LowLevelController,
    filter: Option<&'a mut SafetyFilter>,
    tank: Option<&'a mut EnergyTank>,
}

impl<'a> InnerLoop<'a> {
    /// The stages of one inner loop; the filter must be built for the controller's scene.
    pub fn new(
        controller: &'a mut LowLevelController,
        filter: Option<&'a mut SafetyFilter>,
        tank: Option<&'a mut EnergyTank>,
    ) -> Result<Self> {
        if let Some(f) = &filter {
            let (ours, theirs) = (controller.scene(), f.scene());
            if ours.nq() != theirs.nq() || ours.nx() != theirs.nx() {
                return Err(SabreError::invalid(
                    "safety filter",
                    "was built for a different scene than the low-level controller's",
                ));
            }
        }
        Ok(Self {
            controller,
            filter,
            tank,
        })
    }

    /// One inner-loop step at the measured state `x` (nx) and external torques `tau_ext` (nq) at
    /// time `t`, integrating the tank over `dt` (s): the plan's reference at t → FILTER-QP, with the
    /// passivity row (56) fed by `tau_ext` and the tank's energy when there is a tank → the tank's
    /// refill (when it has one configured and the plan a predicted dissipation) → the tank step
    /// (49) with `tau_ext` and the filtered command → the low-level torque (53) with the plan's
    /// gain inertia floor, else the controller's own. Writes `out`.
    ///
    /// The tank is integrated with the same measurement the passivity row saw and the command the
    /// filter returned, S ← S + dt τ̂ᵀu, as a controller on a real robot must (it cannot know the
    /// next reading): a row met without slack then keeps S above its floor in discrete time.
    /// Every input is checked before any stage changes state.
    pub fn tick(&mut self, plan: &Plan, x: &[f64], tau_ext: &[f64], t: f64, dt: f64, out: &mut TickOutput) -> Result<()> {
        let scene = self.controller.scene();
        let nq = scene.nq();
        scene.check_state(x)?;
        ensure_len("tau_ext", tau_ext, nq)?;
        ensure_finite("tau_ext", tau_ext)?;
        if !t.is_finite() {
            return Err(SabreError::invalid("t", format!("must be finite, got {t}")));
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(SabreError::invalid("dt", format!("must be finite and positive, got {dt}")));
        }
        if plan.nu() != nq {
            return Err(SabreError::shape(
                "plan",
                format!("(K, {nq})"),
                format!("({}, {})", plan.steps(), plan.nu()),
            ));
        }
        out.reference.resize(nq, 0.0);
        out.command.resize(nq, 0.0);
        out.torque.resize(nq, 0.0);
        plan.reference_at(t, &mut out.reference);
        match self.filter.as_deref_mut() {
            Some(filter) => {
                let passivity = self.tank.as_ref().map(|tank| (tau_ext, tank.energy()));
                let filtered = filter.filter(x, &out.reference, passivity)?;
                out.command.copy_from_slice(&filtered.u);
                out.status = Some(filtered.status);
            }
            None => {
                out.command.copy_from_slice(&out.reference);
                out.status = None;
            }
        }
        out.tank_energy = match self.tank.as_deref_mut() {
            Some(tank) => {
                if let Some(predicted) = plan.predicted_dissipation_at(t).filter(|_| tank.refill_config().is_some()) {
                    // Against the reference, not the filtered command: the test is whether the world
                    // pushes back as the model predicted, whatever the passivity row let through.
                    let measured = -EnergyTank::power(tau_ext, &out.reference);
                    tank.refill(predicted, measured, dt)?;
                }
                Some(tank.step(tau_ext, &out.command, dt)?)
            }
            None => None,
        };
        let floor = plan
            .gain_inertia_floor()
            .unwrap_or(self.controller.config().gain_inertia_floor);
        self.controller.torque_into(x, &out.command, floor, &mut out.torque)
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::control::LowLevelConfig;
    use crate::model::scene::Scene;
    use crate::safety::{RefillConfig, SafetyConfig};

    fn scene() -> Arc<Scene> {
        Arc::new(Scene::load("royalpanda", "shelf", None).expect("built-in scene loads"))
    }

    fn controller(scene: &Arc<Scene>) -> LowLevelController {
        LowLevelController::new(scene.clone(), 0.001, LowLevelConfig::default()).unwrap()
    }

    /// K = 3 rows of nu = 2 on the grid t = 1.0, 1.5, 2.0.
    fn small_plan() -> Plan {
        Plan::new(vec![0.0, 10.0, 1.0, 20.0, 3.0, 40.0], 2, 1.0, 0.5).unwrap()
    }

    /// A reference (K × nq) whose every row moves each joint a little, different per row.
    fn moving_reference(nq: usize, k: usize) -> Vec<f64> {
        (0..k * nq)
            .map(|i| 0.05 * ((i % nq) as f64 - 4.0) + 0.01 * (i / nq) as f64)
            .collect()
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

    #[test]
    fn a_tick_without_filter_or_tank_is_the_torque_of_the_interpolated_reference() {
        let scene = scene();
        let (nq, x) = (scene.nq(), scene.default_state());
        let plan = Plan::new(moving_reference(nq, 5), nq, 0.2, 0.015).unwrap();
        let (mut ticked, mut by_hand) = (controller(&scene), controller(&scene));
        let mut inner = InnerLoop::new(&mut ticked, None, None).unwrap();
        let mut out = TickOutput::new(nq, nq);
        // Two ticks: the second one has the reference's feed-forward from the first.
        for t in [0.2071, 0.2082] {
            inner.tick(&plan, &x, &vec![0.3; nq], t, 0.001, &mut out).unwrap();
            let reference = reference_at(&plan, t);
            assert_ne!(reference, reference_at(&plan, 0.2), "between grid points");
            assert_eq!(out.reference, reference);
            assert_eq!(out.command, reference);
            assert_eq!(out.torque, by_hand.torque(&x, &reference).unwrap());
            assert_eq!((out.tank_energy, out.status, out.status_name()), (None, None, "unfiltered"));
        }
    }

    #[test]
    fn a_tick_uses_the_plans_gain_floor_else_the_controllers_own() {
        let scene = scene();
        let (nq, x) = (scene.nq(), scene.default_state());
        let own = LowLevelConfig {
            gain_inertia_floor: 0.02,
            ..LowLevelConfig::default()
        };
        let reference = moving_reference(nq, 2);
        let t = 0.004;
        let floors = [None, Some(0.5)];
        let mut torques = Vec::new();
        for floor in floors {
            let mut plan = Plan::new(reference.clone(), nq, 0.0, 0.01).unwrap();
            if let Some(f) = floor {
                plan = plan.with_gain_inertia_floor(f).unwrap();
            }
            let mut ticked = LowLevelController::new(scene.clone(), 0.001, own.clone()).unwrap();
            let mut by_hand = LowLevelController::new(scene.clone(), 0.001, own.clone()).unwrap();
            let mut out = TickOutput::new(nq, nq);
            InnerLoop::new(&mut ticked, None, None)
                .unwrap()
                .tick(&plan, &x, &vec![0.0; nq], t, 0.001, &mut out)
                .unwrap();
            let mut expected = vec![0.0; nq];
            by_hand
                .torque_into(&x, &reference_at(&plan, t), floor.unwrap_or(0.02), &mut expected)
                .unwrap();
            assert_eq!(out.torque, expected);
            assert_eq!(ticked.config().gain_inertia_floor, 0.02, "the plan's floor is not kept");
            torques.push(out.torque);
        }
        assert_ne!(torques[0], torques[1], "the light wrist joints feel the plan's floor");
    }

    #[test]
    fn a_tick_refills_and_steps_the_tank_as_by_hand() {
        let scene = scene();
        let (nq, x) = (scene.nq(), scene.default_state());
        let reference = moving_reference(nq, 4);
        // τ_ext = −0.5 u_ref: the robot pushes, dissipating 0.5 |u_ref|², which the plan predicts.
        let predicted: Vec<f64> = reference
            .chunks(nq)
            .map(|r| 0.5 * r.iter().map(|v| v * v).sum::<f64>())
            .collect();
        let plan = Plan::new(reference, nq, 0.0, 0.01)
            .unwrap()
            .with_predicted_dissipation(predicted)
            .unwrap();
        let new_tank = || {
            let mut tank = EnergyTank::new(3.0, 2.0, None, false).unwrap();
            tank.set_refill(Some(RefillConfig::default())).unwrap();
            tank
        };
        let (mut tank, mut by_hand) = (new_tank(), new_tank());
        let mut low = controller(&scene);
        let mut inner = InnerLoop::new(&mut low, None, Some(&mut tank)).unwrap();
        let mut out = TickOutput::new(nq, nq);
        let dt = 0.002;
        for step in 0..20 {
            let t = 0.0013 + step as f64 * dt;
            let u_ref = reference_at(&plan, t);
            let tau_ext: Vec<f64> = u_ref.iter().map(|u| -0.5 * u).collect();
            inner.tick(&plan, &x, &tau_ext, t, dt, &mut out).unwrap();
            by_hand
                .refill(
                    plan.predicted_dissipation_at(t).unwrap(),
                    -EnergyTank::power(&tau_ext, &u_ref),
                    dt,
                )
                .unwrap();
            let expected = by_hand.step(&tau_ext, &u_ref, dt).unwrap();
            assert_eq!(out.tank_energy, Some(expected), "step {step}");
        }
        assert!(by_hand.refilled() > 0.0, "the refill ran");
        assert!(by_hand.energy() < 3.0, "the tank drained");
        assert_eq!(tank.energy(), by_hand.energy());
        assert_eq!(tank.refilled(), by_hand.refilled());
    }

    #[test]
    fn a_tick_checks_its_inputs_before_changing_anything() {
        let scene = scene();
        let (nq, x) = (scene.nq(), scene.default_state());
        let plan = Plan::new(moving_reference(nq, 3), nq, 0.0, 0.01).unwrap();
        let mut low = controller(&scene);
        let mut filter = SafetyFilter::new(scene.clone(), SafetyConfig::default()).unwrap();
        let mut tank = EnergyTank::new(10.0, 2.0, None, true).unwrap();
        let mut inner = InnerLoop::new(&mut low, Some(&mut filter), Some(&mut tank)).unwrap();
        let mut out = TickOutput::new(nq, nq);
        let tau = vec![0.0; nq];
        let mut nan_tau = tau.clone();
        nan_tau[1] = f64::NAN;
        let other = Plan::new(vec![0.0; 3 * (nq - 1)], nq - 1, 0.0, 0.01).unwrap();
        let shape = |r: Result<()>| matches!(r, Err(SabreError::Shape { .. }));
        let invalid = |r: Result<()>| matches!(r, Err(SabreError::InvalidValue { .. }));
        assert!(shape(inner.tick(&plan, &x[1..], &tau, 0.0, 0.001, &mut out)));
        assert!(shape(inner.tick(&plan, &x, &tau[1..], 0.0, 0.001, &mut out)));
        assert!(shape(inner.tick(&other, &x, &tau, 0.0, 0.001, &mut out)));
        assert!(invalid(inner.tick(&plan, &x, &nan_tau, 0.0, 0.001, &mut out)));
        assert!(invalid(inner.tick(&plan, &x, &tau, f64::NAN, 0.001, &mut out)));
        for dt in [0.0, -0.001, f64::INFINITY] {
            assert!(invalid(inner.tick(&plan, &x, &tau, 0.0, dt, &mut out)), "dt = {dt}");
        }
        inner.tick(&plan, &x, &tau, 0.0, 0.001, &mut out).unwrap();
        assert_eq!(out.status_name(), "solved");
        assert_eq!(out.tank_energy, Some(10.0));
        assert_eq!(filter.stats().calls, 1, "only the good tick reached the filter");
        assert_eq!(tank.history().len(), 2, "only the good tick stepped the tank");
    }

    #[test]
    fn an_inner_loop_rejects_a_filter_built_for_another_robot() {
        let probe = crate::sim::test_scene::probe_and_drawer();
        let mut low = controller(&probe);
        let mut filter = SafetyFilter::new(scene(), SafetyConfig::default()).unwrap();
        assert!(matches!(
            InnerLoop::new(&mut low, Some(&mut filter), None),
            Err(SabreError::InvalidValue { .. })
        ));
    }
}
