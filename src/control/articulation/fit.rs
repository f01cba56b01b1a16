//! Least-squares fits of a hand's path in space: a line (the weighted principal axis of the path, each
//! hooked stretch free to sit beside the others) and a circle (Levenberg–Marquardt on the geometric
//! distance, a Gaussian prior on the axis direction, the radius bounded), each with its χ² and the
//! standard deviations of what it estimates.

use nalgebra::{Matrix3, Point3, SMatrix, SVector, SymmetricEigen, Unit, Vector3};

/// A point of the path with its weight 1/σ² (1/m²), on hooked stretch `segment` (a hook that came off
/// and went in again may sit elsewhere along the bar).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WeightedPoint {
    pub p: Point3<f64>,
    pub w: f64,
    pub segment: usize,
}

/// A line through the path: the slide of a drawer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineFit {
    /// Unit direction (its sign is the caller's to choose).
    pub direction: Unit<Vector3<f64>>,
    /// The weighted centroid of the first stretch (a point on the line).
    pub origin: Point3<f64>,
    /// Σ w d² of the points' distances from their stretch's line.
    pub chi2: f64,
    /// Free parameters: the direction (2) and each stretch's offset (2 each).
    pub parameters: usize,
    /// Standard deviation (rad) of the direction's angle.
    pub direction_std: f64,
}

/// What the circle fit assumes before the data: the axis near `axis`, its tilt toward each of the two
/// unit directions of `tilts` (across the axis, across each other) with its σ (rad), and a radius
/// within `radius` (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CirclePrior {
    pub axis: Unit<Vector3<f64>>,
    pub tilts: [(Vector3<f64>, f64); 2],
    pub radius: (f64, f64),
}

impl CirclePrior {
    /// A prior with the same σ for every tilt.
    pub fn isotropic(axis: Unit<Vector3<f64>>, std: f64, radius: (f64, f64)) -> Self {
        let (b1, b2) = basis(&axis);
        Self {
            axis,
            tilts: [(b1, std), (b2, std)],
            radius,
        }
    }
}

/// A circle through the path: the arc of a door's handle about its hinge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CircleFit {
    /// Unit axis (its sign is the caller's to choose).
    pub axis: Unit<Vector3<f64>>,
    /// The centre, in the plane of the first stretch.
    pub center: Point3<f64>,
    pub radius: f64,
    /// Σ w d² of the points' distances from the circle, the prior's terms left out.
    pub chi2: f64,
    /// Free parameters: axis (2), centre (2), curvature (1), each stretch's height along the axis (1 each).
    pub parameters: usize,
    /// Standard deviations: of the axis's angle (rad), of the centre across the axis (m), of the radius (m).
    pub axis_std: f64,
    pub center_std: f64,
    pub radius_std: f64,
    /// Standard deviation (1/m) of the curvature 1/radius.
    pub curvature_std: f64,
    /// Whether the radius ended at a bound of the prior's range (the data ask for a straighter or a
    /// tighter arc than a door has).
    pub at_bound: bool,
}

fn segments(points: &[WeightedPoint]) -> usize {
    points.iter().map(|p| p.segment + 1).max().unwrap_or(0)
}

/// Per stretch: Σw and Σw p.
fn stretch_sums(points: &[WeightedPoint]) -> Vec<(f64, Vector3<f64>)> {
    let mut sums = vec![(0.0, Vector3::zeros()); segments(points)];
    for q in points {
        sums[q.segment].0 += q.w;
        sums[q.segment].1 += q.w * q.p.coords;
    }
    sums
}

/// Each stretch's centroid (None for a stretch without points).
fn centroids(points: &[WeightedPoint]) -> Vec<Option<Point3<f64>>> {
    stretch_sums(points)
        .into_iter()
        .map(|(w, s)| (w > 0.0).then(|| Point3::from(s / w)))
        .collect()
}

/// The line of the pooled scatter about each stretch's centroid; None with fewer than 3 points or a
/// path without extent.
pub fn fit_line(points: &[WeightedPoint]) -> Option<LineFit> {
    if points.len() < 3 {
        return None;
    }
    let c = centroids(points);
    let mut scatter = Matrix3::zeros();
    for q in points {
        let d = q.p - c[q.segment]?;
        scatter += q.w * d * d.transpose();
    }
    let eig = SymmetricEigen::new(scatter);
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let spread = eig.eigenvalues[order[0]];
    if spread.is_nan() || spread <= 0.0 {
        return None;
    }
    let chi2 = (eig.eigenvalues[order[1]] + eig.eigenvalues[order[2]]).max(0.0);
    let stretches = c.iter().filter(|c| c.is_some()).count();
    let parameters = 2 + 2 * stretches;
    let dof = (2 * points.len()).saturating_sub(parameters).max(1) as f64;
    // Each tilt of the direction has variance 1/Σw x² (x along the line); a fit worse than the weights
    // promise scales it by the reduced χ².
    let scale = (chi2 / dof).max(1.0);
    Some(LineFit {
        direction: Unit::new_normalize(eig.eigenvectors.column(order[0]).into_owned()),
        origin: c.iter().flatten().next().copied()?,
        chi2,
        parameters,
        direction_std: (2.0 * scale / spread).sqrt(),
    })
}

