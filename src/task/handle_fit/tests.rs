//! The handle fit on bars whose sizes are written into the object: the measured bar and gap against
//! those numbers; the fitted targets checked with parry's distance queries on the tool's and the
//! object's shapes (clear of both at the insert and the hook, and a pull along the handle's −z meets
//! the bar first); the shipped objects keep the configured targets; a gap too tight is refused.

use std::sync::Arc;

use nalgebra::Isometry3;
use rapier3d_f64::parry::query::distance;
use rapier3d_f64::prelude::{Pose, SharedShape};

use super::*;
use crate::model::scene::{Scene, BUILTIN_ROBOTS};

/// The defaults of `OpenObjectConfig` the task fits.
fn preferred() -> Preferred {
    let c = crate::task::OpenObjectConfig::default();
    Preferred {
        pregrasp: c.pregrasp_offset,
        insert: c.insert_offset,
        hook: c.hook_offset,
        open: c.open_offset,
        pitch: c.pitch,
        margin: c.fit_clearance.unwrap(),
    }
}

/// A door hinged about −z at (0, 0.2, 0.8), its leaf's front the door frame's x = 0 plane, and a link
/// `grip`: a vertical bar `depth` (x) by `thick` (y) by 0.167 m with its back face `standoff` in front
/// of the leaf, on two 10 mm standoffs at z = ±0.07 (and one at z = 0 with `middle`).
fn door(depth: f64, thick: f64, standoff: f64, middle: bool) -> HandleGeometry {
    let post = |z: f64| {
        format!(
            r#"<collision><origin xyz="{:.5} 0 {z}"/><geometry><box size="{standoff:.5} 0.01 0.01"/></geometry></collision>"#,
            depth / 2.0 + standoff / 2.0
        )
    };
    let posts = match (standoff > 0.0, middle) {
        (false, _) => String::new(),
        (true, false) => post(-0.07) + &post(0.07),
        (true, true) => post(-0.07) + &post(0.07) + &post(0.0),
    };
    let object = format!(
        r#"<robot name="cabinet">
  <link name="body"><collision><origin xyz="0.25 0 0.5"/><geometry><box size="0.45 0.44 1.0"/></geometry></collision></link>
  <link name="door"><collision><origin xyz="0.009 -0.2 0"/><geometry><box size="0.018 0.4 0.6"/></geometry></collision></link>
  <link name="grip"><collision><geometry><box size="{depth:.5} {thick:.5} 0.167"/></geometry></collision>{posts}</link>
  <joint name="hinge" type="revolute"><parent link="body"/><child link="door"/><origin xyz="0 0.2 0.8"/>
    <axis xyz="0 0 -1"/><limit lower="0" upper="1.5" effort="10" velocity="1"/></joint>
  <joint name="grip_mount" type="fixed"><parent link="door"/><child link="grip"/>
    <origin xyz="{:.5} -0.32 0.05"/></joint>
</robot>"#,
        -(standoff + depth / 2.0)
    );
    let scene = Scene::from_urdf_strings(BUILTIN_ROBOTS[0].1, &object, Some(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0])).unwrap();
    HandleGeometry::new(Arc::new(scene), "grip", "grasp").unwrap()
}

