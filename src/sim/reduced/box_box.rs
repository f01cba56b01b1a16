//! Contact manifolds between two boxes as parry builds them (its separating-axis test, then the
//! support faces along the chosen axis clipped against each other: the same axis, points, features
//! and depths), computed with one rotation matrix instead of quaternion rotations, only the edge
//! pairs that straddle each other's lines (from the vertex sides the inside tests already give)
//! intersected, and the manifold rebuilt in place without the copy parry keeps for transferring
//! contact data the reduced path has none of.

use rapier3d_f64::parry::math::{Matrix, Pose, Vector};
use rapier3d_f64::parry::query::{ContactManifold, TrackedContact};
use rapier3d_f64::parry::shape::Cuboid;

/// Pose of box 2 in the frame of box 1: p₁ = R p₂ + t.
#[derive(Clone, Copy)]
struct Relative {
    r: Matrix,
    t: Vector,
}

impl Relative {
    fn new(pos12: &Pose) -> Self {
        Self {
            r: Matrix::from_quat(pos12.rotation),
            t: pos12.translation,
        }
    }

    fn inverse(&self) -> Self {
        let r = self.r.transpose();
        Self { r, t: -(r * self.t) }
    }

    fn apply(&self, p: Vector) -> Vector {
        self.r * p + self.t
    }
}

/// The point of a box (half extents `he`) furthest along `dir`, in its frame.
fn support(he: Vector, dir: Vector) -> Vector {
    he.copysign(dir)
}

/// Separation of box b (placed by `ba`) from box a along a's face normals: the largest, or, with b
/// beyond several faces at once, along the sum of those normals weighted by their separations
/// (parry's `cuboid_cuboid_find_local_separating_normal_oneway`). The direction is in a's frame.
fn separation_along_faces(he_a: Vector, he_b: Vector, ba: &Relative) -> (f64, Vector) {
    let mut best = (-f64::MAX, Vector::ZERO);
    let mut accumulated = Vector::ZERO;
    let mut positive = 0;
    for i in 0..3 {
        let sign = 1.0f64.copysign(ba.t[i]);
        let mut axis = Vector::ZERO;
        axis[i] = sign;
        let deepest_b = ba.apply(support(he_b, ba.r.transpose() * -axis));
        let separation = deepest_b[i] * sign - he_a[i];
        if separation > best.0 {
            best = (separation, axis);
        }
        if separation >= 0.0 {
            accumulated[i] += sign * separation.max(f64::EPSILON);
            positive += 1;
        }
    }
    if positive > 1 {
        let dir = accumulated.normalize();
        let deepest_b = ba.apply(support(he_b, ba.r.transpose() * -dir));
        return ((deepest_b - support(he_a, dir)).dot(dir), dir);
    }
    best
}

/// Separation of the two boxes along `axis` (unit, box 1's frame), turned to point from box 1
/// toward box 2.
fn separation_along_line(he1: Vector, he2: Vector, rel: &Relative, axis: Vector) -> (f64, Vector) {
    let axis = axis * 1.0f64.copysign(rel.t.dot(axis));
    let deepest2 = rel.apply(support(he2, rel.r.transpose() * -axis));
    ((deepest2 - support(he1, axis)).dot(axis), axis)
}

/// The largest separation along the nine cross products of an edge of each box.
fn separation_along_edges(he1: Vector, he2: Vector, rel: &Relative) -> (f64, Vector) {
    let mut best = (-f64::MAX, Vector::ZERO);
    for edge2 in [rel.r.x_axis, rel.r.y_axis, rel.r.z_axis] {
        for edge1 in [Vector::X, Vector::Y, Vector::Z] {
            let axis = edge1.cross(edge2);
            let norm = axis.length();
            if norm > f64::EPSILON {
                let candidate = separation_along_line(he1, he2, rel, axis / norm);
                if candidate.0 > best.0 {
                    best = candidate;
                }
            }
        }
    }
    best
}

