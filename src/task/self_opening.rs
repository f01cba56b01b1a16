//! Whether the object, left alone at rest, opens further by itself: the open-object task's probe
//! (one short rollout of the object alone) and the objects it need not run for.

use super::open_object::OpenObjectRules;
use crate::error::Result;
use crate::model::dynamics::gravity_torque;
use crate::model::GRAVITY;

impl OpenObjectRules {
    /// Whether the object, left alone at rest, opens further by itself (a dishwasher door past its
    /// balance point): the probe model run for `probe` s from x with the robot and the object at
    /// rest and the robot out of the way (a holonomic base moved 5 m away from the object; a
    /// fixed-base robot's links out of the contact), its opening rate then above `release_rate`.
    pub fn self_opening(&self, x: &[f64]) -> Result<bool> {
        self.geometry.check_state(x)?;
        let scene = self.geometry.scene();
        let upper = scene.object_limits()[0].upper;
        let nq = scene.nq();
        if self.succeeded(x) || x[2 * nq] >= upper - 1e-3 || self.at_rest_checked(x) {
            return Ok(false);
        }
        self.probe_checked(x)
    }

    /// Whether nothing can set the object, left alone at rest at x's opening, in motion: within its
    /// limits (no limit pushes it back) and with no gravity torque on any of its joints (a door on
    /// a vertical hinge, a drawer sliding level). The probe would see it stay at rest exactly; it is
    /// not run.
    pub fn stays_at_rest(&self, x: &[f64]) -> Result<bool> {
        self.geometry.check_state(x)?;
        Ok(self.at_rest_checked(x))
    }

    /// The probe of [`Self::self_opening`], run.
    pub fn probe_opens(&self, x: &[f64]) -> Result<bool> {
        self.geometry.check_state(x)?;
        self.probe_checked(x)
    }

    /// [`Self::stays_at_rest`] of a state already checked.
    fn at_rest_checked(&self, x: &[f64]) -> bool {
        let scene = self.geometry.scene();
        let (nq, no) = (scene.nq(), scene.no());
        let o = &x[2 * nq..2 * nq + no];
        let within = o
            .iter()
            .zip(scene.object_limits())
            .all(|(&v, limits)| limits.lower <= v && v <= limits.upper);
        within
            && gravity_torque(&scene.object, &scene.object_pose, o, &GRAVITY)
                .iter()
                .all(|&g| g == 0.0)
    }

    /// [`Self::probe_opens`] of a state already checked.
    fn probe_checked(&self, x: &[f64]) -> Result<bool> {
        let scene = self.geometry.scene();
        let (nq, no) = (scene.nq(), scene.no());
        let mut free = x.to_vec();
        if let Some(base) = &scene.roles.base {
            let [ix, iy, _] = base.indices();
            let centre = scene.object_pose.translation.vector;
            let away = [free[ix] - centre.x, free[iy] - centre.y];
            let norm = away[0].hypot(away[1]);
            let unit = if norm > 1e-9 {
                [away[0] / norm, away[1] / norm]
            } else {
                [-1.0, 0.0]
            };
            free[ix] = centre.x + 5.0 * unit[0];
            free[iy] = centre.y + 5.0 * unit[1];
        }
        free[nq..2 * nq].fill(0.0);
        free[2 * nq + no..].fill(0.0); // from rest: a drawer still coasting from a pull does not open by itself
        let steps = ((self.config.probe / self.probe.dt()).round_ties_even() as usize).max(1);
        // One short rollout runs on the calling thread; a probe whose physics diverged does not
        // open by itself.
        let zero = vec![0.0; steps * nq];
        let watched = self.probe.rollout(&free, &zero, 1, steps, Some(1))?;
        let nx = scene.nx();
        Ok(!watched.failed[0] && watched.states[steps * nx + 2 * nq + no] > self.config.release_rate)
    }
}
