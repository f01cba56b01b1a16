//! The batch rollouts' failure handling: non-finite physics, panics, reused batches.

use super::*;
use crate::model::scene::Scene;
use crate::sim::evaluator::{StepEvaluator, StepView};
use crate::sim::test_scene::{probe_and_drawer, state};

/// A command value that makes the physics of its step report non-finite numbers (test builds only).
pub(crate) const NON_FINITE_COMMAND: f64 = 0.123_456_789;

pub(super) fn inject_failure(u: &[f64], x: &mut [f64]) {
    if u[0] == NON_FINITE_COMMAND {
        x[0] = f64::NAN;
    }
}

#[test]
fn contact_models_are_found_by_their_names_and_an_unknown_name_lists_the_choices() {
    assert_eq!(ContactModel::from_name("reduced").unwrap(), ContactModel::Reduced);
    assert_eq!(ContactModel::from_name("rapier").unwrap(), ContactModel::Rapier);
    assert_eq!(ContactModel::ALL[0], RolloutConfig::default().contact_model);
    match ContactModel::from_name("mujoco") {
        Err(SabreError::InvalidValue { what, detail }) => {
            assert_eq!(what, "contact_model");
            assert!(
                detail.contains("'reduced'") && detail.contains("'rapier'") && detail.contains("'mujoco'"),
                "{detail}"
            );
        }
        other => panic!("expected an invalid value, got {other:?}"),
    }
}

/// Scores a step by its state and command; panics on a command of `panic_on` in joint 0.
struct Probe {
    panic_on: f64,
}

impl StepEvaluator for Probe {
    fn validate(&self, _: &Scene) -> Result<()> {
        Ok(())
    }
    fn needs_object_frames(&self) -> bool {
        false
    }
    fn evaluate(&self, _: &Scene, view: &StepView) -> f64 {
        assert!(view.u[0] != self.panic_on, "evaluator fault");
        view.x[0] * view.x[0] + view.u[1].abs()
    }
}

const N: usize = 4;
const K: usize = 8;

fn inputs() -> Vec<f64> {
    (0..N * K * 2).map(|e| 0.3 * ((e as f64) * 0.7).sin()).collect()
}

fn batch(u: &[f64], evaluator: &Probe) -> RolloutBatch {
    let model = RolloutModel::new(probe_and_drawer(), RolloutConfig::default()).expect("model");
    let x0 = state([0.3, 0.0], [0.0, 0.0], 0.0, 0.0);
    model
        .rollout_with_cost(&x0, u, N, K, Some(2), Some(evaluator))
        .expect("batch")
}

/// Rollout `i` of two batches is the same, bit for bit.
fn same_rollout(a: &RolloutBatch, b: &RolloutBatch, i: usize) -> bool {
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let (nx, nq) = (a.nx, a.nq);
    bits(&a.states[i * (K + 1) * nx..(i + 1) * (K + 1) * nx]) == bits(&b.states[i * (K + 1) * nx..(i + 1) * (K + 1) * nx])
        && bits(&a.tau_ext[i * K * nq..(i + 1) * K * nq]) == bits(&b.tau_ext[i * K * nq..(i + 1) * K * nq])
        && bits(&a.wrench[i * K * 6..(i + 1) * K * 6]) == bits(&b.wrench[i * K * 6..(i + 1) * K * 6])
        && a.contact[i * K..(i + 1) * K] == b.contact[i * K..(i + 1) * K]
        && a.costs[i].to_bits() == b.costs[i].to_bits()
}

/// Asserts rollout `i` is marked failed at `step`: +∞ cost, outputs NaN from that step, no contact.
fn assert_failed_at(batch: &RolloutBatch, clean: &RolloutBatch, i: usize, step: usize) {
    let (nx, nq) = (batch.nx, batch.nq);
    assert!(batch.failed[i]);
    assert_eq!(batch.costs[i], f64::INFINITY);
    let states = &batch.states[i * (K + 1) * nx..(i + 1) * (K + 1) * nx];
    assert_eq!(
        states[..(step + 1) * nx],
        clean.states[i * (K + 1) * nx..i * (K + 1) * nx + (step + 1) * nx]
    );
    assert!(states[(step + 1) * nx..].iter().all(|v| v.is_nan()));
    assert!(batch.tau_ext[i * K * nq..(i + 1) * K * nq][step * nq..]
        .iter()
        .all(|v| v.is_nan()));
    assert!(batch.wrench[i * K * 6..(i + 1) * K * 6][step * 6..]
        .iter()
        .all(|v| v.is_nan()));
    assert!(batch.contact[i * K..(i + 1) * K][step..].iter().all(|c| !c));
}

