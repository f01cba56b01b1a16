//! Where a handle is and where the hand is relative to it: the handle frame of an object and the
//! robot's control (grasp) frame, measured at a state.
//!
//! The handle frame has x along the bar, y sideways (toward the finger) and z into the door; a
//! grasp target is a pose in that frame. States are laid out as [`Scene`]'s: (q, q̇, o, ȯ).

use std::sync::Arc;

use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::error::{ensure_finite, Result, SabreError};
use crate::model::handle_frame::{handle_frame, HandleFrame};
use crate::model::scene::Scene;

/// The handle frame of a scene's object (an object link and a fixed offset from it) and the
/// robot's control frame, with the handle's pose with the object closed.
#[derive(Debug, Clone)]
pub struct HandleGeometry {
    scene: Arc<Scene>,
    handle_link: usize,
    handle_offset: Isometry3<f64>,
    tool_link: usize,
    tool_name: String,
    closed: Isometry3<f64>,
}

/// The handle's and the grasp frame's world poses at one state, and the object's opening and
/// opening rate (its first joint).
#[derive(Debug, Clone, Copy)]
pub struct HandAtHandle {
    pub handle: Isometry3<f64>,
    pub tool: Isometry3<f64>,
    pub opening: f64,
    pub opening_rate: f64,
}

impl HandAtHandle {
    /// Distance (m) and angle (rad) of the grasp frame from the target `offset` (in the handle frame).
    pub fn approach_error(&self, offset: &Isometry3<f64>) -> (f64, f64) {
        let target = self.handle * offset;
        let distance = (self.tool.translation.vector - target.translation.vector).norm();
        let relative = (target.rotation.inverse() * self.tool.rotation).to_rotation_matrix();
        let cos = (relative.matrix().trace() - 1.0) / 2.0;
        (distance, cos.clamp(-1.0, 1.0).acos())
    }

    /// The grasp frame's offset (m, world axes) from the target `offset`.
    fn offset_from_target(&self, offset: &Isometry3<f64>) -> Vector3<f64> {
        self.tool.translation.vector - (self.handle * offset).translation.vector
    }

    /// Distance (m) of the grasp frame from the target `offset` across the bar (handle y and z)
    /// and along it (x): sliding along the bar does not matter for hooking.
    pub fn pocket_error(&self, offset: &Isometry3<f64>) -> (f64, f64) {
        let e = self.handle.rotation.inverse() * self.offset_from_target(offset);
        (e.y.hypot(e.z), e.x.abs())
    }

    /// Signed distance (m) of the grasp frame from the target `offset` along the handle's z
    /// (into the door): negative while short of it.
    pub fn depth_error(&self, offset: &Isometry3<f64>) -> f64 {
        (self.handle.rotation * Vector3::z()).dot(&self.offset_from_target(offset))
    }

    /// Sideways position (m) of the grasp frame along the handle's y, from `sideways`.
    pub fn lateral_error(&self, sideways: f64) -> f64 {
        (self.handle.inverse() * self.tool).translation.vector.y - sideways
    }
}

/// Where the hand backs off to when letting go (see [`HandleGeometry::release_path`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReleaseMove {
    /// Handle-frame y (m) at which the finger came in beside the bar.
    pub entry_side: f64,
    /// Handle-frame z (m) clear of the bar, in front of it.
    pub entry_depth: f64,
    /// A finger within this distance (m) sideways of `entry_side` counts as hooked.
    pub hooked_within: f64,
    /// Speed (m/s) of the whole move.
    pub speed: f64,
    /// How far (m) the hand backs off once free.
    pub distance: f64,
}

/// −1, 0 or 1 (NumPy's sign: zero stays zero).
fn sign(v: f64) -> f64 {
    if v > 0.0 {
        1.0
    } else if v < 0.0 {
        -1.0
    } else {
        0.0
    }
}

impl HandleGeometry {
    /// The handle frame named by `handle` (an object frame, or a link whose handle frame is
    /// inferred from its collision geometry: see [`handle_frame`]) and the robot's control frame
    /// `tool_frame` of `scene`.
    pub fn new(scene: Arc<Scene>, handle: &str, tool_frame: &str) -> Result<Self> {
        if scene.no() == 0 {
            return Err(SabreError::invalid(
                "scene",
                "the object has no movable joint: there is nothing to open",
            ));
        }
        let HandleFrame {
            link: handle_link,
            offset: handle_offset,
        } = handle_frame(&scene, handle)?;
        let tool_link = scene.robot.require_link(tool_frame)?;
        let lower: Vec<f64> = scene.object_limits().iter().map(|l| l.lower).collect();
        let closed = scene.object.link_poses(&scene.object_pose, &lower)[handle_link] * handle_offset;
        Ok(Self {
            scene,
            handle_link,
            handle_offset,
            tool_link,
            tool_name: tool_frame.to_string(),
            closed,
        })
    }

