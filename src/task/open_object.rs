//! The open-object task's per-iteration logic: its phase switch (with the probe that tells whether
//! the object opens by itself, in `self_opening.rs`), its sampling-noise schedule and its guides, in
//! one place per scene.
//!
//! The phases, their costs and the rationale of every setting are the Python task's
//! (`sabre.tasks.OpenObject`, docs/design.md); this is the part the planner runs every iteration.

use std::sync::Arc;

use nalgebra::Isometry3;

use super::handle::{HandAtHandle, HandleGeometry, ReleaseMove};
use super::handle_fit::{self, HandleFit};
use crate::error::{ensure_finite, Result, SabreError};
use crate::model::scene::Scene;
use crate::mppi::{ServoGuideConfig, ServoGuidePlan};
use crate::sim::{RolloutConfig, RolloutModel};

/// The phases of opening with a hook finger, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OpenPhase {
    /// To a pre-grasp pose in front of the handle, beside the bar.
    Approach,
    /// In until the finger is beside the bar with its tip past it.
    Insert,
    /// Sideways until the bar sits in the finger's pocket.
    Hook,
    /// Pulling the object open.
    Open,
    /// Letting go of an object that opens by itself.
    Release,
    /// Holding the bar of an opened object that stopped following the pull: the hand keeps its
    /// place in the pocket, pulling out along the handle's normal, instead of following the path
    /// the rollout model predicts for the object.
    Hold,
}

impl OpenPhase {
    pub const ALL: [OpenPhase; 6] = [
        Self::Approach,
        Self::Insert,
        Self::Hook,
        Self::Open,
        Self::Release,
        Self::Hold,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Approach => "approach",
            Self::Insert => "insert",
            Self::Hook => "hook",
            Self::Open => "open",
            Self::Release => "release",
            Self::Hold => "hold",
        }
    }

    pub fn from_name(name: &str) -> Result<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name).ok_or_else(|| {
            let names: Vec<&str> = Self::ALL.iter().map(|p| p.name()).collect();
            SabreError::invalid("phase", format!("unknown phase '{name}'; phases: {}", names.join(", ")))
        })
    }

    /// The phase that follows a reaching phase once its target is reached.
    fn after_reaching(self) -> Option<Self> {
        match self {
            Self::Approach => Some(Self::Insert),
            Self::Insert => Some(Self::Hook),
            Self::Hook => Some(Self::Open),
            Self::Open | Self::Release | Self::Hold => None,
        }
    }
}

