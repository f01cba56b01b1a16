//! τ_ext from a wrist wrench in the frame its header names: the frame gives the axes (the world's,
//! or a robot frame's at the measured configuration; an empty one the sensor's), the moment is
//! about a named point frame or the axes frame's origin, and τ_ext = J(q)ᵀ w at that point.

use std::sync::Arc;

use nalgebra::{DVector, Vector3};

use crate::error::{Result, SabreError};
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