/// Two unit vectors completing `a` to a right-handed orthonormal basis.
pub fn basis(a: &Unit<Vector3<f64>>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if a.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    let b1 = a.cross(&helper).normalize();
    (b1, a.cross(&b1))
}

const NP: usize = 5;
type Params = SVector<f64, NP>;

/// The circle fit's parameters about the prior axis a₀ (basis b₁, b₂) and origin o: the axis tilts
/// (α, β), a = (a₀ + α b₁ + β b₂)/‖·‖; the centre c = o + u b₁ + v b₂; the curvature k = 1/r. Each
/// stretch's height along the axis is eliminated (its weighted mean residual), so a hook that went in
/// again elsewhere along the bar does not tilt the axis.
struct CircleProblem<'a> {
    points: &'a [WeightedPoint],
    a0: Unit<Vector3<f64>>,
    b1: Vector3<f64>,
    b2: Vector3<f64>,
    origin: Point3<f64>,
    /// The prior's tilt directions divided by their σ.
    prior: [Vector3<f64>; 2],
    k_range: (f64, f64),
    heights: Vec<(f64, f64)>,
}

impl CircleProblem<'_> {
    fn axis(&self, x: &Params) -> Unit<Vector3<f64>> {
        Unit::new_normalize(self.a0.into_inner() + x[0] * self.b1 + x[1] * self.b2)
    }

    fn center(&self, x: &Params) -> Point3<f64> {
        self.origin + x[2] * self.b1 + x[3] * self.b2
    }

    /// The weighted residuals (axial and radial per point, then the prior's two), into `out`.
    fn residuals(&mut self, x: &Params, out: &mut Vec<f64>) {
        let (a, c, r) = (self.axis(x), self.center(x), 1.0 / x[4]);
        self.heights.iter_mut().for_each(|h| *h = (0.0, 0.0));
        for q in self.points {
            let h = &mut self.heights[q.segment];
            h.0 += q.w;
            h.1 += q.w * a.dot(&(q.p - c));
        }
        out.clear();
        for q in self.points {
            let d = q.p - c;
            let along = a.dot(&d);
            let (w, s) = self.heights[q.segment];
            let sw = q.w.sqrt();
            out.push(sw * (along - s / w));
            out.push(sw * ((d - along * a.into_inner()).norm() - r));
        }
        let tilt = x[0] * self.b1 + x[1] * self.b2;
        out.push(tilt.dot(&self.prior[0]));
        out.push(tilt.dot(&self.prior[1]));
    }

    fn chi2(&mut self, x: &Params, scratch: &mut Vec<f64>) -> (f64, f64) {
        self.residuals(x, scratch);
        let n = scratch.len() - 2;
        let data: f64 = scratch[..n].iter().map(|r| r * r).sum();
        (data, data + scratch[n..].iter().map(|r| r * r).sum::<f64>())
    }

    fn clamp(&self, x: &mut Params) {
        x[4] = x[4].clamp(self.k_range.0, self.k_range.1);
    }

    /// JᵀJ and Jᵀr by central differences.
    fn normal_equations(&mut self, x: &Params, r0: &[f64]) -> (SMatrix<f64, NP, NP>, Params) {
        let steps = [1e-6, 1e-6, 1e-6, 1e-6, 1e-6 * x[4].abs().max(1e-3)];
        let mut jac = vec![Params::zeros(); r0.len()];
        let (mut plus, mut minus) = (Vec::new(), Vec::new());
        for (j, h) in steps.iter().enumerate() {
            let mut xp = *x;
            xp[j] += h;
            let mut xm = *x;
            xm[j] -= h;
            self.residuals(&xp, &mut plus);
            self.residuals(&xm, &mut minus);
            for (i, row) in jac.iter_mut().enumerate() {
                row[j] = (plus[i] - minus[i]) / (2.0 * h);
            }
        }
        let mut jtj = SMatrix::<f64, NP, NP>::zeros();
        let mut jtr = Params::zeros();
        for (row, r) in jac.iter().zip(r0) {
            jtj += row * row.transpose();
            jtr += row * *r;
        }
        (jtj, jtr)
    }
}

/// Iterations of the circle fit, and the relative drop of χ² below which it has converged.
const LM_ITERATIONS: usize = 40;
const LM_TOLERANCE: f64 = 1e-10;

