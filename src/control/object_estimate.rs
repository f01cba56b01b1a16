//! The object's joint coordinate and rate inferred from the robot's joint positions while the hand
//! holds the handle (no door sensor): the hook and release tests, a Gauss–Newton fit of the
//! coordinate and a low-passed rate, cheap enough for a 1 kHz loop (no allocation per update).

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Vector3};

use crate::error::{ensure_coordinates, ensure_len, Result, SabreError};
use crate::model::kinematics::Frames;
use crate::model::Scene;

/// Gauss–Newton iterations per fit: from the previous estimate one step of a 1 kHz loop away, two
/// already reach the rounding floor.
const FIT_ITERATIONS: usize = 4;
/// A fit step below this (m or rad) has converged.
const FIT_TOLERANCE: f64 = 1e-7;
/// Coordinates sampled over the range when the estimate looks for the handle at the hand.
const REACQUIRE_SAMPLES: usize = 64;
/// Below this squared length of dp/do (m²) the hook point does not move with the object (it sits
/// on a hinge's axis) and the fit keeps its estimate.
const FLAT_GRADIENT: f64 = 1e-12;

/// When the estimator hooks and releases, and how it smooths the rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectEstimatorConfig {
    /// A hook needs the hand frame within this distance of the handle frame (m, positive).
    pub hook_distance: f64,
    /// A fit still this far from the hand point across the bar (m, positive) releases: the hand
    /// left the handle.
    pub release_distance: f64,
    /// A hook that slid this far along the bar from where it hooked (m, positive) releases: it
    /// came off the bar's end.
    pub slide_distance: f64,
    /// The wrist force magnitude (N, ≥ 0) that counts as contact.
    pub contact_force: f64,
    /// Without contact for longer than this (s, ≥ 0) the hook releases.
    pub release_time: f64,
    /// Cutoff (Hz, positive) of the first-order low-pass on the rate's difference quotient.
    pub rate_cutoff: f64,
}

impl Default for ObjectEstimatorConfig {
    fn default() -> Self {
        Self {
            hook_distance: 0.08,
            release_distance: 0.04,
            slide_distance: 0.1,
            contact_force: 0.2,
            release_time: 0.5,
            rate_cutoff: 5.0,
        }
    }
}

impl ObjectEstimatorConfig {
    /// A checked config: distances and the cutoff finite and positive, force and time finite and ≥ 0.
    pub fn new(
        hook_distance: f64,
        release_distance: f64,
        contact_force: f64,
        release_time: f64,
        rate_cutoff: f64,
    ) -> Result<Self> {
        let config = Self {
            hook_distance,
            release_distance,
            contact_force,
            release_time,
            rate_cutoff,
            ..Self::default()
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks the bounds [`Self::new`] states.
    pub fn validate(&self) -> Result<()> {
        for (name, value) in [
            ("hook_distance", self.hook_distance),
            ("release_distance", self.release_distance),
            ("slide_distance", self.slide_distance),
            ("rate_cutoff", self.rate_cutoff),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(SabreError::invalid(name, format!("must be finite and positive, got {value}")));
            }
        }
        for (name, value) in [("contact_force", self.contact_force), ("release_time", self.release_time)] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(SabreError::invalid(
                    name,
                    format!("must be finite and non-negative, got {value}"),
                ));
            }
        }
        Ok(())
    }
}

/// One estimate: the object's coordinate (m or rad) and rate, whether they come from the hand
/// (else the last known state, held at rest), and how far (m) the hand point is from where the
/// estimated object puts it, across the bar (NaN while not hooked).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObjectEstimate {
    pub position: f64,
    pub velocity: f64,
    pub hooked: bool,
    pub residual: f64,
}