/// Every setting of the open-object task that its per-iteration logic reads, with the defaults
/// (the Python task's setting groups read theirs from here). Lengths in m, angles in rad, speeds
/// in m/s, openings in rad or m (the object's joint).
#[derive(Debug, Clone, PartialEq)]
pub struct OpenObjectConfig {
    /// Grasp targets in the handle frame (x along the bar, y sideways, z into the door): in front
    /// of the bar and beside it (approach), beside it with the tip past it (insert), the bar in the
    /// pocket (hook), pulled out from the bar (open); the hand pointing `pitch` below the normal.
    pub pregrasp_offset: [f64; 3],
    pub insert_offset: [f64; 3],
    pub hook_offset: [f64; 3],
    pub open_offset: [f64; 3],
    pub pitch: f64,
    /// Clearance (m) the grasp targets keep from the bar and the panel when they are fitted to the
    /// handle's measured geometry (see [`super::handle_fit`]): the targets above where they fit,
    /// moved the least where they do not, the task refused where the tool cannot fit. None: the
    /// targets as given.
    pub fit_clearance: Option<f64>,
    /// Distance to the target that ends inserting (twice it ends approaching); angle that ends
    /// approaching, inserting and hooking.
    pub switch_position: f64,
    pub switch_angle: f64,
    /// Distance across the bar that ends hooking; distance along it allowed while inserting and hooking.
    pub hook_tolerance: f64,
    pub along_tolerance: f64,
    /// Distance from the insert target's depth within which inserting may end (None: no depth test).
    pub insert_depth_tolerance: Option<f64>,
    /// How far short of the insert depth a stopped finger (slower than `blocked_speed`) may end
    /// inserting all the same (None: never).
    pub blocked_depth: Option<f64>,
    pub blocked_speed: f64,
    /// How far short of the hook target's depth a hooking finger may back out of an opened,
    /// unmoving object before the task starts over (None: never).
    pub backout: Option<f64>,
    /// Handle speed that counts as already pulling while inserting or hooking (0: off), and the
    /// distance from closed below which it never counts.
    pub drag_speed: f64,
    pub drag_distance: f64,
    /// How far short of the hook depth a stalled hook starts over however little the handle moved
    /// (None: only past `drag_distance`).
    pub stall_depth: Option<f64>,
    /// Handle speeds of the guides that follow the handle while opening (empty: none).
    pub open_speeds: Vec<f64>,
    /// The bar has left the pocket: grasp frame beyond `slip_distance` of the open target or
    /// beyond `slip_lateral` sideways of it.
    pub slip_distance: f64,
    pub slip_lateral: f64,
    /// An opened object (beyond `drag_distance` from closed, short of success) whose handle moves
    /// slower than `hold_speed` while the bar is in the pocket has stopped following the pull: the
    /// task holds it (0: never), its target `hold_pull` further out from the door than the open
    /// target's; it opens again once the handle moves faster than twice `hold_speed`.
    pub hold_speed: f64,
    pub hold_pull: f64,
    /// Success once the opening reaches this share of the target, in (0, 1].
    pub success_fraction: f64,
    /// Release: speed of the move (0: no release guide) and how far the hand backs off.
    pub release_speed: f64,
    pub release_distance: f64,
    /// Opening rate that counts as opening by itself, within `probe` s of the object left alone.
    pub release_rate: f64,
    pub probe: f64,
    /// Handle speed above which the object is taken to run ahead of the hand.
    pub runaway_speed: f64,
    /// Noise while reaching: Σ scaled by (d / noise_distance)², clipped to [noise_floor, 1];
    /// opening and releasing use `noise_open`.
    pub noise_distance: f64,
    pub noise_floor: f64,
    pub noise_open: f64,
    /// Reaching guides: linear speed cap while approaching (0: no reaching guides) and while
    /// inserting and hooking; the servo gain (1/s) of every guide.
    pub guide_speed: f64,
    pub fine_speed: f64,
    pub guide_gain: f64,
}

impl Default for OpenObjectConfig {
    fn default() -> Self {
        Self {
            pregrasp_offset: [0.0, -0.022, -0.07],
            insert_offset: [0.0, -0.022, 0.0],
            hook_offset: [0.0, 0.003, 0.0],
            open_offset: [0.0, 0.003, -0.016],
            pitch: 0.3,
            fit_clearance: Some(0.002),
            switch_position: 0.015,
            switch_angle: 0.15,
            hook_tolerance: 0.006,
            along_tolerance: 0.03,
            insert_depth_tolerance: Some(0.005),
            blocked_depth: Some(0.008),
            blocked_speed: 0.005,
            backout: Some(0.010),
            drag_speed: 0.02,
            drag_distance: 0.03,
            stall_depth: Some(0.04),
            open_speeds: vec![0.1, 0.05],
            slip_distance: 0.05,
            slip_lateral: 0.01,
            hold_speed: 0.003,
            hold_pull: 0.05,
            success_fraction: 0.9,
            release_speed: 0.4,
            release_distance: 0.3,
            release_rate: 0.05,
            probe: 0.15,
            runaway_speed: 0.15,
            noise_distance: 0.5,
            noise_floor: 1e-3,
            noise_open: 0.01,
            guide_speed: 0.3,
            fine_speed: 0.05,
            guide_gain: 2.0,
        }
    }
}

