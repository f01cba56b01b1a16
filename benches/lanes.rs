//! What rollouts side by side in lanes would give the step: the robot's forward kinematics (the
//! product's `KinematicTree::update_frames`, one configuration per call) against the same walk over
//! L configurations at once, each quantity an array of L values (structure of arrays), for L = 1,
//! 2, 4 and 8, in the default build and with AVX2 enabled for the laned walk.
//!
//!     cargo bench --bench lanes [-- rounds]
//!
//! The laned walk uses the product's formulas (nalgebra's quaternion product and rotation, in
//! nalgebra's order of operations) and libm's `sin_cos` per lane; before timing, every pose of
//! every lane is checked equal to the bit to `update_frames`'. It is an evaluation of a direction,
//! not a code path of the library.

// A lane loop indexes several arrays by the same lane: the form the vectoriser reads.
#![allow(clippy::needless_range_loop)]

use std::hint::black_box;
use std::time::Instant;

use nalgebra::{Isometry3, UnitQuaternion};
use sabre::model::kinematics::{Frames, JointKind, KinematicTree};
use sabre::model::Scene;

/// A pose per lane: quaternion (w, i, j, k) and translation, each component an array over lanes.
#[derive(Clone, Copy)]
struct LanePose<const L: usize> {
    q: [[f64; L]; 4],
    t: [[f64; L]; 3],
}

impl<const L: usize> LanePose<L> {
    fn broadcast(pose: &Isometry3<f64>) -> Self {
        let (q, t) = (pose.rotation.quaternion(), pose.translation.vector);
        Self {
            q: [[q.w; L], [q.i; L], [q.j; L], [q.k; L]],
            t: [[t.x; L], [t.y; L], [t.z; L]],
        }
    }
}

/// v rotated by the unit quaternion q, per lane, as nalgebra computes it: t = 2 (q⃗ × v),
/// (w t + q⃗ × t) + v.
#[inline(always)]
fn rotate<const L: usize>(q: &[[f64; L]; 4], v: [[f64; L]; 3]) -> [[f64; L]; 3] {
    let mut out = [[0.0; L]; 3];
    for l in 0..L {
        let (w, x, y, z) = (q[0][l], q[1][l], q[2][l], q[3][l]);
        let (vx, vy, vz) = (v[0][l], v[1][l], v[2][l]);
        let tx = (y * vz - z * vy) * 2.0;
        let ty = (z * vx - x * vz) * 2.0;
        let tz = (x * vy - y * vx) * 2.0;
        out[0][l] = tx * w + (y * tz - z * ty) + vx;
        out[1][l] = ty * w + (z * tx - x * tz) + vy;
        out[2][l] = tz * w + (x * ty - y * tx) + vz;
    }
    out
}

/// The Hamilton product a b, per lane.
#[inline(always)]
fn product<const L: usize>(a: &[[f64; L]; 4], b: &[[f64; L]; 4]) -> [[f64; L]; 4] {
    let mut out = [[0.0; L]; 4];
    for l in 0..L {
        let (aw, ax, ay, az) = (a[0][l], a[1][l], a[2][l], a[3][l]);
        let (bw, bx, by, bz) = (b[0][l], b[1][l], b[2][l], b[3][l]);
        out[0][l] = aw * bw - ax * bx - ay * by - az * bz;
        out[1][l] = aw * bx + ax * bw + ay * bz - az * by;
        out[2][l] = aw * by - ax * bz + ay * bw + az * bx;
        out[3][l] = aw * bz + ax * by - ay * bx + az * bw;
    }
    out
}

/// The poses, joint axes and joint origins of every link for L configurations (`q[c][lane]`).
struct LaneFrames<const L: usize> {
    poses: Vec<LanePose<L>>,
    axes: Vec<[[f64; L]; 3]>,
    origins: Vec<[[f64; L]; 3]>,
}