/// Builds `manifold` for box 1 and box 2 at `pos12` (box 2 in box 1's frame): empty beyond
/// `prediction`, kept and updated while the pose moved less than parry's coherence thresholds.
pub(super) fn box_box_manifold(
    cuboid1: &Cuboid,
    cuboid2: &Cuboid,
    pos12: &Pose,
    prediction: f64,
    manifold: &mut ContactManifold<(), ()>,
) {
    if manifold.try_update_contacts(pos12) {
        return;
    }
    let (he1, he2) = (cuboid1.half_extents, cuboid2.half_extents);
    let rel = Relative::new(pos12);
    let inverse = rel.inverse();
    let faces1 = separation_along_faces(he1, he2, &rel);
    if faces1.0 > prediction {
        manifold.clear();
        return;
    }
    let faces2 = separation_along_faces(he2, he1, &inverse);
    if faces2.0 > prediction {
        manifold.clear();
        return;
    }
    let edges = separation_along_edges(he1, he2, &rel);
    if edges.0 > prediction {
        manifold.clear();
        return;
    }
    let mut best = faces1;
    if faces2.0 > faces1.0 && faces2.0 > edges.0 {
        best = (faces2.0, rel.r * -faces2.1);
    } else if edges.0 > faces1.0 {
        best = edges;
    }
    clip(cuboid1, cuboid2, &rel, &inverse, best.1, manifold);
}

/// Replaces `manifold`'s points with those of the two boxes' faces that support the normal `n1`
/// (box 1's frame, pointing from box 1 toward box 2) clipped against each other, as parry's
/// `PolygonalFeature::contacts` finds them: the vertices of each face inside the other's outline
/// (seen along `n1`), then the crossings of their edges.
pub(super) fn clip_support_faces(
    cuboid1: &Cuboid,
    cuboid2: &Cuboid,
    pos12: &Pose,
    n1: Vector,
    manifold: &mut ContactManifold<(), ()>,
) {
    let rel = Relative::new(pos12);
    clip(cuboid1, cuboid2, &rel, &rel.inverse(), n1, manifold);
}

fn clip(
    cuboid1: &Cuboid,
    cuboid2: &Cuboid,
    rel: &Relative,
    inverse: &Relative,
    n1: Vector,
    manifold: &mut ContactManifold<(), ()>,
) {
    let n2 = inverse.r * -n1;
    let face1 = cuboid1.support_face(n1);
    let face2 = cuboid2.support_face(n2);
    manifold.clear();
    manifold.local_n1 = n1;
    manifold.local_n2 = n2;
    let v1 = face1.vertices;
    let v2 = face2.vertices.map(|v| rel.apply(v));
    let (b0, b1) = n1.any_orthonormal_pair();
    let project = |v: &Vector| (v.dot(b0), v.dot(b1));
    let p1 = v1.map(|v| project(&v));
    let p2 = v2.map(|v| project(&v));
    let side = |a: (f64, f64), b: (f64, f64), p: (f64, f64)| (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0);
    // sides1[i][j]: where vertex j of face 2 lies from edge i of face 1 (vertex i to i + 1);
    // sides2[j][i] the same of face 1's vertices from face 2's edges.
    let mut sides1 = [[0.0; 4]; 4];
    let mut sides2 = [[0.0; 4]; 4];
    for e in 0..4 {
        for v in 0..4 {
            sides1[e][v] = side(p1[e], p1[(e + 1) % 4], p2[v]);
            sides2[e][v] = side(p2[e], p2[(e + 1) % 4], p1[v]);
        }
    }
    let normal2 = (v2[2] - v2[1]).cross(v2[0] - v2[1]);
    let denom2 = normal2.dot(n1);
    if denom2.abs() > f64::EPSILON {
        for i in (0..4).filter(|&i| inside(&sides2, i)) {
            let dist = (v2[0] - v1[i]).dot(normal2) / denom2;
            let on2 = inverse.apply(v1[i] + n1 * dist);
            manifold
                .points
                .push(TrackedContact::new(v1[i], on2, face1.vids[i], face2.fid, dist));
        }
    }
    let normal1 = (v1[2] - v1[1]).cross(v1[0] - v1[1]);
    let denom1 = -normal1.dot(n1);
    if denom1.abs() > f64::EPSILON {
        for j in (0..4).filter(|&j| inside(&sides1, j)) {
            let dist = (v1[0] - v2[j]).dot(normal1) / denom1;
            manifold.points.push(TrackedContact::new(
                v2[j] - n1 * dist,
                face2.vertices[j],
                face1.fid,
                face2.vids[j],
                dist,
            ));
        }
    }
    for j in 0..4 {
        for i in 0..4 {
            // Edges whose ends lie strictly on one side of the other's line cannot cross; the others
            // cross where parry's line intersection says, strictly inside both.
            if sides1[i][j] * sides1[i][(j + 1) % 4] > 0.0 || sides2[j][i] * sides2[j][(i + 1) % 4] > 0.0 {
                continue;
            }
            let Some((s, t)) = line_crossing([p1[i], p1[(i + 1) % 4]], [p2[j], p2[(j + 1) % 4]]) else {
                continue;
            };
            if !(s > 0.0 && s < 1.0 && t > 0.0 && t < 1.0) {
                continue;
            }
            let on1 = v1[i] * (1.0 - s) + v1[(i + 1) % 4] * s;
            let on2 = v2[j] * (1.0 - t) + v2[(j + 1) % 4] * t;
            let local2 = face2.vertices[j] * (1.0 - t) + face2.vertices[(j + 1) % 4] * t;
            manifold.points.push(TrackedContact::new(
                on1,
                local2,
                face1.eids[i],
                face2.eids[j],
                (on2 - on1).dot(n1),
            ));
        }
    }
}

