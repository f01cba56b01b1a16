//! How the hook fits behind a handle's bar: the bar and the gap behind it measured from the object's
//! collision geometry, the tool's shape from the robot's, and the grasp targets of the insert, the hook
//! and the pull placed so that the finger passes beside the bar, its tip behind the bar and short of the
//! panel, between the standoffs; a tool that does not fit is refused with both sizes.
//!
//! The handle frame (x along the bar, y sideways toward the finger, z into the door, origin at the bar's
//! centre) is scanned with the object closed: rays along z, one per column (x, y), give the occupied
//! depths of every object part. The bar is what stands frontmost at the frame's origin: a column meets
//! it when its frontmost run starts in front of the bar's back face. That face is the shallowest of the
//! bar's per-x backs (a standoff or a panel fused with the bar makes a column's run longer, never
//! shorter); behind it, per x, the nearest occupied depth across the tip's sweep is the panel, a
//! standoff (at the back face: no gap) or nothing within the scan.
//!
//! The tool is every collision shape rigidly attached to the grasp frame. With the hand at a target
//! (x, y, z) and the configured pitch (or less, down to level, when the configured one does not fit),
//! its points must: at the bar's depth, stay beside it on the finger's side (−y); behind the bar, keep a
//! clearance from the panel; and behind the bar reach at least its middle across (the tip that holds it).
//! The configured targets are kept wherever they fit, so that a handle with room behind it is approached
//! as configured; otherwise each moves the least the geometry asks.

use nalgebra::{Isometry3, Point3, Vector3};
use rapier3d_f64::parry::query::Ray;
use rapier3d_f64::prelude::{Pose, SharedShape, Vector};

use super::handle::HandleGeometry;
use crate::error::{Result, SabreError};
use crate::model::collision_shape::shared_shape;
use crate::model::description::{Collision, Shape};
use crate::model::handle_frame::shape_points;

/// How far (m) in front of and behind the handle frame's origin the scan looks along z.
const DEPTH_REACH: f64 = 0.25;
/// How far (m) along the bar, each way, the scan looks for its ends.
const ALONG_REACH: f64 = 0.4;
/// Column spacing (m) along the bar, and across it where its faces are found.
const ALONG_STEP: f64 = 0.002;
const ACROSS_STEP: f64 = 0.0005;
/// How far beside the bar (m) on the finger's side and on the other the gap behind it is scanned:
/// where the tip sweeps while inserting and hooking.
const FINGER_SIDE: f64 = 0.035;
const FAR_SIDE: f64 = 0.015;
/// The deepest (m) a bar's front may stand behind the handle frame's origin.
const MAX_BAR_DEPTH: f64 = 0.02;
/// Depth steps (m) of the search for the insert depth, and pitch steps (rad) toward level.
const DEPTH_STEP: f64 = 0.0005;
const PITCH_STEP: f64 = 0.05;
/// How far (m) the tip's face behind the bar should clear its back face, where a pitch allows (the
/// shipped handles' 9.5–12 mm at the configured targets): closer, the tip sliding behind the bar
/// catches its edge.
const BITE_CLEARANCE: f64 = 0.005;
/// Spacing (m) of the points on the tool's box faces.
const SURFACE_STEP: f64 = 0.001;
const SURFACE_POINTS: f64 = 25.0;
/// How far (m) from the grasp frame the tool's points count.
const TOOL_REACH: f64 = 0.12;

/// The bar and the space behind it, in the handle frame (m).
#[derive(Debug, Clone, PartialEq)]
pub struct HandleClearance {
    /// The bar's extent along x (its ends), across y, and in depth z (front and back faces).
    pub along: [f64; 2],
    pub across: [f64; 2],
    pub front: f64,
    pub back: f64,
    /// Per x sample: the depth of the nearest surface behind the back face within the tip's sweep
    /// (the back face itself where a standoff stands; `DEPTH_REACH` where nothing is).
    pub xs: Vec<f64>,
    pub behind: Vec<f64>,
}