impl<const L: usize> LaneFrames<L> {
    fn new(tree: &KinematicTree) -> Self {
        let identity = LanePose::broadcast(&Isometry3::identity());
        Self {
            poses: vec![identity; tree.links.len()],
            axes: vec![[[0.0; L]; 3]; tree.joints.len()],
            origins: vec![[[0.0; L]; 3]; tree.joints.len()],
        }
    }

    #[inline(always)]
    fn update(&mut self, tree: &KinematicTree, q: &[[f64; L]]) {
        for &j in &tree.topological_joints {
            let joint = &tree.joints[j];
            let parent = self.poses[joint.parent];
            let origin = LanePose::<L>::broadcast(&joint.origin);
            let moved = rotate(&parent.q, origin.t);
            let mut frame = LanePose {
                q: if joint.origin.rotation == UnitQuaternion::identity() {
                    parent.q
                } else {
                    product(&parent.q, &origin.q)
                },
                t: [[0.0; L]; 3],
            };
            for c in 0..3 {
                for l in 0..L {
                    frame.t[c][l] = parent.t[c][l] + moved[c][l];
                }
            }
            let Some(i) = joint.q_index else {
                self.poses[joint.child] = frame;
                continue;
            };
            let axis = [[joint.axis.x; L], [joint.axis.y; L], [joint.axis.z; L]];
            self.axes[j] = rotate(&frame.q, axis);
            self.origins[j] = frame.t;
            self.poses[joint.child] = match joint.kind {
                JointKind::Fixed => frame,
                JointKind::Revolute => {
                    let mut turn = [[0.0; L]; 4];
                    for l in 0..L {
                        let (s, c) = (q[i][l] * 0.5).sin_cos();
                        turn[0][l] = c;
                        for a in 0..3 {
                            turn[a + 1][l] = axis[a][l] * s;
                        }
                    }
                    LanePose {
                        q: product(&frame.q, &turn),
                        t: frame.t,
                    }
                }
                JointKind::Prismatic => {
                    let mut along = axis;
                    for row in &mut along {
                        for l in 0..L {
                            row[l] *= q[i][l];
                        }
                    }
                    let shift = rotate(&frame.q, along);
                    let mut t = frame.t;
                    for c in 0..3 {
                        for l in 0..L {
                            t[c][l] += shift[c][l];
                        }
                    }
                    LanePose { q: frame.q, t }
                }
            };
        }
    }
}

/// The walk compiled with AVX2 and FMA; call only where both are present.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn update_avx2<const L: usize>(frames: &mut LaneFrames<L>, tree: &KinematicTree, q: &[[f64; L]]) {
    frames.update(tree, q);
}

/// Whether this CPU runs [`update_avx2`] (never elsewhere than on x86-64).
fn has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Configurations to walk: each a small step from the last, within the joint limits.
fn configurations(tree: &KinematicTree, count: usize) -> Vec<Vec<f64>> {
    let nq = tree.active_joints.len();
    let mut state = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    let mut q = vec![0.1; nq];
    (0..count)
        .map(|_| {
            for (c, &j) in tree.active_joints.iter().enumerate() {
                let limits = &tree.joints[j].limits;
                q[c] = (q[c] + 0.05 * next()).clamp(limits.lower.max(-3.0), limits.upper.min(3.0));
            }
            q.clone()
        })
        .collect()
}

/// The configurations `[start, start + L)` laid out by coordinate, then lane.
fn lanes<const L: usize>(configs: &[Vec<f64>], start: usize) -> Vec<[f64; L]> {
    let nq = configs[0].len();
    (0..nq)
        .map(|c| std::array::from_fn(|l| configs[(start + l) % configs.len()][c]))
        .collect()
}

