//! τ_ext as the cascade reads it: joint torques, or a wrist wrench in the frame its header names mapped
//! by τ_ext = J(q)ᵀ w, counted as none once older than a timeout, and low-passed over the ticks' steps.
//!
//! A wrench's frame gives the axes (the world's, or a robot frame's at the measured configuration; an
//! empty one the sensor's), and the moment is about a named point frame or the axes frame's origin.

use std::sync::Arc;

use nalgebra::{DVector, Vector3};

use crate::error::{ensure_finite, ensure_len, Result, SabreError};
use crate::low_pass::LowPass;
use crate::model::Scene;

/// How a wrench's header frame is read (see the module).
#[derive(Debug, Clone)]
pub struct WrenchFrames {
    scene: Arc<Scene>,
    world: [String; 2],
    default_frame: String,
    point_frame: String,
}

impl WrenchFrames {
    /// `world_frame` (and "world") name world axes; `default_frame` is an empty header's frame;
    /// `point_frame` (empty: the axes frame's, or `default_frame`'s for world axes) the moment's
    /// point. Errors: a default or point frame that is neither the world nor a robot frame.
    pub fn new(scene: Arc<Scene>, world_frame: &str, default_frame: &str, point_frame: &str) -> Result<Self> {
        let frames = Self {
            scene,
            world: [world_frame.to_string(), "world".to_string()],
            default_frame: default_frame.to_string(),
            point_frame: point_frame.to_string(),
        };
        for (label, frame) in [("wrench_frame", default_frame), ("wrench_point_frame", point_frame)] {
            if !frame.is_empty() && !frames.is_world(frame) && frames.scene.robot.require_link(frame).is_err() {
                return Err(SabreError::invalid(
                    label,
                    format!("{frame:?} is neither {world_frame:?} nor a robot frame"),
                ));
            }
        }
        Ok(frames)
    }

    fn is_world(&self, frame: &str) -> bool {
        self.world.iter().any(|w| w == frame)
    }

    /// (axes frame or None for world axes, moment point frame) of a header's frame id.
    pub fn resolve<'a>(&'a self, frame_id: &'a str) -> Result<(Option<&'a str>, &'a str)> {
        let frame = if frame_id.is_empty() {
            self.default_frame.as_str()
        } else {
            frame_id
        };
        let axes = if self.is_world(frame) {
            None
        } else if self.scene.robot.require_link(frame).is_ok() {
            Some(frame)
        } else {
            return Err(SabreError::invalid(
                "wrench",
                format!("frame {frame:?} is neither the world frame nor a robot frame"),
            ));
        };
        let point = if !self.point_frame.is_empty() {
            self.point_frame.as_str()
        } else {
            axes.unwrap_or(self.default_frame.as_str())
        };
        Ok((axes, if self.is_world(point) { "world" } else { point }))
    }

    /// τ_ext (nq) = J(q)ᵀ w of `wrench` [f; m] given in the header frame `frame_id`.
    pub fn tau_ext(&self, q: &[f64], wrench: &[f64; 6], frame_id: &str) -> Result<Vec<f64>> {
        if wrench.iter().any(|v| !v.is_finite()) {
            return Err(SabreError::invalid("wrench", "non-finite values"));
        }
        let (axes, point) = self.resolve(frame_id)?;
        let (mut force, mut moment) = (
            Vector3::new(wrench[0], wrench[1], wrench[2]),
            Vector3::new(wrench[3], wrench[4], wrench[5]),
        );
        if let Some(axes) = axes {
            let rotation = self.scene.fk(q, axes)?.rotation;
            force = rotation * force;
            moment = rotation * moment;
        }
        let w = DVector::from_iterator(6, force.iter().chain(moment.iter()).copied());
        let jacobian = self.scene.jacobian(q, point)?;
        Ok((jacobian.transpose() * w).as_slice().to_vec())
    }
}

/// The newest τ_ext reading and its conditioning (see the module): what the tank and the passivity
/// row (56) see at each tick.
#[derive(Debug, Clone)]
pub struct ExternalTorque {
    raw: Vec<f64>,
    force: f64,
    received: f64,
    timeout: Option<f64>,
    low_pass: LowPass,
    frames: Option<WrenchFrames>,
    zeros: Vec<f64>,
    stale: u64,
    readings: u64,
}