impl HandleClearance {
    /// The gap (m) behind the back face at x (the nearest sample; none outside the scan).
    pub fn gap_at(&self, x: f64) -> f64 {
        let i = self.xs.partition_point(|&s| s < x);
        let nearest = match (i.checked_sub(1), self.xs.get(i)) {
            (Some(a), Some(&b)) if (x - self.xs[a]).abs() <= (b - x).abs() => a,
            (Some(a), None) => a,
            (_, Some(_)) => i,
            (None, None) => return 0.0,
        };
        if x < self.xs[0] - ALONG_STEP || x > self.xs[self.xs.len() - 1] + ALONG_STEP {
            return 0.0;
        }
        self.behind[nearest] - self.back
    }

    /// The largest gap (m) behind the back face anywhere along the bar.
    pub fn widest_gap(&self) -> f64 {
        self.behind.iter().fold(0.0, |m, &b| m.max(b - self.back))
    }

    /// The bar's thickness across (m).
    pub fn thickness(&self) -> f64 {
        self.across[1] - self.across[0]
    }
}

/// The grasp targets that fit the handle (handle frame, m and rad) and what the fit measured.
#[derive(Debug, Clone, PartialEq)]
pub struct HandleFit {
    pub pitch: f64,
    pub pregrasp: [f64; 3],
    pub insert: [f64; 3],
    pub hook: [f64; 3],
    pub open: [f64; 3],
    /// Depth (m) from the bar's back face to the tip's face behind it with the hand at the hook
    /// target: how far a pull moves the hand before the tip bites.
    pub tip_behind: f64,
    /// The gap (m) behind the bar where the finger goes, and the least gap the tool needs there.
    pub gap: f64,
    pub need: f64,
    pub clearance: HandleClearance,
}

/// The configured targets a fit starts from and keeps where they fit.
#[derive(Debug, Clone, Copy)]
pub struct Preferred {
    pub pregrasp: [f64; 3],
    pub insert: [f64; 3],
    pub hook: [f64; 3],
    pub open: [f64; 3],
    pub pitch: f64,
    /// Clearance (m) kept from the bar and the panel.
    pub margin: f64,
}

/// Occupied depth intervals of one column, sorted and merged.
fn column(shapes: &[(SharedShape, Pose)], x: f64, y: f64) -> Vec<[f64; 2]> {
    let length = 2.0 * DEPTH_REACH;
    let forward = Ray::new(Vector::new(x, y, -DEPTH_REACH), Vector::new(0.0, 0.0, 1.0));
    let backward = Ray::new(Vector::new(x, y, DEPTH_REACH), Vector::new(0.0, 0.0, -1.0));
    let mut runs: Vec<[f64; 2]> = shapes
        .iter()
        .filter_map(|(shape, pose)| {
            let enter = shape.cast_ray(pose, &forward, length, true)?;
            let leave = shape.cast_ray(pose, &backward, length, true)?;
            Some([enter - DEPTH_REACH, DEPTH_REACH - leave])
        })
        .filter(|[a, b]| b >= a)
        .collect();
    runs.sort_by(|a, b| a[0].total_cmp(&b[0]));
    let mut merged: Vec<[f64; 2]> = Vec::with_capacity(runs.len());
    for run in runs {
        match merged.last_mut() {
            Some(last) if run[0] <= last[1] + 1e-9 => last[1] = last[1].max(run[1]),
            _ => merged.push(run),
        }
    }
    merged
}

/// The bar's run of a column whose bar has its back face at `back`: the frontmost run, when it starts
/// in front of that face (else the column misses the bar: the panel or a standoff is frontmost).
fn bar_run(runs: &[[f64; 2]], back: f64) -> Option<[f64; 2]> {
    runs.first().copied().filter(|[a, _]| *a < back - 1e-6)
}

/// The shallowest occupied depth at or past `from` (`DEPTH_REACH` when none).
fn first_from(runs: &[[f64; 2]], from: f64) -> f64 {
    runs.iter()
        .filter(|[_, b]| *b > from)
        .map(|[a, _]| a.max(from))
        .fold(DEPTH_REACH, f64::min)
}