#[test]
fn non_finite_physics_fails_that_rollout_alone() {
    let probe = Probe { panic_on: f64::NAN };
    let u = inputs();
    let clean = batch(&u, &probe);
    assert!(clean.failed.iter().all(|f| !f) && clean.costs.iter().all(|c| c.is_finite()));
    let mut poisoned = u.clone();
    poisoned[(2 * K + 3) * 2] = NON_FINITE_COMMAND;
    let failing = batch(&poisoned, &probe);
    assert_eq!(failing.failed, vec![false, false, true, false]);
    assert_failed_at(&failing, &clean, 2, 3);
    for i in [0, 1, 3] {
        assert!(same_rollout(&failing, &clean, i), "rollout {i} changed");
    }
    let mut w = Vec::new();
    crate::mppi::weights(&failing.costs, crate::mppi::LikelihoodMapping::Invariant { h: 10.0 }, &mut w);
    assert_eq!(w[2], 0.0);
    assert!(w.iter().enumerate().all(|(i, &v)| i == 2 || v > 0.0));
    assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
}

#[test]
fn panic_inside_a_rollout_fails_it_from_the_first_step() {
    let u = inputs();
    let clean = batch(&u, &Probe { panic_on: f64::NAN });
    let mut poisoned = u.clone();
    let fault = 0.0625;
    poisoned[(K + 5) * 2] = fault;
    let failing = batch(&poisoned, &Probe { panic_on: fault });
    assert_eq!(failing.failed, vec![false, true, false, false]);
    assert_failed_at(&failing, &clean, 1, 0);
    for i in [0, 2, 3] {
        assert!(same_rollout(&failing, &clean, i), "rollout {i} changed");
    }
}

#[test]
fn a_single_rollout_run_on_the_calling_thread_matches_its_row_of_a_batch_and_keeps_a_panic_inside() {
    let probe = Probe { panic_on: 0.0625 };
    let model = RolloutModel::new(probe_and_drawer(), RolloutConfig::default()).expect("model");
    let x0 = state([0.3, 0.0], [0.0, 0.0], 0.0, 0.0);
    let u = inputs();
    let clean = batch(&u, &Probe { panic_on: f64::NAN });
    let row = &u[2 * K * 2..3 * K * 2];
    let single = model
        .rollout_with_cost(&x0, row, 1, K, Some(2), Some(&probe))
        .expect("single");
    let nx = single.nx;
    assert_eq!(single.states, clean.states[2 * (K + 1) * nx..3 * (K + 1) * nx]);
    assert_eq!(single.tau_ext, clean.tau_ext[2 * K * single.nq..3 * K * single.nq]);
    assert_eq!((single.costs[0], single.failed[0]), (clean.costs[2], false));
    let mut poisoned = row.to_vec();
    poisoned[5 * 2] = 0.0625;
    let failing = model
        .rollout_with_cost(&x0, &poisoned, 1, K, Some(2), Some(&probe))
        .expect("failing");
    assert!(failing.failed[0] && failing.costs[0] == f64::INFINITY);
    assert!(failing.states[nx..].iter().all(|v| v.is_nan()));
}