fn check<const L: usize>(tree: &KinematicTree, configs: &[Vec<f64>]) {
    let mut lane_frames = LaneFrames::<L>::new(tree);
    lane_frames.update(tree, &lanes::<L>(configs, 0));
    let mut frames = Frames::default();
    for l in 0..L {
        tree.update_frames(&Isometry3::identity(), &configs[l], &mut frames);
        for (link, pose) in frames.poses.iter().enumerate() {
            let lane = &lane_frames.poses[link];
            let t = pose.translation.vector;
            let q = pose.rotation.quaternion();
            let error = (0..3).map(|c| (lane.t[c][l] - t[c]).abs()).fold(0.0, f64::max).max(
                [q.w, q.i, q.j, q.k]
                    .iter()
                    .enumerate()
                    .map(|(c, v)| (lane.q[c][l] - v).abs())
                    .fold(0.0, f64::max),
            );
            assert!(error == 0.0, "lane {l} link {link}: {error}");
        }
    }
}

/// Nanoseconds per configuration of the laned walk, `avx2` selecting the feature-enabled copy
/// (which only x86-64 has).
fn time_lanes<const L: usize>(tree: &KinematicTree, configs: &[Vec<f64>], calls: usize, avx2: bool) -> f64 {
    #[cfg(not(target_arch = "x86_64"))]
    let _ = avx2;
    let batches: Vec<Vec<[f64; L]>> = (0..configs.len() / L).map(|b| lanes::<L>(configs, b * L)).collect();
    let mut frames = LaneFrames::<L>::new(tree);
    let start = Instant::now();
    for call in 0..calls {
        let q = &batches[call % batches.len()];
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: `avx2` is true only where `has_avx2` found both features.
            unsafe { update_avx2(&mut frames, tree, q) };
            black_box(&frames.poses);
            continue;
        }
        frames.update(tree, q);
        black_box(&frames.poses);
    }
    start.elapsed().as_secs_f64() * 1e9 / (calls * L) as f64
}

fn time_product(tree: &KinematicTree, configs: &[Vec<f64>], calls: usize) -> f64 {
    let mut frames = Frames::default();
    let start = Instant::now();
    for call in 0..calls {
        tree.update_frames(&Isometry3::identity(), &configs[call % configs.len()], &mut frames);
        black_box(&frames.poses);
    }
    start.elapsed().as_secs_f64() * 1e9 / calls as f64
}

fn main() {
    let rounds: usize = std::env::args()
        .skip(1)
        .find(|a| !a.starts_with('-'))
        .map(|a| a.parse().expect("rounds is a count"))
        .unwrap_or(5);
    let scene = Scene::load("royalpanda", "shelf", None).expect("built-in scene");
    let tree = &scene.robot;
    let configs = configurations(tree, 64 * 8 + 1);
    check::<1>(tree, &configs);
    check::<2>(tree, &configs);
    check::<4>(tree, &configs);
    check::<8>(tree, &configs);
    let avx2 = has_avx2();
    let calls = 200_000;
    println!(
        "forward kinematics of {} ({} joints, {} movable), ns per configuration; rounds alternate",
        tree.name,
        tree.joints.len(),
        tree.active_joints.len()
    );
    println!("round  product  lanes1  lanes2  lanes4  lanes8  lanes4+avx2  lanes8+avx2");
    for round in 0..rounds {
        let product = time_product(tree, &configs, calls);
        let one = time_lanes::<1>(tree, &configs, calls, false);
        let two = time_lanes::<2>(tree, &configs, calls / 2, false);
        let four = time_lanes::<4>(tree, &configs, calls / 4, false);
        let eight = time_lanes::<8>(tree, &configs, calls / 8, false);
        let (four_avx, eight_avx) = if avx2 {
            (
                time_lanes::<4>(tree, &configs, calls / 4, true),
                time_lanes::<8>(tree, &configs, calls / 8, true),
            )
        } else {
            (f64::NAN, f64::NAN)
        };
        println!("{round:>5} {product:>8.1} {one:>7.1} {two:>7.1} {four:>7.1} {eight:>7.1} {four_avx:>12.1} {eight_avx:>12.1}");
    }
}