impl OpenObjectConfig {
    fn check(&self) -> Result<()> {
        for (name, v) in [
            ("pregrasp_offset", &self.pregrasp_offset),
            ("insert_offset", &self.insert_offset),
            ("hook_offset", &self.hook_offset),
            ("open_offset", &self.open_offset),
        ] {
            ensure_finite(name, v)?;
        }
        ensure_finite("pitch", &[self.pitch])?;
        let optional = [
            ("insert_depth_tolerance", self.insert_depth_tolerance),
            ("blocked_depth", self.blocked_depth),
            ("backout", self.backout),
            ("stall_depth", self.stall_depth),
            ("fit_clearance", self.fit_clearance),
        ];
        let plain = [
            ("switch_position", self.switch_position),
            ("switch_angle", self.switch_angle),
            ("hook_tolerance", self.hook_tolerance),
            ("along_tolerance", self.along_tolerance),
            ("blocked_speed", self.blocked_speed),
            ("drag_speed", self.drag_speed),
            ("drag_distance", self.drag_distance),
            ("slip_distance", self.slip_distance),
            ("slip_lateral", self.slip_lateral),
            ("hold_speed", self.hold_speed),
            ("hold_pull", self.hold_pull),
            ("release_speed", self.release_speed),
            ("release_distance", self.release_distance),
            ("release_rate", self.release_rate),
            ("runaway_speed", self.runaway_speed),
            ("noise_floor", self.noise_floor),
            ("noise_open", self.noise_open),
            ("guide_speed", self.guide_speed),
            ("fine_speed", self.fine_speed),
            ("guide_gain", self.guide_gain),
        ];
        let speeds = self.open_speeds.iter().map(|&v| ("open_speeds", v));
        let values = plain
            .into_iter()
            .chain(optional.into_iter().filter_map(|(n, v)| v.map(|v| (n, v))));
        for (name, v) in values.chain(speeds) {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SabreError::invalid(name, format!("must be finite and non-negative, got {v}")));
            }
        }
        for (name, v) in [("probe", self.probe), ("noise_distance", self.noise_distance)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(SabreError::invalid(name, format!("must be positive and finite, got {v}")));
            }
        }
        if !(self.success_fraction > 0.0 && self.success_fraction <= 1.0) {
            return Err(SabreError::invalid(
                "success_fraction",
                format!("must be in (0, 1], got {}", self.success_fraction),
            ));
        }
        Ok(())
    }
}

/// The open-object task on one scene: its handle geometry, settings, targets and the rollout
/// model of its probe.
pub struct OpenObjectRules {
    pub(super) geometry: HandleGeometry,
    pub(super) config: OpenObjectConfig,
    /// Grasp targets in the handle frame, by phase (release has none: it uses `open`'s; hold's is
    /// `open`'s moved `hold_pull` out from the door).
    offsets: [Isometry3<f64>; 5],
    /// The targets fitted to the handle's geometry (None: as configured, or no bar to measure).
    fit: Option<HandleFit>,
    target_opening: f64,
    object_setpoint: f64,
    /// The rollout model that watches the object alone (a fixed-base robot's links out of the contact).
    pub(super) probe: RolloutModel,
}

impl OpenObjectRules {
    /// The task's logic on `geometry`'s scene, opening to `target_opening` (success at
    /// `success_fraction` of it), the opening guides running toward `object_setpoint` (both rad or m).
    pub fn new(geometry: HandleGeometry, config: OpenObjectConfig, target_opening: f64, object_setpoint: f64) -> Result<Self> {
        config.check()?;
        ensure_finite("target_opening", &[target_opening])?;
        ensure_finite("object_setpoint", &[object_setpoint])?;
        let fit = match config.fit_clearance {
            Some(margin) => match handle_fit::measure(&geometry) {
                Some(clearance) => {
                    let want = handle_fit::Preferred {
                        pregrasp: config.pregrasp_offset,
                        insert: config.insert_offset,
                        hook: config.hook_offset,
                        open: config.open_offset,
                        pitch: config.pitch,
                        margin,
                    };
                    Some(handle_fit::fit(
                        &geometry,
                        clearance,
                        &handle_fit::tool_points(&geometry),
                        &want,
                    )?)
                }
                None => None,
            },
            None => None,
        };
        let (targets, pitch) = match &fit {
            Some(f) => ([f.pregrasp, f.insert, f.hook, f.open], f.pitch),
            None => (
                [
                    config.pregrasp_offset,
                    config.insert_offset,
                    config.hook_offset,
                    config.open_offset,
                ],
                config.pitch,
            ),
        };
        let [x, y, z] = targets[3];
        let offsets = [
            geometry.grasp_offset(targets[0], pitch)?,
            geometry.grasp_offset(targets[1], pitch)?,
            geometry.grasp_offset(targets[2], pitch)?,
            geometry.grasp_offset(targets[3], pitch)?,
            geometry.grasp_offset([x, y, z - config.hold_pull], pitch)?,
        ];
        let scene = geometry.scene();
        let probe_scene = if scene.roles.base.is_none() {
            let mut alone = Scene::clone(scene);
            alone.rollout_contact_links.clear();
            Arc::new(alone)
        } else {
            scene.clone()
        };
        let probe = RolloutModel::new(probe_scene, RolloutConfig::default())?;
        Ok(Self {
            geometry,
            config,
            offsets,
            fit,
            target_opening,
            object_setpoint,
            probe,
        })
    }