/// Where two lines through 2D segments cross, as fractions along each (parry's
/// `closest_points_line2d`, after Ericson): None for parallel lines; a fraction of 0 where a
/// segment is a point.
fn line_crossing(edge1: [(f64, f64); 2], edge2: [(f64, f64); 2]) -> Option<(f64, f64)> {
    let dot = |a: (f64, f64), b: (f64, f64)| a.0 * b.0 + a.1 * b.1;
    let dir1 = (edge1[1].0 - edge1[0].0, edge1[1].1 - edge1[0].1);
    let dir2 = (edge2[1].0 - edge2[0].0, edge2[1].1 - edge2[0].1);
    let r = (edge1[0].0 - edge2[0].0, edge1[0].1 - edge2[0].1);
    let (a, e, f) = (dot(dir1, dir1), dot(dir2, dir2), dot(dir2, r));
    let eps = f64::EPSILON;
    if a <= eps && e <= eps {
        return Some((0.0, 0.0));
    }
    if a <= eps {
        return Some((0.0, f / e));
    }
    let c = dot(dir1, r);
    if e <= eps {
        return Some((-c / a, 0.0));
    }
    let b = dot(dir1, dir2);
    let (ae, bb) = (a * e, b * b);
    let denom = ae - bb;
    if denom <= eps || nearly_equal(ae, bb) {
        return None;
    }
    let s = (b * f - c * e) / denom;
    Some((s, (b * s + f) / e))
}

/// `approx`'s `ulps_eq` at its defaults: within machine epsilon, or four units in the last place.
fn nearly_equal(x: f64, y: f64) -> bool {
    if (x - y).abs() <= f64::EPSILON {
        return true;
    }
    x.signum() == y.signum() && (x.to_bits() as i64 - y.to_bits() as i64).unsigned_abs() <= 4
}