#[test]
fn a_reused_batch_holds_what_a_fresh_one_would_after_failures_and_other_sizes() {
    let probe = Probe { panic_on: f64::NAN };
    let model = RolloutModel::new(probe_and_drawer(), RolloutConfig::default()).expect("model");
    let x0 = state([0.3, 0.0], [0.0, 0.0], 0.0, 0.0);
    let u = inputs();
    let clean = batch(&u, &probe);
    let mut poisoned = u.clone();
    poisoned[(2 * K + 3) * 2] = NON_FINITE_COMMAND;
    let mut reused = RolloutBatch::default();
    // A failing batch, a smaller one, then the full clean one into the same buffers.
    model
        .rollout_into(&x0, &poisoned, N, K, Some(2), Some(&probe), &mut reused)
        .expect("failing");
    assert!(reused.failed[2]);
    let half = &u[..2 * K * 2];
    model
        .rollout_into(&x0, half, 2, K, Some(1), Some(&probe), &mut reused)
        .expect("smaller");
    assert_eq!(
        (reused.n, reused.states.len(), reused.failed.len()),
        (2, 2 * (K + 1) * reused.nx, 2)
    );
    for i in 0..2 {
        assert!(same_rollout(&reused, &clean, i), "rollout {i} of the smaller batch");
    }
    model
        .rollout_into(&x0, &u, N, K, Some(2), Some(&probe), &mut reused)
        .expect("clean");
    assert_eq!(
        (reused.failed.as_slice(), reused.engine_steps.as_slice()),
        (clean.failed.as_slice(), clean.engine_steps.as_slice())
    );
    assert_eq!(reused.states.len(), clean.states.len());
    for i in 0..N {
        assert!(same_rollout(&reused, &clean, i), "rollout {i} of the reused batch");
    }
}

#[test]
fn inputs_filled_by_the_workers_roll_out_as_the_same_inputs_given() {
    let model = RolloutModel::new(probe_and_drawer(), RolloutConfig::default()).expect("model");
    let x0 = state([0.3, 0.0], [0.0, 0.0], 0.0, 0.0);
    let given = inputs();
    let row = K * 2;
    let fill = |i: usize, out: &mut [f64]| out.copy_from_slice(&given[i * row..(i + 1) * row]);
    for (n, threads) in [(N, 1), (N, 2), (1, 2)] {
        let mut expected = RolloutBatch::default();
        model
            .rollout_into(&x0, &given[..n * row], n, K, Some(threads), None, &mut expected)
            .unwrap();
        let mut filled = vec![f64::NAN; n * row];
        let mut batch = RolloutBatch::default();
        model
            .rollout_filled_into(&x0, &mut filled, &fill, n, K, Some(threads), None, true, &mut batch)
            .unwrap();
        assert_eq!(filled, given[..n * row], "{n} rollouts on {threads} threads");
        assert!(
            (0..n).all(|i| same_rollout(&batch, &expected, i)),
            "{n} rollouts on {threads} threads"
        );
    }
}

/// Scores a step by its state's squared norm.
struct SquaredState;

impl StepEvaluator for SquaredState {
    fn validate(&self, _: &Scene) -> Result<()> {
        Ok(())
    }
    fn needs_object_frames(&self) -> bool {
        false
    }
    fn evaluate(&self, _: &Scene, view: &StepView) -> f64 {
        view.x.iter().map(|v| v * v).sum()
    }
}

#[test]
fn a_batch_for_its_costs_alone_has_the_costs_of_one_that_keeps_its_trajectories() {
    let model = RolloutModel::new(probe_and_drawer(), RolloutConfig::default()).expect("model");
    let x0 = state([0.3, 0.0], [0.0, 0.0], 0.0, 0.0);
    let given = inputs();
    let row = K * 2;
    let fill = |i: usize, out: &mut [f64]| out.copy_from_slice(&given[i * row..(i + 1) * row]);
    for threads in [1, 2] {
        let mut kept = RolloutBatch::default();
        let mut alone = RolloutBatch::default();
        for (trajectories, batch) in [(true, &mut kept), (false, &mut alone)] {
            let mut u = vec![0.0; N * row];
            model
                .rollout_filled_into(
                    &x0,
                    &mut u,
                    &fill,
                    N,
                    K,
                    Some(threads),
                    Some(&SquaredState),
                    trajectories,
                    batch,
                )
                .unwrap();
        }
        // The sum the evaluator gives, from the kept states: the costs are those of the rollouts.
        let nx = kept.nx;
        for i in 0..N {
            let states = &kept.states[i * (K + 1) * nx..(i + 1) * (K + 1) * nx];
            let expected: f64 = states[nx..].iter().map(|v| v * v).sum();
            assert!((kept.costs[i] - expected).abs() <= 1e-9 * expected.max(1.0), "rollout {i}");
        }
        assert_eq!(alone.costs, kept.costs, "{threads} threads");
        assert_eq!(alone.failed, kept.failed);
        assert_eq!(alone.engine_steps, kept.engine_steps);
        assert!(alone.states.is_empty() && alone.tau_ext.is_empty() && alone.wrench.is_empty() && alone.contact.is_empty());
        // The same batch keeps its trajectories again when asked to.
        let mut u = vec![0.0; N * row];
        model
            .rollout_filled_into(&x0, &mut u, &fill, N, K, Some(threads), Some(&SquaredState), true, &mut alone)
            .unwrap();
        assert_eq!(alone.states, kept.states);
    }
}