    pub fn geometry(&self) -> &HandleGeometry {
        &self.geometry
    }

    /// The grasp targets fitted to the handle's measured geometry (None: the configured ones).
    pub fn fit(&self) -> Option<&HandleFit> {
        self.fit.as_ref()
    }

    /// The grasp target of `phase` in the handle frame (release: the open phase's).
    pub fn offset(&self, phase: OpenPhase) -> &Isometry3<f64> {
        match phase {
            OpenPhase::Approach => &self.offsets[0],
            OpenPhase::Insert => &self.offsets[1],
            OpenPhase::Hook => &self.offsets[2],
            OpenPhase::Open | OpenPhase::Release => &self.offsets[3],
            OpenPhase::Hold => &self.offsets[4],
        }
    }

    fn checked_at(&self, x: &[f64]) -> Result<HandAtHandle> {
        self.geometry.check_state(x)?;
        Ok(self.geometry.at(x))
    }

    /// Whether the object is open to `success_fraction` of the target at state x.
    pub fn success(&self, x: &[f64]) -> Result<bool> {
        self.geometry.check_state(x)?;
        Ok(self.succeeded(x))
    }

    pub(super) fn succeeded(&self, x: &[f64]) -> bool {
        self.geometry.split(x).2[0] >= self.config.success_fraction * self.target_opening
    }

    /// The bar has left the finger's pocket.
    fn slipped(&self, at: &HandAtHandle) -> bool {
        let offset = self.offset(OpenPhase::Open);
        at.approach_error(offset).0 > self.config.slip_distance
            || at.lateral_error(offset.translation.vector.y).abs() > self.config.slip_lateral
    }

    /// Whether the finger already pulls the object open before the hook test passed: the handle
    /// opens faster than `drag_speed` while the grasp frame is within the open phase's slip bounds,
    /// at least `drag_distance` from closed.
    pub fn pulling(&self, x: &[f64]) -> Result<bool> {
        let at = self.checked_at(x)?;
        Ok(self.is_pulling(x, &at))
    }

    fn is_pulling(&self, x: &[f64], at: &HandAtHandle) -> bool {
        if self.config.drag_speed <= 0.0 || self.geometry.distance_from_closed(x) < self.config.drag_distance {
            return false;
        }
        self.geometry.speed(x) > self.config.drag_speed && !self.slipped(at)
    }

    /// Whether a hooking finger has backed out in front of the bar and stalled: more than
    /// `backout` short of the hook depth, the handle no faster than `drag_speed`, and either at
    /// least `drag_distance` from closed or more than `stall_depth` short.
    pub fn backed_out(&self, x: &[f64]) -> Result<bool> {
        let at = self.checked_at(x)?;
        Ok(self.is_backed_out(x, &at))
    }

    fn is_backed_out(&self, x: &[f64], at: &HandAtHandle) -> bool {
        let Some(backout) = self.config.backout else {
            return false;
        };
        let short = -at.depth_error(self.offset(OpenPhase::Hook));
        if short <= backout {
            return false;
        }
        let lost = self.config.stall_depth.is_some_and(|stall| short > stall);
        if !lost && self.geometry.distance_from_closed(x) < self.config.drag_distance {
            return false;
        }
        self.geometry.speed(x) <= self.config.drag_speed
    }

    /// Whether the object opens by itself faster than `runaway_speed` at the handle.
    pub fn running_ahead(&self, x: &[f64]) -> Result<bool> {
        self.geometry.check_state(x)?;
        Ok(self.geometry.speed(x) > self.config.runaway_speed)
    }