/// Every collision shape of the object (closed) and of the tool's rigid group (with the grasp frame
/// at `target`, in the handle frame, pitched by `pitch`), in the world; the object's with their link.
type Placed = Vec<(SharedShape, Pose, String)>;
fn shapes_at(g: &HandleGeometry, target: [f64; 3], pitch: f64) -> (Placed, Placed) {
    let scene = g.scene();
    let closed: Vec<f64> = scene.object_limits().iter().map(|l| l.lower).collect();
    let object_poses = scene.object.link_poses(&scene.object_pose, &closed);
    let mut object = Vec::new();
    for (link, pose) in scene.object.links.iter().zip(&object_poses) {
        for c in &link.collisions {
            let (shape, frame) = shared_shape(&c.shape);
            object.push((shape, Pose::from(pose * c.origin * frame), link.name.clone()));
        }
    }
    let grasp_world = g.closed_pose() * g.grasp_offset(target, pitch).unwrap();
    let robot = &scene.robot;
    let poses = robot.link_poses(&Isometry3::identity(), &vec![0.0; robot.nq()]);
    let tool = g.tool_link();
    let mut hand = Vec::new();
    for (i, link) in robot.links.iter().enumerate() {
        if robot.ancestor_active_joints(i) != robot.ancestor_active_joints(tool) {
            continue;
        }
        for c in &link.collisions {
            let (shape, frame) = shared_shape(&c.shape);
            let pose = grasp_world * poses[tool].inverse() * poses[i] * c.origin * frame;
            hand.push((shape, Pose::from(pose), link.name.clone()));
        }
    }
    (object, hand)
}

/// The smallest distance between the tool and the object, and the object link it is to.
fn nearest(object: &Placed, hand: &Placed) -> (f64, String) {
    let mut best = (f64::INFINITY, String::new());
    for (a, pa, _) in hand {
        for (b, pb, link) in object {
            let d = distance(pa, a.as_ref(), pb, b.as_ref()).unwrap().distance;
            if d < best.0 {
                best = (d, link.clone());
            }
        }
    }
    best
}

/// The fitted targets are clear of the object at the insert and the hook by the margin (less the
/// surface sampling's millimetre), and pulling the hooked hand out along the handle's −z, the tool
/// meets the bar (the grip) first, within `bite` m.
fn assert_fits(g: &HandleGeometry, f: &HandleFit, margin: f64, bite: f64) {
    for (name, target) in [("insert", f.insert), ("hook", f.hook)] {
        let (object, hand) = shapes_at(g, target, f.pitch);
        let (d, link) = nearest(&object, &hand);
        let allowed = if name == "hook" { 0.0 } else { margin - SURFACE_STEP };
        assert!(d >= allowed - 1e-6, "{name}: the tool is {d} m from '{link}'");
    }
    let mut pulled = f.hook;
    loop {
        pulled[2] -= 0.0005;
        let (object, hand) = shapes_at(g, pulled, f.pitch);
        let (d, link) = nearest(&object, &hand);
        if d <= 1e-9 {
            assert_eq!(link, "grip", "the pull met '{link}' first");
            assert!(
                f.hook[2] - pulled[2] <= bite,
                "the tip bites only after {} m",
                f.hook[2] - pulled[2]
            );
            return;
        }
        assert!(f.hook[2] - pulled[2] < 0.1, "a pull of 10 cm met nothing");
    }
}

#[test]
fn the_measured_bar_and_gap_are_the_sizes_written_into_the_object() {
    for (depth, thick, standoff) in [
        (0.014, 0.014, 0.025),
        (0.01, 0.02, 0.04),
        (0.02, 0.012, 0.02),
        (0.01, 0.01, 0.056),
    ] {
        let g = door(depth, thick, standoff, false);
        let c = measure(&g).unwrap();
        // the inferred frame's origin lies half the bar's thickness seen from the front behind its front face
        let close = |got: f64, expected: f64, tolerance: f64, what: &str| {
            assert!(
                (got - expected).abs() <= tolerance,
                "{depth}/{thick}/{standoff}: {what} {got}, expected {expected}"
            )
        };
        close(c.front, -thick / 2.0, 1e-9, "front");
        close(c.back, depth - thick / 2.0, 1e-9, "back");
        close(c.across[0], -thick / 2.0, ACROSS_STEP, "across");
        close(c.across[1], thick / 2.0, ACROSS_STEP, "across");
        close(c.along[0], -0.0835, ALONG_STEP, "along");
        close(c.along[1], 0.0835, ALONG_STEP, "along");
        close(c.gap_at(0.0), standoff, 1e-9, "the gap midway");
        close(c.widest_gap(), standoff, 1e-9, "the widest gap");
        // the standoffs (10 mm wide, at ±0.07 along) leave no gap, and the tip's sweep beside the bar sees them
        for x in [-0.07, 0.07, 0.074, -0.066] {
            close(c.gap_at(x), 0.0, 1e-9, &format!("the gap at {x}"));
        }
    }
}

