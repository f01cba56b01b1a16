//! A batch's rows as jobs: each row's input and output slices, taken by exactly one worker, and
//! when the workers stop early.

use std::sync::Mutex;

use super::batch::RolloutBatch;
use crate::interrupt::{Cancel, Poll};

/// A batch's inputs: given, or written row by row by the worker that rolls the row out.
pub(super) enum Inputs<'a> {
    Given(&'a [f64]),
    Filled(&'a mut [f64], &'a (dyn Fn(usize, &mut [f64]) + Sync)),
}

/// One rollout's trajectory: its states (K+1 × nx), τ_ext (K × nq), wrenches (K × 6) and
/// contact flags (K).
pub(super) struct Trajectory<'a> {
    pub(super) states: &'a mut [f64],
    pub(super) tau_ext: &'a mut [f64],
    pub(super) wrench: &'a mut [f64],
    pub(super) contact: &'a mut [bool],
}

/// A worker's own trajectory buffer, for rows whose trajectory the batch does not keep: one
/// rollout's worth, rewritten by each, stays in the worker's cache.
#[derive(Default)]
pub(super) struct ScratchTrajectory {
    states: Vec<f64>,
    tau_ext: Vec<f64>,
    wrench: Vec<f64>,
    contact: Vec<bool>,
}

impl ScratchTrajectory {
    pub(super) fn slices(&mut self, k: usize, nx: usize, nq: usize) -> Trajectory<'_> {
        self.states.resize((k + 1) * nx, 0.0);
        self.tau_ext.resize(k * nq, 0.0);
        self.wrench.resize(k * 6, 0.0);
        self.contact.resize(k, false);
        Trajectory {
            states: &mut self.states,
            tau_ext: &mut self.tau_ext,
            wrench: &mut self.wrench,
            contact: &mut self.contact,
        }
    }
}

/// One row's input: given, or written by `fill(i, row)` on the worker that rolls the row out.
pub(super) enum RowInput<'a> {
    Given(&'a [f64]),
    Filled(&'a mut [f64], usize, &'a (dyn Fn(usize, &mut [f64]) + Sync)),
}

/// One row of a batch: its input and its slices of every output (its trajectory only when the
/// batch keeps trajectories).
pub(super) struct Row<'a> {
    pub(super) input: RowInput<'a>,
    pub(super) trajectory: Option<Trajectory<'a>>,
    pub(super) cost: &'a mut f64,
    pub(super) failed: &'a mut bool,
    pub(super) steps: &'a mut u64,
    pub(super) time: &'a mut f64,
}

/// A batch's rows, each taken by exactly one worker.
pub(super) struct Rows<'a>(Vec<Mutex<Option<Row<'a>>>>);

impl<'a> Rows<'a> {
    pub(super) fn split(inputs: Inputs<'a>, n: usize, k: usize, nq: usize, nx: usize, batch: &'a mut RolloutBatch) -> Self {
        let inputs: Vec<RowInput<'a>> = match inputs {
            Inputs::Given(u) => u.chunks(k * nq).map(RowInput::Given).collect(),
            Inputs::Filled(u, fill) => u
                .chunks_mut(k * nq)
                .enumerate()
                .map(|(i, row)| RowInput::Filled(row, i, fill))
                .collect(),
        };
        let b = batch;
        let trajectories: Vec<Option<Trajectory<'a>>> = if b.states.is_empty() {
            (0..n).map(|_| None).collect()
        } else {
            b.states
                .chunks_mut((k + 1) * nx)
                .zip(b.tau_ext.chunks_mut(k * nq))
                .zip(b.wrench.chunks_mut(k * 6))
                .zip(b.contact.chunks_mut(k))
                .map(|(((states, tau_ext), wrench), contact)| {
                    Some(Trajectory {
                        states,
                        tau_ext,
                        wrench,
                        contact,
                    })
                })
                .collect()
        };
        let rows = inputs
            .into_iter()
            .zip(trajectories)
            .zip(b.failed.iter_mut().zip(b.costs.iter_mut()))
            .zip(b.engine_steps.iter_mut().zip(b.engine_time.iter_mut()))
            .map(|(((input, trajectory), (failed, cost)), (steps, time))| {
                Mutex::new(Some(Row {
                    input,
                    trajectory,
                    cost,
                    failed,
                    steps,
                    time,
                }))
            })
            .collect::<Vec<_>>();
        debug_assert_eq!(rows.len(), n);
        Self(rows)
    }

    pub(super) fn take(&self, i: usize) -> Option<Row<'a>> {
        self.0[i].lock().unwrap_or_else(|e| e.into_inner()).take()
    }
}

/// When a worker stops early: `cancel` set by any worker, or (on the watched calling thread) the
/// embedding's watcher asking to, which sets `cancel` for the others.
pub(super) struct Stop<'a> {
    cancel: &'a Cancel,
    poll: Option<Poll>,
    /// Calls until the watcher's clock is read again: a step is a few µs, the watcher is asked
    /// every 20 ms, so reading the clock on every step would be wasted.
    countdown: u32,
}

/// Calls of [`Stop::now`] between two readings of the watcher's clock.
const POLL_EVERY: u32 = 32;

impl<'a> Stop<'a> {
    pub(super) fn new(cancel: &'a Cancel, caller: bool) -> Self {
        let poll = (caller && crate::interrupt::watched()).then(Poll::new);
        Self {
            cancel,
            poll,
            countdown: 0,
        }
    }

    pub(super) fn now(&mut self) -> bool {
        if self.cancel.is_set() {
            return true;
        }
        let Some(poll) = self.poll.as_mut() else { return false };
        if self.countdown > 0 {
            self.countdown -= 1;
            return false;
        }
        self.countdown = POLL_EVERY;
        if poll.check().is_err() {
            self.cancel.set();
            return true;
        }
        false
    }
}