/// The object's collision shapes in the handle frame with the object closed, those near the handle.
fn object_shapes(geometry: &HandleGeometry) -> Vec<(SharedShape, Pose)> {
    let scene = geometry.scene();
    let closed: Vec<f64> = scene.object_limits().iter().map(|l| l.lower).collect();
    let poses = scene.object.link_poses(&scene.object_pose, &closed);
    let to_handle = geometry.closed_pose().inverse();
    let reach = Vector3::new(ALONG_REACH, FINGER_SIDE + 0.1, DEPTH_REACH);
    let mut out = Vec::new();
    for (link, pose) in scene.object.links.iter().zip(&poses) {
        for c in &link.collisions {
            let placed = to_handle * pose * c.origin;
            let near = shape_points(c).iter().any(|p| {
                let q = to_handle * pose * p;
                (0..3).all(|k| q[k].abs() <= reach[k])
            });
            // a shape larger than the scan (a carcass board) has no corner in it: its centre decides
            let centre = placed.translation.vector;
            if near || (0..3).all(|k| centre[k].abs() <= reach[k] + c.shape.half_extents().norm()) {
                let (shape, frame) = shared_shape(&c.shape);
                out.push((shape, Pose::from(placed * frame)));
            }
        }
    }
    out
}

/// The bar and the gap behind it (see the module); None when nothing stands at the handle frame's
/// origin (a frame put elsewhere than on a bar: nothing to fit).
pub fn measure(geometry: &HandleGeometry) -> Option<HandleClearance> {
    let shapes = object_shapes(geometry);
    // the bar is frontmost at the frame's origin, within a bar's depth of it; its back face is the
    // shallowest end of the frontmost runs near the origin along it (a standoff or a panel fused with
    // the bar makes a run longer, never shorter)
    let [front, _] = *column(&shapes, 0.0, 0.0).first().filter(|r| r[0] <= MAX_BAR_DEPTH)?;
    let bar_back = (-8..=8)
        .filter_map(|k| column(&shapes, 0.005 * k as f64, 0.0).first().copied())
        .filter(|r| r[0] <= front + 0.005)
        .map(|r| r[1])
        .fold(f64::INFINITY, f64::min);
    // the bar's ends: the columns at y = 0 that meet it, contiguous from x = 0
    let extent = |step: f64, sign: f64, reach: f64, at: &dyn Fn(f64) -> bool| {
        let mut last = 0.0;
        let mut s = step;
        while s <= reach && at(sign * s) {
            last = sign * s;
            s += step;
        }
        last
    };
    let on_bar = |x: f64, y: f64| bar_run(&column(&shapes, x, y), bar_back).is_some();
    let along = [
        extent(ALONG_STEP, -1.0, ALONG_REACH, &|x| on_bar(x, 0.0)),
        extent(ALONG_STEP, 1.0, ALONG_REACH, &|x| on_bar(x, 0.0)),
    ];
    // across: the widest of the bar's faces at a few places along it
    let mut across = [0.0f64, 0.0f64];
    for k in 0..5 {
        let x = along[0] + (along[1] - along[0]) * (0.1 + 0.2 * k as f64);
        if !on_bar(x, 0.0) {
            continue;
        }
        across[0] = across[0].min(extent(ACROSS_STEP, -1.0, 0.1, &|y| on_bar(x, y)) - 0.5 * ACROSS_STEP);
        across[1] = across[1].max(extent(ACROSS_STEP, 1.0, 0.1, &|y| on_bar(x, y)) + 0.5 * ACROSS_STEP);
    }
    let count = ((along[1] - along[0]) / ALONG_STEP).round() as usize + 1;
    let xs: Vec<f64> = (0..count).map(|i| along[0] + i as f64 * ALONG_STEP).collect();
    let ys: Vec<f64> = {
        let (low, high) = (across[0] - FINGER_SIDE, across[1] + FAR_SIDE);
        let n = ((high - low) / 0.001).ceil() as usize;
        (0..=n).map(|i| low + i as f64 * (high - low) / n as f64).collect()
    };
    let columns: Vec<Vec<Vec<[f64; 2]>>> = xs
        .iter()
        .map(|&x| ys.iter().map(|&y| column(&shapes, x, y)).collect())
        .collect();
    let bar_y = |y: f64| across[0] < y && y < across[1];
    let mut front = front;
    let mut back = f64::INFINITY;
    for row in &columns {
        // beside the bar, the panel's face at this x: a bar run reaching it is fused with the panel
        let panel = ys
            .iter()
            .zip(row)
            .filter(|(y, _)| **y < across[0] - 0.001 || **y > across[1] + 0.001)
            .map(|(_, runs)| first_from(runs, 0.0))
            .fold(DEPTH_REACH, f64::min);
        let runs: Vec<[f64; 2]> = ys
            .iter()
            .zip(row)
            .filter(|(y, _)| bar_y(**y))
            .filter_map(|(_, r)| bar_run(r, bar_back))
            .collect();
        if runs.is_empty() {
            continue;
        }
        front = front.min(runs.iter().map(|r| r[0]).fold(f64::INFINITY, f64::min));
        let deepest = runs.iter().map(|r| r[1]).fold(f64::NEG_INFINITY, f64::max);
        if deepest < panel - 1e-4 {
            back = back.min(deepest);
        }
    }
    let behind = if back.is_finite() {
        columns
            .iter()
            .map(|row| {
                row.iter()
                    .map(|runs| first_from(runs, back + 5e-4))
                    .fold(DEPTH_REACH, f64::min)
            })
            .map(|b| if b <= back + 5e-4 { back } else { b })
            .collect()
    } else {
        // fused with the panel everywhere: no gap behind it
        back = bar_back;
        vec![back; xs.len()]
    };
    Some(HandleClearance {
        along,
        across,
        front,
        back,
        xs,
        behind,
    })
}