/// Infers the coordinate o and rate ȯ of the scene's single-joint object from the robot's joint
/// positions.
///
/// Once the hand hooks the handle, the hook point stays on the bar (it may slide along it, the
/// handle frame's x, which does not move o), so o is the coordinate that puts the handle-frame point
/// recorded at hooking where the hand frame measures it. Hooking is declared when the hand frame is
/// within `hook_distance` of the handle frame and the wrist force reaches `contact_force`; it ends
/// when the best fit is still more than `release_distance` off across the bar (the residual), the
/// hook slid more than `slide_distance` along it, or the force stays below `contact_force` for
/// longer than `release_time`. Before hooking and after release the last known state holds at rest. ȯ is the
/// difference quotient low-passed at `rate_cutoff` (exact exponential update on the measured step).
#[derive(Debug, Clone)]
pub struct ObjectStateEstimator {
    scene: Arc<Scene>,
    hand_frame: String,
    handle_frame: String,
    hand_link: usize,
    handle_link: usize,
    /// The handle frame in the object link `handle_frame`.
    handle_offset: Isometry3<f64>,
    config: ObjectEstimatorConfig,
    lower: f64,
    upper: f64,
    /// Central-difference step of the fit's dp/do (rad or m).
    difference_step: f64,
    position: f64,
    velocity: f64,
    residual: f64,
    /// The hook point in the handle frame while hooked.
    hook_point: Option<Point3<f64>>,
    /// The latest time seen.
    time: Option<f64>,
    /// How long the force has stayed below `contact_force` while hooked (s).
    without_contact: f64,
    /// The rate low-pass's state (None: the next raw rate starts it).
    filtered_rate: Option<f64>,
    robot_frames: Frames,
    object_frames: Frames,
}

impl ObjectStateEstimator {
    /// An estimator at `initial` (None: the lower limit; clipped to the limits), not hooked, with
    /// the hand at the robot frame `hand_frame` and the handle frame at `handle_offset` in the
    /// object frame `handle_frame`.
    ///
    /// Errors: an object with other than one movable joint, an unknown frame, a non-finite offset
    /// or initial coordinate, a config out of its bounds.
    pub fn new(
        scene: Arc<Scene>,
        hand_frame: &str,
        handle_frame: &str,
        handle_offset: Isometry3<f64>,
        initial: Option<f64>,
        config: ObjectEstimatorConfig,
    ) -> Result<Self> {
        if scene.no() != 1 {
            return Err(SabreError::invalid(
                "scene",
                format!(
                    "the estimator handles single-joint objects, this one has {} joints",
                    scene.no()
                ),
            ));
        }
        let hand_link = scene.robot.require_link(hand_frame)?;
        let handle_link = scene.object.require_link(handle_frame)?;
        let offset = handle_offset.to_homogeneous();
        if offset.iter().any(|v| !v.is_finite()) {
            return Err(SabreError::invalid("handle_offset", "entries must be finite"));
        }
        config.validate()?;
        let limits = scene.object_limits()[0];
        let position = match initial {
            None => limits.lower,
            Some(o) if o.is_finite() => o.clamp(limits.lower, limits.upper),
            Some(o) => return Err(SabreError::invalid("initial", format!("must be finite, got {o}"))),
        };
        let difference_step = if scene.object_is_revolute() { 1e-5 } else { 1e-6 };
        Ok(Self {
            scene,
            hand_frame: hand_frame.to_string(),
            handle_frame: handle_frame.to_string(),
            hand_link,
            handle_link,
            handle_offset,
            config,
            lower: limits.lower,
            upper: limits.upper,
            difference_step,
            position,
            velocity: 0.0,
            residual: f64::NAN,
            hook_point: None,
            time: None,
            without_contact: 0.0,
            filtered_rate: None,
            robot_frames: Frames::default(),
            object_frames: Frames::default(),
        })
    }