    pub fn scene(&self) -> &Arc<Scene> {
        &self.scene
    }

    /// The robot's control frame, by name.
    pub fn tool_frame(&self) -> &str {
        &self.tool_name
    }

    /// The robot's control frame, as a link index of the robot.
    pub fn tool_link(&self) -> usize {
        self.tool_link
    }

    /// The handle's world pose at object configuration o (no).
    pub fn handle_pose(&self, o: &[f64]) -> Isometry3<f64> {
        self.scene.object.link_poses(&self.scene.object_pose, o)[self.handle_link] * self.handle_offset
    }

    /// The handle's world pose with the object's first joint at `opening` and the others at `o`'s.
    fn handle_pose_at(&self, o: &[f64], opening: f64) -> Isometry3<f64> {
        let mut at = o.to_vec();
        at[0] = opening;
        self.handle_pose(&at)
    }

    /// The grasp frame's world pose at robot configuration q (nq).
    pub fn tool_pose(&self, q: &[f64]) -> Isometry3<f64> {
        self.scene.robot.link_poses(&Isometry3::identity(), q)[self.tool_link]
    }

    /// The handle's pose with the object closed (every joint at its lower limit).
    pub fn closed_pose(&self) -> Isometry3<f64> {
        self.closed
    }

    /// The parts of a state x (nx): q, q̇, o, ȯ.
    pub fn split<'a>(&self, x: &'a [f64]) -> (&'a [f64], &'a [f64], &'a [f64], &'a [f64]) {
        let (nq, no) = (self.scene.nq(), self.scene.no());
        let (q, rest) = x.split_at(nq);
        let (q_dot, rest) = rest.split_at(nq);
        let (o, o_dot) = rest.split_at(no);
        (q, q_dot, o, o_dot)
    }

    /// Checks a state x (nx) before it is measured.
    pub fn check_state(&self, x: &[f64]) -> Result<()> {
        self.scene.check_state(x)
    }

    /// The handle and the grasp frame at state x (nx, checked by the caller).
    pub fn at(&self, x: &[f64]) -> HandAtHandle {
        let (q, _, o, o_dot) = self.split(x);
        HandAtHandle {
            handle: self.handle_pose(o),
            tool: self.tool_pose(q),
            opening: o[0],
            opening_rate: o_dot[0],
        }
    }

    /// Pose in the handle frame of a grasp target at `xyz` (m), the hand pointing `pitch` (rad)
    /// below the handle's normal: tilted about whichever handle axis (x or y) is horizontal with
    /// the object closed, in the sense that makes the grasp frame's z point downward.
    pub fn grasp_offset(&self, xyz: [f64; 3], pitch: f64) -> Result<Isometry3<f64>> {
        ensure_finite("grasp offset", &xyz)?;
        ensure_finite("pitch", &[pitch])?;
        let closed = self.closed.rotation;
        let x_tilt = (closed * Vector3::x()).z.abs() < (closed * Vector3::y()).z.abs();
        let axis = if x_tilt { Vector3::x_axis() } else { Vector3::y_axis() };
        let mut rot = Rotation3::from_axis_angle(&axis, pitch);
        if (closed * (rot * Vector3::z())).z > 0.0 {
            rot = rot.inverse(); // tilted up: the other way
        }
        Ok(Isometry3::from_parts(
            Translation3::new(xyz[0], xyz[1], xyz[2]),
            UnitQuaternion::from_rotation_matrix(&rot),
        ))
    }

    /// Distance (m) the handle moves per unit of opening (rad or m) at opening o of the first
    /// joint, the others at `o`'s (a central difference of 10⁻⁴ of the range, within the limits).
    pub fn travel(&self, o: &[f64]) -> f64 {
        let limits = &self.scene.object_limits()[0];
        let h = 1e-4 * (limits.upper - limits.lower);
        let lo = (o[0] - h).clamp(limits.lower, limits.upper);
        let hi = (o[0] + h).clamp(limits.lower, limits.upper);
        let moved = self.handle_pose_at(o, hi).translation.vector - self.handle_pose_at(o, lo).translation.vector;
        moved.norm() / (hi - lo).max(1e-12)
    }

    /// Speed (m/s) of the handle in the opening direction at state x (negative while closing).
    pub fn speed(&self, x: &[f64]) -> f64 {
        let (_, _, o, o_dot) = self.split(x);
        o_dot[0] * self.travel(o)
    }

    /// Distance (m) of the handle at state x from where it is with the object closed.
    pub fn distance_from_closed(&self, x: &[f64]) -> f64 {
        let (_, _, o, _) = self.split(x);
        (self.handle_pose(o).translation.vector - self.closed.translation.vector).norm()
    }

    /// Unit direction in which the hand backs off when releasing: away from the door (the grasp
    /// frame's −z) and, for a hinged door, out of its sweep (away from the hinge axis, found as the
    /// centre of the circle through three handle positions about the current opening), half each.
    pub fn release_direction(&self, x: &[f64]) -> Vector3<f64> {
        let (q, _, o, _) = self.split(x);
        let pose = self.tool_pose(q);
        let back = -(pose.rotation * Vector3::z());
        if !self.scene.object_is_revolute() {
            return back;
        }
        let [p0, p1, p2] = [o[0] - 0.1, o[0], o[0] + 0.1].map(|v| self.handle_pose_at(o, v).translation.vector);
        let (a, b) = (p0 - p1, p2 - p1);
        let normal = a.cross(&b);
        let nn = normal.norm_squared();
        if nn < 1e-12 {
            return back;
        }
        let centre = p1 + (a.norm_squared() * b.cross(&normal) + b.norm_squared() * normal.cross(&a)) / (2.0 * nn);
        let axis = normal / nn.sqrt();
        let mut radial = pose.translation.vector - centre;
        radial -= radial.dot(&axis) * axis;
        let norm = radial.norm();
        if norm < 1e-9 {
            return back;
        }
        let way = back + radial / norm;
        way / way.norm()
    }

    /// `steps + 1` grasp-frame targets that let go of the handle at `motion.speed` (m/s).
    ///
    /// A finger within `hooked_within` sideways of `entry_side` leaves the way it came in, riding
    /// on the handle as the object keeps opening at its current rate: back across the bar to
    /// `entry_side`, then back to `entry_depth`. Then the hand backs off `distance` along
    /// [`Self::release_direction`], fixed in the world. Backing off with the bar still in the
    /// pocket drags it, or lifts it against a door hinged below, which pushes the door back toward
    /// closed; following the handle for longer would chase a falling door into the robot.
    pub fn release_path(&self, x: &[f64], steps: usize, dt: f64, motion: &ReleaseMove) -> Result<Vec<Isometry3<f64>>> {
        self.check_state(x)?;
        ensure_finite("dt", &[dt])?;
        let (q, _, o, o_dot) = self.split(x);
        let relative = self.handle_pose(o).inverse() * self.tool_pose(q);
        let sideways = motion.entry_side - relative.translation.vector.y;
        let hooked = sideways.abs() <= motion.hooked_within; // else the finger slipped away: just back off
        let unhook = if hooked { sideways.abs() } else { 0.0 };
        let clear = if hooked {
            (relative.translation.vector.z - motion.entry_depth).max(0.0)
        } else {
            0.0
        };
        let upper = self.scene.object_limits()[0].upper;
        let rate = o_dot[0].max(0.0);
        let riding = |k: usize, travel: f64| {
            let mut offset = relative;
            offset.translation.vector.y += sign(sideways) * travel.min(unhook);
            offset.translation.vector.z -= (travel - unhook).clamp(0.0, clear);
            self.handle_pose_at(o, (o[0] + rate * dt * k as f64).min(upper)) * offset
        };
        let mut free: Option<(Isometry3<f64>, Vector3<f64>)> = None;
        let mut out = Vec::with_capacity(steps + 1);
        for k in 0..=steps {
            let travel = (motion.speed * dt * k as f64).min(unhook + clear + motion.distance);
            if travel < unhook + clear {
                out.push(riding(k, travel));
                continue;
            }
            // free of the bar: from where it got free, back off along a direction fixed in the world
            let (at, direction) = *free.get_or_insert_with(|| (riding(k, travel), self.release_direction(x)));
            let mut pose = at;
            pose.translation.vector += (travel - unhook - clear) * direction;
            out.push(pose);
        }
        Ok(out)
    }
}