/// The points of every collision shape rigidly attached to the robot's grasp frame, in that frame,
/// within `TOOL_REACH` of it (farther back, the hand stays in front of the bar at any insert depth).
pub fn tool_points(geometry: &HandleGeometry) -> Vec<Point3<f64>> {
    let robot = &geometry.scene().robot;
    let tool = geometry.tool_link();
    let poses = robot.link_poses(&Isometry3::identity(), &vec![0.0; robot.nq()]);
    let joints = robot.ancestor_active_joints(tool);
    let to_grasp = poses[tool].inverse();
    robot
        .links
        .iter()
        .enumerate()
        .filter(|(i, _)| robot.ancestor_active_joints(*i) == joints)
        .flat_map(|(i, link)| {
            link.collisions
                .iter()
                .flat_map(move |c| surface_points(c).into_iter().map(move |p| (i, p)))
        })
        .map(|(i, p)| to_grasp * poses[i] * p)
        .filter(|p| p.coords.norm() <= TOOL_REACH)
        .collect()
}

/// Points on the surface of a collision shape in its link's frame, a box's faces on a grid of at most
/// `SURFACE_STEP` (a slanted face crossing the bar shows between its corners) and at most
/// `SURFACE_POINTS` intervals a side, other shapes by their hull's points.
fn surface_points(c: &Collision) -> Vec<Point3<f64>> {
    let Shape::Box { half_extents: h } = c.shape else {
        return shape_points(c);
    };
    let counts = h.map(|e| (2.0 * e / SURFACE_STEP).ceil().clamp(1.0, SURFACE_POINTS) as usize);
    let mut out = Vec::new();
    for i in 0..=counts.x {
        for j in 0..=counts.y {
            for k in 0..=counts.z {
                let on_face = i == 0 || i == counts.x || j == 0 || j == counts.y || k == 0 || k == counts.z;
                if on_face {
                    let at = |n: usize, of: usize, e: f64| -e + 2.0 * e * n as f64 / of as f64;
                    out.push(c.origin * Point3::new(at(i, counts.x, h.x), at(j, counts.y, h.y), at(k, counts.z, h.z)));
                }
            }
        }
    }
    out
}