    /// The estimate at time `t` (s) from the robot's joint positions `q` (nq) and the wrist force
    /// magnitude `force` (N; infinity: assume contact). A time at or before the latest one counts
    /// as no time passed. `may_hook` false says the task's hook is not seated: no hook is declared
    /// (the hand touches the handle on its way in elsewhere than where it will pull) and a hook
    /// ends (a task that lost its hook moves the hand away, and the object does not follow).
    ///
    /// Errors: q of the wrong length or not finite, t not finite, force negative or NaN; the
    /// estimate is left as it was.
    pub fn update(&mut self, q: &[f64], t: f64, force: f64, may_hook: bool) -> Result<ObjectEstimate> {
        ensure_len("q", q, self.scene.nq())?;
        ensure_coordinates("q", q)?;
        if !t.is_finite() {
            return Err(SabreError::invalid("t", format!("must be finite, got {t}")));
        }
        if force.is_nan() || force < 0.0 {
            return Err(SabreError::invalid("force", format!("must be a magnitude ≥ 0, got {force}")));
        }
        self.scene
            .robot
            .update_frames(&Isometry3::identity(), q, &mut self.robot_frames);
        let hand = Point3::from(self.robot_frames.poses[self.hand_link].translation.vector);
        Ok(self.observe(&hand, t, force, may_hook))
    }

    /// [`Self::update`] on the hand point `hand` (world), its inputs checked.
    fn observe(&mut self, hand: &Point3<f64>, t: f64, force: f64, may_hook: bool) -> ObjectEstimate {
        let dt = self.time.map_or(0.0, |last| (t - last).max(0.0));
        self.time = Some(self.time.map_or(t, |last| last.max(t)));
        if !may_hook && self.hook_point.is_some() {
            // the task says its hook is not seated: the hand's motion is no longer the object's
            self.hook_point = None;
            self.velocity = 0.0;
        }
        match self.hook_point {
            None => {
                if may_hook && force >= self.config.contact_force {
                    self.reacquire(hand);
                }
                let handle = self.handle_pose(self.position);
                let local = handle.inverse_transform_point(hand);
                if may_hook && local.coords.norm() <= self.config.hook_distance && force >= self.config.contact_force {
                    self.hook_point = Some(local);
                    self.without_contact = 0.0;
                    self.filtered_rate = None;
                }
                self.velocity = 0.0;
                self.residual = f64::NAN;
            }
            Some(hook_point) => self.follow(hand, dt, force, &hook_point),
        }
        self.estimate()
    }

    /// Before a hook: when the hand is at the handle (within twice `release_distance` of the
    /// handle frame) for some coordinate o*, and the handle where the estimate puts it is more
    /// than `release_distance` farther from the hand than at o*, the estimate moves to o*. An
    /// object that moved while no hook held it (a door swinging on after a slip) is then hooked
    /// where it is, not where it was last seen. o* is the coordinate whose handle frame is nearest
    /// the hand, among samples of the range refined by the fit.
    fn reacquire(&mut self, hand: &Point3<f64>) {
        let origin = Point3::origin();
        let distance = |this: &mut Self, o: f64| (this.handle_pose(o) * origin - hand).norm();
        let now = distance(self, self.position);
        let (mut best, mut best_distance) = (self.position, now);
        for k in 0..=REACQUIRE_SAMPLES {
            let o = self.lower + (self.upper - self.lower) * k as f64 / REACQUIRE_SAMPLES as f64;
            let d = distance(self, o);
            if d < best_distance {
                (best, best_distance) = (o, d);
            }
        }
        let previous = self.position;
        self.position = best;
        let (refined, _, _) = self.fit(hand, &origin);
        let refined_distance = distance(self, refined);
        let at_handle = refined_distance <= 2.0 * self.config.release_distance;
        self.position = if at_handle && now - refined_distance > self.config.release_distance {
            refined
        } else {
            previous
        };
    }

    /// One update while hooked: the fit, its rate, and the release tests.
    fn follow(&mut self, hand: &Point3<f64>, dt: f64, force: f64, hook_point: &Point3<f64>) {
        let (position, residual, slide) = self.fit(hand, hook_point);
        self.without_contact = if force >= self.config.contact_force {
            0.0
        } else {
            self.without_contact + dt
        };
        if residual > self.config.release_distance
            || slide > self.config.slide_distance
            || self.without_contact > self.config.release_time
        {
            self.hook_point = None;
            self.velocity = 0.0;
        } else {
            if dt > 0.0 {
                self.velocity = self.filter_rate((position - self.position) / dt, dt);
            }
            self.position = position;
        }
        self.residual = residual;
    }