impl ExternalTorque {
    /// τ_ext of `nq` joints, low-passed at `cutoff` Hz (None: as read), none once older than `timeout`
    /// s (None: a reading never ages), wrenches read through `frames` (None: torques only).
    pub fn new(nq: usize, cutoff: Option<f64>, timeout: Option<f64>, frames: Option<WrenchFrames>) -> Result<Self> {
        if let Some(f) = cutoff.filter(|f| !(f.is_finite() && *f >= 0.0)) {
            return Err(SabreError::invalid(
                "tau_ext_cutoff",
                format!("must be finite and ≥ 0 (Hz; 0: none), got {f}"),
            ));
        }
        if let Some(t) = timeout.filter(|t| t.is_nan() || *t < 0.0) {
            return Err(SabreError::invalid("wrench_timeout", format!("must be ≥ 0 (s), got {t}")));
        }
        if let Some(f) = frames.as_ref().filter(|f| f.scene.nq() != nq) {
            return Err(SabreError::invalid(
                "wrench frames",
                format!("read a robot of {} joints, τ_ext has {nq}", f.scene.nq()),
            ));
        }
        Ok(Self {
            raw: vec![0.0; nq],
            force: 0.0,
            received: f64::NEG_INFINITY,
            timeout,
            low_pass: LowPass::new(nq, cutoff),
            frames,
            zeros: vec![0.0; nq],
            stale: 0,
            readings: 0,
        })
    }

    /// The newest τ_ext (nq) and the wrist force's magnitude (N; infinity: torques only, contact
    /// assumed), arrived at `received` (s). Nothing changes on an error.
    pub fn set_torque(&mut self, tau: &[f64], force: f64, received: f64) -> Result<()> {
        ensure_len("tau_ext", tau, self.raw.len())?;
        ensure_finite("tau_ext", tau)?;
        if force.is_nan() || force < 0.0 {
            return Err(SabreError::invalid("force", format!("must be a magnitude ≥ 0, got {force}")));
        }
        self.raw.copy_from_slice(tau);
        self.force = force;
        self.received = received;
        self.readings += 1;
        Ok(())
    }

    /// A wrist wrench [f; m] given in the header frame `frame_id`, arrived at `received`: τ_ext at
    /// the joint positions `q`. Errors: no wrench frames, non-finite values, an unknown frame;
    /// nothing changes then.
    pub fn set_wrench(&mut self, q: &[f64], wrench: &[f64; 6], frame_id: &str, received: f64) -> Result<()> {
        let frames = self
            .frames
            .as_ref()
            .ok_or_else(|| SabreError::invalid("wrench", "this cascade reads no wrench (built without wrench frames)"))?;
        let tau = frames.tau_ext(q, wrench, frame_id)?;
        let force = (wrench[0] * wrench[0] + wrench[1] * wrench[1] + wrench[2] * wrench[2]).sqrt();
        self.set_torque(&tau, force, received)
    }

    /// τ_ext for a tick at `now` (s, the readings' clock) that integrates over `dt` (s): the newest
    /// reading while fresh, else zero (counted stale), through the low-pass.
    pub fn condition(&mut self, now: f64, dt: f64) -> &[f64] {
        let fresh = self.timeout.is_none_or(|timeout| now - self.received <= timeout);
        if !fresh {
            self.stale += 1;
        }
        let sample = if fresh { &self.raw } else { &self.zeros };
        self.low_pass.update(sample, dt)
    }

    /// The newest reading as received (before the low-pass).
    pub fn raw(&self) -> &[f64] {
        &self.raw
    }
    /// The newest wrist force's magnitude (N; infinity: torques only).
    pub fn force(&self) -> f64 {
        self.force
    }
    /// Ticks that found the newest reading too old.
    pub fn stale_count(&self) -> u64 {
        self.stale
    }
    /// Readings received.
    pub fn readings(&self) -> u64 {
        self.readings
    }
    pub fn frames(&self) -> Option<&WrenchFrames> {
        self.frames.as_ref()
    }
    /// Forgets the readings and the low-pass's state.
    pub fn reset(&mut self) {
        self.raw.iter_mut().for_each(|v| *v = 0.0);
        self.force = 0.0;
        self.received = f64::NEG_INFINITY;
        self.low_pass.reset();
    }
}