    /// Whether the grasp frame is close enough to the target of the reaching `phase` to move on.
    fn reached(&self, x: &[f64], at: &HandAtHandle, phase: OpenPhase) -> bool {
        let offset = self.offset(phase);
        let (distance, angle) = at.approach_error(offset);
        if angle >= self.config.switch_angle {
            return false;
        }
        if phase == OpenPhase::Approach {
            return distance < 2.0 * self.config.switch_position;
        }
        let (across, along) = at.pocket_error(offset);
        if along >= self.config.along_tolerance {
            return false;
        }
        if phase == OpenPhase::Hook {
            return across < self.config.hook_tolerance;
        }
        if across >= self.config.switch_position {
            return false;
        }
        let depth_error = at.depth_error(offset);
        match self.config.insert_depth_tolerance {
            None => true,
            Some(depth) => depth_error.abs() < depth || self.blocked(x, depth_error),
        }
    }

    /// Whether an opened object, short of success, has stopped following the pull: its handle
    /// beyond `drag_distance` from closed and slower than `hold_speed`.
    fn stalled(&self, x: &[f64]) -> bool {
        self.config.hold_speed > 0.0
            && self.geometry.distance_from_closed(x) > self.config.drag_distance
            && self.geometry.speed(x).abs() < self.config.hold_speed
    }

    /// Whether an inserting finger has stopped short of the insert depth, within `blocked_depth`
    /// of it: something in front of the hand holds it there, and this close the tip clears the bar.
    fn blocked(&self, x: &[f64], depth_error: f64) -> bool {
        let Some(blocked) = self.config.blocked_depth else {
            return false;
        };
        if !(-blocked < depth_error && depth_error < 0.0) {
            return false;
        }
        let scene = self.geometry.scene();
        let (q, q_dot, _, _) = self.geometry.split(x);
        let jacobian = scene
            .robot
            .frame_jacobian(&Isometry3::identity(), q, self.geometry.tool_link());
        let velocity = jacobian.rows(0, 3) * nalgebra::DVector::from_column_slice(q_dot);
        velocity.norm() < self.config.blocked_speed
    }

    /// The phase to plan in from state x, coming from `phase`.
    pub fn next_phase(&self, x: &[f64], phase: OpenPhase) -> Result<OpenPhase> {
        let at = self.checked_at(x)?;
        Ok(match phase {
            OpenPhase::Release if self.self_opening(x)? => OpenPhase::Release,
            OpenPhase::Release => OpenPhase::Approach,
            OpenPhase::Open | OpenPhase::Hold => {
                // release a door that opens by itself (holding it makes the arm follow it down into
                // its joint limits); start over when the bar has left the pocket and the object is
                // not running ahead of the hand; hold an object that stopped following the pull
                // until it moves again
                if self.succeeded(x) {
                    OpenPhase::Open
                } else if self.self_opening(x)? {
                    OpenPhase::Release
                } else if self.slipped(&at) && self.geometry.speed(x) <= self.config.runaway_speed {
                    OpenPhase::Approach
                } else if phase == OpenPhase::Hold {
                    if self.geometry.speed(x).abs() > 2.0 * self.config.hold_speed {
                        OpenPhase::Open
                    } else {
                        OpenPhase::Hold
                    }
                } else if self.stalled(x) {
                    OpenPhase::Hold
                } else {
                    OpenPhase::Open
                }
            }
            reaching => {
                if at.opening > 0.0 && self.self_opening(x)? {
                    OpenPhase::Release
                } else if self.reached(x, &at, reaching) {
                    reaching.after_reaching().unwrap_or(reaching)
                } else if matches!(reaching, OpenPhase::Insert | OpenPhase::Hook) && self.is_pulling(x, &at) {
                    OpenPhase::Open
                } else if reaching == OpenPhase::Hook && self.is_backed_out(x, &at) {
                    OpenPhase::Approach
                } else {
                    reaching
                }
            }
        })
    }

    /// Factor on the sampling covariance in `phase` at state x.
    pub fn noise_scale(&self, x: &[f64], phase: OpenPhase) -> Result<f64> {
        if matches!(phase, OpenPhase::Open | OpenPhase::Release | OpenPhase::Hold) {
            return Ok(self.config.noise_open);
        }
        let (distance, _) = self.checked_at(x)?.approach_error(self.offset(phase));
        Ok((distance / self.config.noise_distance)
            .powi(2)
            .clamp(self.config.noise_floor, 1.0))
    }