    /// The coordinate (within the limits) minimising |T(o)·hook_point − hand| by Gauss–Newton from
    /// the current estimate, and that distance across the bar and along it.
    fn fit(&mut self, hand: &Point3<f64>, hook_point: &Point3<f64>) -> (f64, f64, f64) {
        let local = self.handle_offset * hook_point;
        let h = self.difference_step;
        let mut o = self.position;
        for _ in 0..FIT_ITERATIONS {
            let r = self.link_point(o, &local) - hand;
            let d = (self.link_point(o + h, &local) - self.link_point(o - h, &local)) / (2.0 * h);
            let dd = d.norm_squared();
            if dd < FLAT_GRADIENT {
                break;
            }
            let step = -d.dot(&r) / dd;
            o = (o + step).clamp(self.lower, self.upper);
            if step.abs() < FIT_TOLERANCE {
                break;
            }
        }
        // The hook may slide along the bar (the handle frame's x): that is not the hand leaving the
        // handle, and it does not move o (the bar runs along the hinge, or across the slide).
        let r = self.link_point(o, &local) - hand;
        let bar = self.handle_pose(o).rotation * Vector3::x();
        let along = bar.dot(&r);
        (o, (r - bar * along).norm(), along.abs())
    }

    /// The world position of `local` (in the object link `handle_frame`) at coordinate `o`.
    fn link_point(&mut self, o: f64, local: &Point3<f64>) -> Point3<f64> {
        let scene = &self.scene;
        scene.object.update_frames(&scene.object_pose, &[o], &mut self.object_frames);
        self.object_frames.poses[self.handle_link] * local
    }

    /// The handle frame's world pose at coordinate `o`.
    fn handle_pose(&mut self, o: f64) -> Isometry3<f64> {
        let scene = &self.scene;
        scene.object.update_frames(&scene.object_pose, &[o], &mut self.object_frames);
        self.object_frames.poses[self.handle_link] * self.handle_offset
    }

    /// The rate low-pass: exact first-order update over the step `dt` (> 0).
    fn filter_rate(&mut self, raw: f64, dt: f64) -> f64 {
        let filtered = match self.filtered_rate {
            None => raw,
            Some(previous) => {
                let gain = crate::low_pass::blend(self.config.rate_cutoff, dt);
                previous + gain * (raw - previous)
            }
        };
        self.filtered_rate = Some(filtered);
        filtered
    }

    /// Starts over at `position` (clipped to the limits), not hooked, at rest, with no time seen.
    pub fn reset_to(&mut self, position: f64) -> Result<()> {
        if !position.is_finite() {
            return Err(SabreError::invalid("position", format!("must be finite, got {position}")));
        }
        self.position = position.clamp(self.lower, self.upper);
        self.velocity = 0.0;
        self.residual = f64::NAN;
        self.hook_point = None;
        self.time = None;
        self.without_contact = 0.0;
        self.filtered_rate = None;
        Ok(())
    }

    /// The current estimate.
    pub fn estimate(&self) -> ObjectEstimate {
        ObjectEstimate {
            position: self.position,
            velocity: self.velocity,
            hooked: self.hooked(),
            residual: self.residual,
        }
    }
    pub fn hooked(&self) -> bool {
        self.hook_point.is_some()
    }
    pub fn position(&self) -> f64 {
        self.position
    }
    pub fn velocity(&self) -> f64 {
        self.velocity
    }
    /// The last fit's distance from the hand point (m; NaN while not hooked).
    pub fn residual(&self) -> f64 {
        self.residual
    }
    /// The hook point in the handle frame while hooked.
    pub fn hook_point(&self) -> Option<Point3<f64>> {
        self.hook_point
    }
    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }
    pub fn hand_frame(&self) -> &str {
        &self.hand_frame
    }
    pub fn handle_frame(&self) -> &str {
        &self.handle_frame
    }
    pub fn handle_offset(&self) -> &Isometry3<f64> {
        &self.handle_offset
    }
    pub fn config(&self) -> &ObjectEstimatorConfig {
        &self.config
    }
}

#[cfg(test)]
mod tests;