/// One candidate: the hand at depth `z` and along `x` with the tool's points `points` (rotated by the
/// pitch, at the origin): the hook's and the insert's sideways positions, or None where it does not fit.
fn place(c: &HandleClearance, points: &[Vector3<f64>], x: f64, z: f64, want: &Preferred) -> Option<([f64; 2], f64)> {
    let m = want.margin;
    let (mut band, mut reaching) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
    let mut tip = f64::NEG_INFINITY;
    for p in points {
        let depth = p.z + z;
        if depth > c.back {
            // behind the bar: short of the panel (or a standoff) by the margin
            if depth > c.back + c.gap_at(p.x + x) - m {
                return None;
            }
        }
        if depth > c.front && depth < c.back {
            band = band.max(p.y);
        }
        if depth > c.front - m {
            reaching = reaching.max(p.y);
        }
        if depth >= c.back + m {
            tip = tip.max(p.y);
        }
    }
    if !tip.is_finite() {
        return None;
    }
    // hooked, the finger's face may touch the bar's side (the pocket holds it); passing it, it keeps clear
    let hook = want.hook[1].min(c.across[0] - band);
    let insert = want.insert[1].min(c.across[0] - m - reaching);
    // the tip holds the bar: behind it, it reaches at least the bar's middle across
    if tip + hook < 0.5 * (c.across[0] + c.across[1]) {
        return None;
    }
    // how far the tip's face behind the bar stands from its back face: the pull before it bites
    let bites = points
        .iter()
        .filter(|p| p.z + z > c.back && (c.across[0]..=c.across[1]).contains(&(p.y + hook)))
        .map(|p| p.z + z)
        .fold(f64::INFINITY, f64::min);
    bites.is_finite().then_some(([insert, hook], bites - c.back))
}

/// The targets that fit the measured handle (see the module), or an error with the gap and the need.
pub fn fit(geometry: &HandleGeometry, clearance: HandleClearance, tool: &[Point3<f64>], want: &Preferred) -> Result<HandleFit> {
    let c = &clearance;
    let mut pitches = vec![want.pitch];
    let steps = (want.pitch.abs() / PITCH_STEP).ceil() as usize;
    for k in 1..steps {
        pitches.push(want.pitch - (k as f64 * PITCH_STEP).copysign(want.pitch));
    }
    if want.pitch != 0.0 {
        pitches.push(0.0);
    }
    // x: the configured one first, then outward along the bar
    let mut xs: Vec<f64> = c.xs.clone();
    xs.sort_by(|a, b| (a - want.insert[0]).abs().total_cmp(&(b - want.insert[0]).abs()));
    xs.insert(0, want.insert[0]);
    // per pitch (the configured one first, then toward level), the first x (the configured one first)
    // with a depth that fits, the depth nearest the configured one; the first whose tip clears the
    // bar's back face by `BITE_CLEARANCE`, else the one that clears it most
    let search = |c: &HandleClearance, xs: &[f64], any: bool| -> Option<HandleFit> {
        let mut best: Option<HandleFit> = None;
        for &pitch in &pitches {
            let rotation = geometry.grasp_offset([0.0; 3], pitch).ok()?.rotation;
            let points: Vec<Vector3<f64>> = tool.iter().map(|p| rotation * p.coords).collect();
            let deepest = points.iter().map(|p| p.z).fold(f64::NEG_INFINITY, f64::max);
            // depths: the configured one, then nearer and farther, within the gap's reach
            let (low, high) = (c.front - deepest, c.back + c.widest_gap() - deepest);
            let count = ((high - low) / DEPTH_STEP).ceil().max(0.0) as usize;
            let mut zs: Vec<f64> = (0..=count).map(|i| low + i as f64 * DEPTH_STEP).collect();
            zs.sort_by(|a, b| (a - want.insert[2]).abs().total_cmp(&(b - want.insert[2]).abs()));
            zs.insert(0, want.insert[2]);
            let found = xs.iter().find_map(|&x| {
                zs.iter()
                    .find_map(|&z| place(c, &points, x, z, want).map(|placed| (x, z, placed)))
            });
            let Some((x, z, ([insert_y, hook_y], tip_behind))) = found else {
                continue;
            };
            let (dx, dz) = (x - want.insert[0], z - want.insert[2]);
            let pregrasp_z = want.pregrasp[2].min(c.front - want.margin - deepest);
            let candidate = HandleFit {
                pitch,
                pregrasp: [
                    want.pregrasp[0] + dx,
                    want.pregrasp[1] + insert_y - want.insert[1],
                    pregrasp_z,
                ],
                insert: [x, insert_y, z],
                hook: [want.hook[0] + dx, hook_y, want.hook[2] + dz],
                open: [want.open[0] + dx, want.open[1] + hook_y - want.hook[1], want.open[2] + dz],
                tip_behind,
                gap: c.gap_at(x),
                need: 0.0,
                clearance: c.clone(),
            };
            if any || tip_behind >= BITE_CLEARANCE {
                return Some(candidate);
            }
            if best.as_ref().is_none_or(|b| tip_behind > b.tip_behind) {
                best = Some(candidate);
            }
        }
        best
    };
    // the least gap the tool needs: the same bar with a uniform gap behind it, bisected
    let need = || {
        let uniform = |gap: f64| HandleClearance {
            behind: vec![c.back + gap; c.xs.len()],
            ..c.clone()
        };
        let at = [want.insert[0].clamp(c.along[0], c.along[1])];
        let (mut low, mut high) = (0.0, 0.1);
        search(&uniform(high), &at, true)?;
        for _ in 0..12 {
            let mid = 0.5 * (low + high);
            if search(&uniform(mid), &at, true).is_some() {
                high = mid;
            } else {
                low = mid;
            }
        }
        Some(high)
    };
    match search(c, &xs, false) {
        Some(mut found) => {
            found.need = need().unwrap_or(f64::NAN);
            Ok(found)
        }
        None => Err(refusal(c, need(), tool, geometry, want)),
    }
}