/// Whether vertex `v` of one face lies inside the other's outline: on the same side of all four
/// of its edges, or on one of them.
fn inside(sides: &[[f64; 4]; 4], v: usize) -> bool {
    let mut sign = sides[3][v];
    for edge in sides.iter().take(3) {
        let next = edge[v];
        if sign == 0.0 {
            sign = next;
        } else if sign * next < 0.0 {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rapier3d_f64::parry::math::{Pose, Rotation, Vector};
    use rapier3d_f64::parry::query::{ContactManifold, DefaultQueryDispatcher, PersistentQueryDispatcher};
    use rapier3d_f64::parry::shape::Cuboid;

    use super::box_box_manifold;

    /// How far (m) the two may place a point: where an edge crosses a nearly parallel one, the
    /// crossing moves by the rounding error over the sine of their angle along the edge.
    const POINT_TOLERANCE: f64 = 1e-8;

    fn random_box(rng: &mut ChaCha8Rng) -> Cuboid {
        Cuboid::new(Vector::new(
            rng.random_range(0.004..0.1),
            rng.random_range(0.004..0.1),
            rng.random_range(0.004..0.1),
        ))
    }

    /// A rotation: uniformly random (`tilt` None), or quarter turns about an axis tilted by up to
    /// `tilt` rad (exactly aligned boxes at 0).
    fn random_rotation(rng: &mut ChaCha8Rng, tilt: Option<f64>) -> Rotation {
        let axis = Vector::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        )
        .normalize();
        let Some(tilt) = tilt else {
            return Rotation::from_axis_angle(axis, rng.random_range(0.0..std::f64::consts::TAU));
        };
        let quarter = [Vector::X, Vector::Y, Vector::Z][rng.random_range(0..3)];
        let turns = rng.random_range(0..4) as f64 * std::f64::consts::FRAC_PI_2;
        let tilted = if tilt > 0.0 { rng.random_range(-tilt..tilt) } else { 0.0 };
        Rotation::from_axis_angle(axis, tilted) * Rotation::from_axis_angle(quarter, turns)
    }

    /// Parry's and sabre's manifolds for `cases` random pairs of boxes near each other; returns how
    /// many differ (points, features, depths or normal), after asserting every other agrees.
    fn compare(seed: u64, cases: usize, tilt: Option<f64>) -> usize {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (mut differ, mut skipped) = (0, 0);
        for _ in 0..cases {
            let (c1, c2) = (random_box(&mut rng), random_box(&mut rng));
            let reach = c1.half_extents + c2.half_extents;
            let t = Vector::new(
                rng.random_range(-1.1..1.1) * reach.x,
                rng.random_range(-1.1..1.1) * reach.y,
                rng.random_range(-1.1..1.1) * reach.z,
            );
            let pos12 = Pose::from_parts(t, random_rotation(&mut rng, tilt));
            let prediction = 0.01;
            let mut theirs = ContactManifold::<(), ()>::new();
            DefaultQueryDispatcher
                .contact_manifold_convex_convex(&pos12, &c1, &c2, None, None, prediction, &mut theirs)
                .unwrap();
            let mut ours = ContactManifold::<(), ()>::new();
            box_box_manifold(&c1, &c2, &pos12, prediction, &mut ours);
            // Exactly aligned boxes apart along an edge–edge axis see both support faces edge on:
            // which points their clipping gives then rests on rounding, in either implementation.
            let face_normal =
                |n: Vector| n.abs().max_element() > 1.0 - 1e-9 || (pos12.rotation.inverse() * n).abs().max_element() > 1.0 - 1e-9;
            if tilt == Some(0.0) && !(face_normal(theirs.local_n1) || theirs.points.is_empty() && face_normal(ours.local_n1)) {
                skipped += 1;
                continue;
            }
            let same = theirs.points.len() == ours.points.len()
                && (theirs.points.is_empty() || (theirs.local_n1 - ours.local_n1).length() < 1e-9)
                && theirs.points.iter().zip(&ours.points).all(|(a, b)| {
                    a.fid1 == b.fid1
                        && a.fid2 == b.fid2
                        && (a.local_p1 - b.local_p1).length() < POINT_TOLERANCE
                        && (a.local_p2 - b.local_p2).length() < POINT_TOLERANCE
                        && (a.dist - b.dist).abs() < POINT_TOLERANCE
                });
            differ += usize::from(!same);
        }
        assert!(skipped < cases / 4, "{skipped} of {cases} cases skipped");
        differ
    }

    #[test]
    fn box_box_manifolds_are_parrys() {
        for (seed, tilt) in [(1, None), (2, Some(0.05)), (3, Some(1e-6)), (4, Some(0.0))] {
            let differ = compare(seed, 20_000, tilt);
            assert_eq!(differ, 0, "seed {seed}, tilt {tilt:?}");
        }
    }
}