/// Records the threads that evaluate steps.
#[derive(Default)]
struct Threads(Mutex<std::collections::HashSet<std::thread::ThreadId>>);

impl StepEvaluator for Threads {
    fn validate(&self, _: &Scene) -> Result<()> {
        Ok(())
    }
    fn needs_object_frames(&self) -> bool {
        false
    }
    fn evaluate(&self, _: &Scene, _: &StepView) -> f64 {
        self.0.lock().unwrap().insert(std::thread::current().id());
        0.0
    }
}

#[test]
fn the_calling_thread_rolls_out_alone_on_one_thread_and_is_one_of_the_workers_on_more() {
    let model = RolloutModel::new(probe_and_drawer(), RolloutConfig::default()).expect("model");
    let x0 = state([0.3, 0.0], [0.0, 0.0], 0.0, 0.0);
    let u = inputs();
    let caller = std::thread::current().id();
    let one = Threads::default();
    model.rollout_with_cost(&x0, &u, N, K, Some(1), Some(&one)).unwrap();
    assert_eq!(one.0.lock().unwrap().iter().copied().collect::<Vec<_>>(), vec![caller]);
    let two = Threads::default();
    model.rollout_with_cost(&x0, &u, N, K, Some(2), Some(&two)).unwrap();
    let seen = two.0.lock().unwrap();
    assert!((1..=2).contains(&seen.len()), "{} threads for a batch on 2", seen.len());
}

#[test]
fn rows_are_handed_out_longest_first_and_the_order_changes_no_result() {
    let probe = Probe { panic_on: f64::NAN };
    let model = RolloutModel::new(probe_and_drawer(), RolloutConfig::default()).expect("model");
    let x0 = state([0.3, 0.0], [0.0, 0.0], 0.0, 0.0);
    let u = inputs();
    let clean = batch(&u, &probe);
    assert_eq!(model.row_order(N), (0..N).collect::<Vec<_>>(), "no batch yet: in order");
    model.rollout_with_cost(&x0, &u, N, K, Some(2), Some(&probe)).unwrap();
    {
        let last = model.row_seconds.lock().unwrap();
        assert!(last.len() == N && last.iter().all(|&s| s > 0.0), "{last:?}");
    }
    // A single rollout (a task's probe) keeps the times of the last batch.
    model
        .rollout_with_cost(&x0, &u[..K * 2], 1, K, Some(2), Some(&probe))
        .unwrap();
    assert_eq!(model.row_seconds.lock().unwrap().len(), N);
    // Times of an earlier batch order the next one of that size, longest first; another size in order.
    model.remember_row_seconds([0.1, 0.4, 0.2, 0.3].into_iter());
    assert_eq!(model.row_order(N), vec![1, 3, 2, 0]);
    assert_eq!(model.row_order(3), vec![0, 1, 2]);
    for threads in [1, 2] {
        model.remember_row_seconds([0.1, 0.2, 0.3, 0.4].into_iter());
        assert_eq!(model.row_order(N), vec![3, 2, 1, 0]);
        let reordered = model.rollout_with_cost(&x0, &u, N, K, Some(threads), Some(&probe)).unwrap();
        for i in 0..N {
            assert!(
                same_rollout(&reordered, &clean, i),
                "rollout {i} on {threads} threads, last row first"
            );
        }
    }
}