/// The circle of the path about an axis near the prior's, from the line fit's chord; None with fewer
/// than 3 points or a path without extent.
pub fn fit_circle(points: &[WeightedPoint], prior: &CirclePrior) -> Option<CircleFit> {
    let line = fit_line(points)?;
    let a0 = prior.axis;
    let (r_lo, r_hi) = prior.radius;
    // The chord's direction within the plane across the prior axis, and the plane's other direction.
    let chord = line.direction.into_inner() - a0.dot(&line.direction) * a0.into_inner();
    if chord.norm() < 1e-6 {
        return None; // the path runs along the prior axis: no arc about it
    }
    let t1 = chord.normalize();
    let t2 = a0.cross(&t1);
    let origin = line.origin;
    // A weighted parabola y = c0 + c1 x + c2 x² in (t1, t2) starts the fit: its curvature and side.
    let mut m = nalgebra::Matrix3::zeros();
    let mut rhs = Vector3::zeros();
    for q in points.iter().filter(|q| q.segment == points[0].segment) {
        let d = q.p - origin;
        let (x, y) = (d.dot(&t1), d.dot(&t2));
        let f = Vector3::new(1.0, x, x * x);
        m += q.w * f * f.transpose();
        rhs += q.w * y * f;
    }
    let coef = m.lu().solve(&rhs).unwrap_or_else(Vector3::zeros);
    let slope = coef[1];
    let side = if coef[2] < 0.0 { -1.0 } else { 1.0 };
    let k0 = (2.0 * coef[2].abs() / (1.0 + slope * slope).powf(1.5)).clamp(1.0 / r_hi, 1.0 / r_lo);
    let normal = side * (-slope * t1 + t2) / (1.0 + slope * slope).sqrt();
    let c0 = origin + coef[0] * t2 + normal / k0;
    let mut problem = CircleProblem {
        points,
        a0,
        b1: t1,
        b2: t2,
        origin,
        prior: prior.tilts.map(|(d, std)| d / std),
        k_range: (1.0 / r_hi, 1.0 / r_lo),
        heights: vec![(0.0, 0.0); segments(points)],
    };
    let d0 = c0 - origin;
    let mut x = Params::new(0.0, 0.0, d0.dot(&t1), d0.dot(&t2), k0);
    let mut scratch = Vec::with_capacity(2 * points.len() + 2);
    let mut r0 = Vec::with_capacity(2 * points.len() + 2);
    let mut lambda = 1e-3;
    let (_, mut total) = problem.chi2(&x, &mut scratch);
    for _ in 0..LM_ITERATIONS {
        problem.residuals(&x, &mut r0);
        let (jtj, jtr) = problem.normal_equations(&x, &r0);
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = jtj;
            for i in 0..NP {
                damped[(i, i)] += lambda * jtj[(i, i)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|c| c.solve(&(-jtr))) else {
                lambda *= 10.0;
                continue;
            };
            let mut trial = x + step;
            problem.clamp(&mut trial);
            let (_, t) = problem.chi2(&trial, &mut scratch);
            if t.is_finite() && t <= total {
                let drop = (total - t) / total.max(1e-300);
                x = trial;
                total = t;
                lambda = (lambda / 3.0).max(1e-12);
                improved = drop > LM_TOLERANCE;
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    problem.clamp(&mut x);
    let at_bound = x[4] <= problem.k_range.0 * (1.0 + 1e-9) || x[4] >= problem.k_range.1 * (1.0 - 1e-9);
    let (chi2, _) = problem.chi2(&x, &mut scratch);
    problem.residuals(&x, &mut r0);
    let (jtj, _) = problem.normal_equations(&x, &r0);
    let stretches = problem.heights.iter().filter(|h| h.0 > 0.0).count();
    let parameters = NP + stretches;
    let dof = (2 * points.len()).saturating_sub(parameters).max(1) as f64;
    let scale = (chi2 / dof).max(1.0);
    let cov = jtj.try_inverse().map(|c| c * scale);
    let std = |i: usize, j: usize| cov.map_or(f64::INFINITY, |c| (c[(i, i)] + c[(j, j)]).max(0.0).sqrt());
    let k = x[4];
    let axis = problem.axis(&x);
    // The centre reported in the plane of the first stretch: the heights put each stretch's plane.
    let c = problem.center(&x);
    let (w0, s0) = problem.heights[points[0].segment];
    Some(CircleFit {
        axis,
        center: c + (s0 / w0) * axis.into_inner(),
        radius: 1.0 / k,
        chi2,
        parameters,
        axis_std: std(0, 1),
        center_std: std(2, 3),
        radius_std: cov.map_or(f64::INFINITY, |c| c[(4, 4)].max(0.0).sqrt() / (k * k)),
        curvature_std: cov.map_or(f64::INFINITY, |c| c[(4, 4)].max(0.0).sqrt()),
        at_bound,
    })
}