#[test]
fn the_shipped_objects_keep_the_configured_targets() {
    let want = preferred();
    for object in ["shelf", "microwave", "dishwasher", "drawer"] {
        let g = HandleGeometry::new(
            Arc::new(Scene::load("royalpanda", object, None).unwrap()),
            "handle_frame",
            "grasp",
        )
        .unwrap();
        let c = measure(&g).unwrap();
        // assets/objects/README.md: a 10 mm bar whose axis stands 61 mm in front of the panel
        assert!(
            (c.back - 0.005).abs() < 1e-9 && (c.front + 0.005).abs() < 1e-9,
            "{object}: {c:?}"
        );
        assert!((c.gap_at(0.0) - 0.056).abs() < 1e-9, "{object}: {c:?}");
        let f = fit(&g, c, &tool_points(&g), &want).unwrap();
        assert_eq!(
            (f.pitch, f.pregrasp, f.insert, f.hook, f.open),
            (want.pitch, want.pregrasp, want.insert, want.hook, want.open),
            "{object}"
        );
        assert!(f.need < 0.056 && f.tip_behind > 0.0, "{object}: {f:?}");
    }
}

#[test]
fn a_bar_on_short_standoffs_gets_targets_clear_of_bar_and_panel_that_hook_it() {
    let want = preferred();
    for (depth, thick, standoff) in [(0.014, 0.014, 0.025), (0.02, 0.02, 0.022), (0.01, 0.016, 0.03)] {
        let g = door(depth, thick, standoff, false);
        let f = fit(&g, measure(&g).unwrap(), &tool_points(&g), &want).unwrap();
        assert!(f.gap >= f.need && f.need > 0.0, "{f:?}");
        assert_fits(&g, &f, want.margin, 0.02);
    }
}

#[test]
fn a_standoff_midway_moves_the_finger_along_the_bar_beside_it() {
    let want = preferred();
    let g = door(0.014, 0.014, 0.025, true);
    let c = measure(&g).unwrap();
    assert_eq!(c.gap_at(0.0), 0.0);
    let f = fit(&g, c, &tool_points(&g), &want).unwrap();
    // the hook is 21 mm wide and the post 10 mm: the finger goes in beside the post
    assert!(f.insert[0].abs() >= 0.005, "{f:?}");
    assert!(f.hook[0] == f.insert[0] && f.open[0] == f.insert[0]);
    assert_fits(&g, &f, want.margin, 0.02);
}

#[test]
fn a_gap_too_tight_for_the_tip_is_refused_with_both_sizes() {
    let g = door(0.014, 0.014, 0.012, false);
    let error = fit(&g, measure(&g).unwrap(), &tool_points(&g), &preferred())
        .unwrap_err()
        .to_string();
    assert!(error.contains("12.0 mm deep"), "{error}");
    let need: f64 = error
        .split("needs ")
        .nth(1)
        .unwrap()
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!(need > 12.0 && need < 30.0, "{error}");
    // a gap just above the need fits
    let g = door(0.014, 0.014, need / 1000.0 + 0.001, false);
    assert!(fit(&g, measure(&g).unwrap(), &tool_points(&g), &preferred()).is_ok());
}

#[test]
fn a_bar_fused_with_the_panel_has_no_gap_and_is_refused() {
    let g = door(0.014, 0.014, 0.0, false);
    let c = measure(&g).unwrap();
    assert_eq!(c.widest_gap(), 0.0);
    assert!(fit(&g, c, &tool_points(&g), &preferred()).is_err());
}