    /// The release's grasp-frame targets (`steps + 1`, see [`HandleGeometry::release_path`]): a
    /// finger within `slip_distance` of the pocket leaves across the bar to the insert offset's
    /// side, then back to the pre-grasp depth, riding on the handle (both as fitted to the handle);
    /// then the hand backs off.
    pub fn release_path(&self, x: &[f64], steps: usize, dt: f64) -> Result<Vec<Isometry3<f64>>> {
        let motion = ReleaseMove {
            entry_side: self.offset(OpenPhase::Insert).translation.y,
            entry_depth: self.offset(OpenPhase::Approach).translation.z,
            hooked_within: self.config.slip_distance,
            speed: self.config.release_speed,
            distance: self.config.release_distance,
        };
        self.geometry.release_path(x, steps, dt, &motion)
    }

    fn guide_config(&self, max_linear: f64, max_angular: f64) -> ServoGuideConfig {
        ServoGuideConfig {
            gain: self.config.guide_gain,
            max_linear,
            max_angular,
            ..ServoGuideConfig::default()
        }
    }

    /// The guides (M × steps × nu, row-major) for `phase` from state x, and M: a servo along the
    /// release path; a servo toward the reaching phase's target; servos that follow the handle along
    /// its path at `open_speeds` (and at the object's own pace when it opens faster), toward the
    /// object setpoint. None where the settings turn them off.
    pub fn guides(&self, x: &[f64], phase: OpenPhase, steps: usize, dt: f64) -> Result<(Vec<f64>, usize)> {
        let plan = self.guide_plan(x, phase, steps, dt)?;
        Ok((plan.evaluate(), plan.len()))
    }

    /// [`Self::guides`] as a plan whose guides are integrated where they are used (targets and
    /// settings checked here).
    pub fn guide_plan(&self, x: &[f64], phase: OpenPhase, steps: usize, dt: f64) -> Result<ServoGuidePlan> {
        if steps == 0 || !(dt.is_finite() && dt > 0.0) {
            return Err(SabreError::invalid(
                "steps, dt",
                format!("need at least one step of positive length, got {steps} and {dt}"),
            ));
        }
        let at = self.checked_at(x)?;
        let scene = self.geometry.scene();
        let frame = self.geometry.tool_frame();
        let (q, _, o, _) = self.geometry.split(x);
        match phase {
            OpenPhase::Release => {
                if self.config.release_speed <= 0.0 {
                    return Ok(ServoGuidePlan::empty(scene.clone()));
                }
                let targets = self.release_path(x, steps, dt)?;
                let config = self.guide_config(2.0 * self.config.release_speed, 1.0);
                ServoGuidePlan::new(scene.clone(), q, &[targets], dt, frame, &[config])
            }
            OpenPhase::Open => {
                if self.config.open_speeds.is_empty() {
                    return Ok(ServoGuidePlan::empty(scene.clone()));
                }
                let travel = self.geometry.travel(o);
                let upper = scene.object_limits()[0].upper;
                let end = self.object_setpoint.min(upper).max(at.opening);
                let mut speeds = self.config.open_speeds.clone();
                let own = at.opening_rate * travel;
                if own > speeds.iter().cloned().fold(f64::NEG_INFINITY, f64::max) {
                    speeds.insert(0, own); // follow the object at its own pace
                }
                let offset = self.offset(OpenPhase::Open);
                let mut opened = o.to_vec();
                let targets: Vec<Vec<Isometry3<f64>>> = speeds
                    .iter()
                    .map(|speed| {
                        let rate = speed / travel.max(1e-6);
                        (0..=steps)
                            .map(|k| {
                                opened[0] = (at.opening + rate * dt * k as f64).min(end);
                                self.geometry.handle_pose(&opened) * offset
                            })
                            .collect()
                    })
                    .collect();
                let configs: Vec<ServoGuideConfig> = speeds.iter().map(|s| self.guide_config(2.0 * s + 0.05, 2.0)).collect();
                ServoGuidePlan::new(scene.clone(), q, &targets, dt, frame, &configs)
            }
            reaching => {
                if self.config.guide_speed <= 0.0 {
                    return Ok(ServoGuidePlan::empty(scene.clone()));
                }
                let target = at.handle * self.offset(reaching);
                let speed = if reaching == OpenPhase::Approach {
                    self.config.guide_speed
                } else {
                    self.config.fine_speed
                };
                let targets = vec![target; steps + 1];
                let config = self.guide_config(speed, 4.0 * speed);
                ServoGuidePlan::new(scene.clone(), q, &[targets], dt, frame, &[config])
            }
        }
    }
}