/// Why the tool does not fit, with the sizes.
fn refusal(
    c: &HandleClearance,
    need: Option<f64>,
    tool: &[Point3<f64>],
    geometry: &HandleGeometry,
    want: &Preferred,
) -> SabreError {
    let mm = |v: f64| 1000.0 * v;
    let reason = match need {
        Some(need) if need > c.widest_gap() => format!(
            "the gap behind its bar is {:.1} mm deep at the most (from the bar's back face to the panel or a standoff); \
             the tool's tip needs {:.1} mm there, {:.1} mm of clearance included",
            mm(c.widest_gap()),
            mm(need),
            mm(2.0 * want.margin)
        ),
        Some(need) => {
            let width = tool.iter().map(|p| p.x).fold(f64::NEG_INFINITY, f64::max)
                - tool.iter().map(|p| p.x).fold(f64::INFINITY, f64::min);
            let mut longest = 0.0f64;
            let mut start = None;
            for (x, b) in c.xs.iter().zip(&c.behind) {
                match (b - c.back >= need, start) {
                    (true, None) => start = Some(*x),
                    (false, Some(s)) => {
                        longest = longest.max(x - s);
                        start = None;
                    }
                    _ => {}
                }
            }
            if let (Some(s), Some(last)) = (start, c.xs.last()) {
                longest = longest.max(last - s);
            }
            format!(
                "the stretch of its bar with a gap of {:.1} mm behind it (what the tool's tip needs) is {:.1} mm long \
                 between the standoffs; the tool is {:.1} mm wide there",
                mm(need),
                mm(longest),
                mm(width)
            )
        }
        None => format!(
            "its bar is {:.1} mm thick across, and the tool's tip, with the finger {:.1} mm clear of the bar, does not reach \
             the bar's middle behind it",
            mm(c.thickness()),
            mm(want.margin)
        ),
    };
    SabreError::invalid(
        format!("handle of '{}'", geometry.scene().object.name),
        format!(
            "the hook does not fit: {reason}. Give the task the handle's grasp targets yourself \
             (OpenObject's approach and hook offsets) with the fit turned off (`approach.fit_clearance = None`), \
             or use a tool that fits"
        ),
    )
}

#[cfg(test)]
#[path = "handle_fit/tests.rs"]
mod tests;
