//! The reduced path's velocity solve: projected Gauss–Seidel over soft contact rows (normal and
//! Coulomb friction) between the robot's proxy bodies and the object's joint coordinates, and the
//! object's joint limits and dry friction, with the soft-constraint formulation Rapier uses.

use nalgebra::{Matrix3, Point3, Vector3};

/// The most movable joints an object may have on the reduced path: a row's object part is a
/// fixed array, so that the solver's inner loop has no indirection. A solver is built for one
/// joint (most objects: rows without padding) or for up to this many.
pub const MAX_OBJECT_DOFS: usize = 8;

type ObjectVector<const N: usize> = [f64; N];

fn dot<const N: usize>(a: &ObjectVector<N>, b: &ObjectVector<N>) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// A robot contact body during the solve: a free rigid body with the robot's effective mass.
#[derive(Debug, Clone, Copy)]
pub(super) struct Proxy {
    pub inv_mass: f64,
    /// World-frame inverse inertia about the centre of mass.
    pub inv_inertia: Matrix3<f64>,
    pub com: Point3<f64>,
    /// Velocity of the centre of mass and angular velocity.
    pub v: Vector3<f64>,
    pub w: Vector3<f64>,
}

/// Constants of one solve.
#[derive(Debug, Clone, Copy)]
pub(super) struct SolverParams {
    pub dt: f64,
    /// Contact softness (Rapier's `erp_inv_dt` and `cfm_factor` of a spring of given natural
    /// frequency and damping ratio).
    pub erp_inv_dt: f64,
    pub cfm_factor: f64,
    /// Largest velocity with which an overlap is pushed apart (m/s).
    pub max_corrective_velocity: f64,
    /// Joint limits are stiff: the share of a limit violation removed per second.
    pub limit_erp_inv_dt: f64,
    pub iterations: usize,
    pub relaxation_iterations: usize,
}

/// Rapier's soft-constraint coefficients (its `SpringCoefficients`) for a constraint of natural
/// frequency `frequency` (Hz) and damping ratio `damping_ratio` at step `dt`: (erp / dt, cfm factor).
pub(super) fn softness(frequency: f64, damping_ratio: f64, dt: f64) -> (f64, f64) {
    let omega = 2.0 * std::f64::consts::PI * frequency;
    let erp_inv_dt = omega / (dt * omega + 2.0 * damping_ratio);
    let erp = dt * erp_inv_dt;
    let inv_erp_minus_one = 1.0 / erp - 1.0;
    let cfm_coeff = inv_erp_minus_one * inv_erp_minus_one / ((1.0 + inv_erp_minus_one) * 4.0 * damping_ratio * damping_ratio);
    (erp_inv_dt, 1.0 / (1.0 + cfm_coeff))
}

const NO_PROXY: usize = usize::MAX;

/// One scalar constraint row: J v + rhs ≥ 0 (or within bounds), J acting on at most one proxy and
/// on the object's coordinates.
#[derive(Debug, Clone, Copy)]
struct Row<const N: usize> {
    proxy: usize,
    /// Linear and angular parts of J on the proxy, and the same through its inverse mass.
    lin: Vector3<f64>,
    ang: Vector3<f64>,
    m_lin: Vector3<f64>,
    m_ang: Vector3<f64>,
    /// Object part of J (on ȯ) and W Jᵀ, zero beyond the object's coordinates.
    object_j: ObjectVector<N>,
    object_wj: ObjectVector<N>,
    inv_k: f64,
    rhs: f64,
    rhs_wo_bias: f64,
    impulse: f64,
}

/// A contact's three rows (normal, two tangents) and its friction coefficient.
#[derive(Debug, Clone, Copy)]
struct ContactRows {
    first: usize,
    friction: f64,
}

/// A joint row and its impulse bounds.
#[derive(Debug, Clone, Copy)]
struct BoundedRow {
    row: usize,
    lower: f64,
    upper: f64,
    /// Whether the row's rhs carries a position bias (limits) or not (dry friction).
    biased: bool,
}

/// The solve's bodies, rows and impulses for an object of at most N joints; buffers are reused
/// from step to step.
#[derive(Debug, Clone)]
pub(super) struct Solver<const N: usize> {
    no: usize,
    pub proxies: Vec<Proxy>,
    /// The object's generalized velocity (zero beyond its coordinates).
    od: ObjectVector<N>,
    /// (M + dt D)⁻¹ of the object, row-major in its first `no` × `no` entries.
    inverse_mass: [ObjectVector<N>; N],
    rows: Vec<Row<N>>,
    contacts: Vec<ContactRows>,
    bounded: Vec<BoundedRow>,
}

/// Two unit vectors orthogonal to `n` and to each other.
fn tangents(n: &Vector3<f64>) -> [Vector3<f64>; 2] {
    let helper = if n.x.abs() < 0.6 { Vector3::x() } else { Vector3::y() };
    let t1 = n.cross(&helper).normalize();
    [t1, n.cross(&t1)]
}

impl<const N: usize> Default for Solver<N> {
    fn default() -> Self {
        Self {
            no: 0,
            proxies: Vec::new(),
            od: [0.0; N],
            inverse_mass: [[0.0; N]; N],
            rows: Vec::new(),
            contacts: Vec::new(),
            bounded: Vec::new(),
        }
    }
}

impl<const N: usize> Solver<N> {
    /// Starts a solve over the object's `no` coordinates moving at `od` with inverse (augmented)
    /// mass `inverse_mass` (no × no, row-major); proxies are set through [`Self::proxies`].
    pub fn begin(&mut self, od: &[f64], inverse_mass: &[f64]) {
        let no = od.len();
        assert!(no <= N, "this solver takes at most {N} object joints");
        self.no = no;
        self.od = [0.0; N];
        self.od[..no].copy_from_slice(od);
        self.inverse_mass = [[0.0; N]; N];
        for (a, row) in self.inverse_mass.iter_mut().take(no).enumerate() {
            row[..no].copy_from_slice(&inverse_mass[a * no..(a + 1) * no]);
        }
        self.proxies.clear();
        self.rows.clear();
        self.contacts.clear();
        self.bounded.clear();
    }

    /// Adds a row acting on `proxy` at `point` along `dir` (linear part; none for joint rows) and on
    /// the object with J_o = `j`.
    #[inline(always)]
    fn push_row(&mut self, proxy: Option<(usize, &Point3<f64>, &Vector3<f64>)>, j: ObjectVector<N>) -> usize {
        let no = self.no;
        let mut wj = [0.0; N];
        for (slot, row) in wj.iter_mut().zip(&self.inverse_mass).take(no) {
            *slot = row[..no].iter().zip(&j[..no]).map(|(a, b)| a * b).sum();
        }
        let mut k: f64 = j[..no].iter().zip(&wj[..no]).map(|(a, b)| a * b).sum();
        let (index, lin, ang, m_lin, m_ang) = match proxy {
            Some((index, point, dir)) => {
                let body = &self.proxies[index];
                let ang = (point - body.com).cross(dir);
                let m_lin = dir * body.inv_mass;
                let m_ang = body.inv_inertia * ang;
                k += dir.dot(&m_lin) + ang.dot(&m_ang);
                (index, *dir, ang, m_lin, m_ang)
            }
            None => (
                NO_PROXY,
                Vector3::zeros(),
                Vector3::zeros(),
                Vector3::zeros(),
                Vector3::zeros(),
            ),
        };
        self.rows.push(Row {
            proxy: index,
            lin,
            ang,
            m_lin,
            m_ang,
            object_j: j,
            object_wj: wj,
            inv_k: if k > 0.0 { 1.0 / k } else { 0.0 },
            rhs: 0.0,
            rhs_wo_bias: 0.0,
            impulse: 0.0,
        });
        self.rows.len() - 1
    }

    /// A contact of proxy `proxy` with the object at `point`, `normal` pointing from the object to
    /// the robot, signed distance `dist`; `object_jacobian` is the linear point Jacobian of the
    /// object's link at the point (3 × no, column-major; zeros for a fixed link). `warm` is the
    /// impulse the same contact carried in the previous step (on the robot, world frame), the
    /// solve's starting point.
    #[allow(clippy::too_many_arguments)]
    pub fn add_contact(
        &mut self,
        params: &SolverParams,
        proxy: usize,
        point: &Point3<f64>,
        normal: &Vector3<f64>,
        dist: f64,
        object_jacobian: &[f64],
        friction: f64,
        warm: Option<Vector3<f64>>,
    ) {
        let no = self.no;
        let project = |dir: &Vector3<f64>| {
            let mut j = [0.0; N];
            for (c, slot) in j.iter_mut().enumerate().take(no) {
                let column = &object_jacobian[3 * c..3 * c + 3];
                *slot = -(column[0] * dir.x + column[1] * dir.y + column[2] * dir.z);
            }
            j
        };
        let first = self.push_row(Some((proxy, point, normal)), project(normal));
        // A gap may close within the step (speculative contact); an overlap is pushed apart at
        // the contact's stiffness, no faster than the corrective velocity bound.
        let rhs_wo_bias = dist.max(0.0) / params.dt;
        let row = &mut self.rows[first];
        row.rhs_wo_bias = rhs_wo_bias;
        row.rhs = rhs_wo_bias + (params.erp_inv_dt * dist).clamp(-params.max_corrective_velocity, 0.0);
        for t in tangents(normal) {
            self.push_row(Some((proxy, point, &t)), project(&t));
        }
        self.contacts.push(ContactRows { first, friction });
        if let Some(impulse) = warm {
            for row in first..first + 3 {
                let start = impulse.dot(&self.rows[row].lin);
                let start = if row == first { start.max(0.0) } else { start };
                self.rows[row].impulse = start;
                self.apply(row, start);
            }
        }
    }

    /// The limit of coordinate `dof` at signed distance `distance` inside its range (negative:
    /// beyond it); `lower` says which end. The row keeps the coordinate from moving past the limit
    /// within the step and pushes it back stiffly once beyond.
    pub fn add_limit(&mut self, params: &SolverParams, dof: usize, lower: bool, distance: f64) {
        let sign = if lower { 1.0 } else { -1.0 };
        let mut j = [0.0; N];
        j[dof] = sign;
        let row = self.push_row(None, j);
        let rhs_wo_bias = distance.max(0.0) / params.dt;
        self.rows[row].rhs_wo_bias = rhs_wo_bias;
        self.rows[row].rhs = rhs_wo_bias + params.limit_erp_inv_dt * distance.min(0.0);
        self.bounded.push(BoundedRow {
            row,
            lower: 0.0,
            upper: f64::INFINITY,
            biased: true,
        });
    }

    /// Dry friction on coordinate `dof`: its velocity is held at zero by at most `max_impulse`.
    pub fn add_dry_friction(&mut self, dof: usize, max_impulse: f64) {
        let mut j = [0.0; N];
        j[dof] = 1.0;
        let row = self.push_row(None, j);
        self.bounded.push(BoundedRow {
            row,
            lower: -max_impulse,
            upper: max_impulse,
            biased: false,
        });
    }

    #[inline(always)]
    fn velocity(&self, row: &Row<N>) -> f64 {
        let mut v = dot(&row.object_j, &self.od);
        if row.proxy != NO_PROXY {
            let body = &self.proxies[row.proxy];
            v += row.lin.dot(&body.v) + row.ang.dot(&body.w);
        }
        v
    }

    #[inline(always)]
    fn apply(&mut self, row: usize, delta: f64) {
        let r = &self.rows[row];
        if r.proxy != NO_PROXY {
            let body = &mut self.proxies[r.proxy];
            body.v += r.m_lin * delta;
            body.w += r.m_ang * delta;
        }
        for (od, wj) in self.od.iter_mut().zip(&r.object_wj) {
            *od += wj * delta;
        }
    }

    /// The object's generalized velocity.
    pub fn object_velocity(&self) -> &[f64] {
        &self.od[..self.no]
    }

    /// One sweep over every row; `biased` selects the position-correcting pass (with contact
    /// softness) or the relaxation that removes the correction from the velocities it leaves.
    fn sweep(&mut self, biased: bool, cfm_factor: f64) {
        for b in 0..self.bounded.len() {
            let BoundedRow {
                row,
                lower,
                upper,
                biased: has_bias,
            } = self.bounded[b];
            let r = &self.rows[row];
            let rhs = if biased && has_bias { r.rhs } else { r.rhs_wo_bias };
            let old = r.impulse;
            let impulse = (old - (self.velocity(r) + rhs) * r.inv_k).clamp(lower, upper);
            self.rows[row].impulse = impulse;
            self.apply(row, impulse - old);
        }
        let cfm = if biased { cfm_factor } else { 1.0 };
        for c in 0..self.contacts.len() {
            let first = self.contacts[c].first;
            let n = &self.rows[first];
            let rhs = if biased { n.rhs } else { n.rhs_wo_bias };
            let old = n.impulse;
            let impulse = (cfm * (old - (self.velocity(n) + rhs) * n.inv_k)).max(0.0);
            self.rows[first].impulse = impulse;
            self.apply(first, impulse - old);
        }
        // Friction acts on the velocities the step ends with, not on the push that corrects
        // overlaps (as Rapier leaves it out of its position-correcting pass).
        if biased {
            return;
        }
        for c in 0..self.contacts.len() {
            let ContactRows { first, friction } = self.contacts[c];
            // Coulomb friction: both tangent impulses together stay within the cone.
            let (t1, t2) = (&self.rows[first + 1], &self.rows[first + 2]);
            let old = [t1.impulse, t2.impulse];
            let mut f = [old[0] - self.velocity(t1) * t1.inv_k, old[1] - self.velocity(t2) * t2.inv_k];
            let limit = friction * self.rows[first].impulse;
            let norm = (f[0] * f[0] + f[1] * f[1]).sqrt();
            if norm > limit {
                let scale = if norm > 0.0 { limit / norm } else { 0.0 };
                f = [f[0] * scale, f[1] * scale];
            }
            for j in 0..2 {
                let row = first + 1 + j;
                self.rows[row].impulse = f[j];
                self.apply(row, f[j] - old[j]);
            }
        }
    }

    /// The position-correcting solve; its velocities move the object over the step.
    pub fn solve(&mut self, params: &SolverParams) {
        for _ in 0..params.iterations {
            self.sweep(true, params.cfm_factor);
        }
    }

    /// The relaxation after the positions moved: the velocities the object keeps, without the
    /// push that corrected overlaps.
    pub fn relax(&mut self, params: &SolverParams) {
        for _ in 0..params.relaxation_iterations {
            self.sweep(false, 1.0);
        }
    }

    /// The impulse each contact put on the robot, in the order the contacts were added (world
    /// frame, N·s).
    pub fn contact_impulses(&self) -> impl Iterator<Item = Vector3<f64>> + '_ {
        self.contacts.iter().map(|c| {
            let (n, t1, t2) = (&self.rows[c.first], &self.rows[c.first + 1], &self.rows[c.first + 2]);
            n.lin * n.impulse + t1.lin * t1.impulse + t2.lin * t2.impulse
        })
    }
}

#[cfg(test)]
mod tests {
    use approx::assert_relative_eq;

    use super::*;

    fn params(iterations: usize) -> SolverParams {
        let (erp_inv_dt, cfm_factor) = softness(60.0, 1.0, 0.015);
        SolverParams {
            dt: 0.015,
            erp_inv_dt,
            cfm_factor,
            max_corrective_velocity: 3.0,
            limit_erp_inv_dt: 1.0 / 0.015,
            iterations,
            relaxation_iterations: iterations,
        }
    }

    fn ball(mass: f64, v: Vector3<f64>) -> Proxy {
        Proxy {
            inv_mass: 1.0 / mass,
            inv_inertia: Matrix3::identity() * (1.0 / (0.4 * mass * 0.05 * 0.05)),
            com: Point3::origin(),
            v,
            w: Vector3::zeros(),
        }
    }

    #[test]
    fn softness_matches_the_spring_it_models() {
        // erp/dt = ω / (dt ω + 2ζ); cfm_coeff = (1/erp − 1)² / ((1/erp) 4 ζ²).
        let (dt, f, zeta) = (0.015, 60.0, 1.0);
        let (erp_inv_dt, cfm_factor) = softness(f, zeta, dt);
        let omega = 2.0 * std::f64::consts::PI * f;
        assert_relative_eq!(erp_inv_dt, omega / (dt * omega + 2.0), max_relative = 1e-12);
        let erp = erp_inv_dt * dt;
        let coeff = (1.0 / erp - 1.0).powi(2) / (4.0 / erp);
        assert_relative_eq!(cfm_factor, 1.0 / (1.0 + coeff), max_relative = 1e-12);
        assert!(cfm_factor < 1.0 && cfm_factor > 0.5);
    }

    /// A proxy of mass m moving at v along −x into a free slider of mass M (one prismatic
    /// coordinate along x), touching: with hard rows the two end at a common velocity,
    /// m v / (m + M) (momentum conserved, a perfectly inelastic impact).
    #[test]
    fn an_impact_conserves_momentum_and_ends_at_the_common_velocity() {
        let (m, big_m, v) = (2.0, 3.0, 0.5);
        let mut p = params(30);
        p.cfm_factor = 1.0;
        let mut solver = Solver::<1>::default();
        solver.begin(&[0.0], &[1.0 / big_m]);
        solver.proxies.push(ball(m, Vector3::new(-v, 0.0, 0.0)));
        // The slider's point moves with ȯ along x: J_o = x̂. The object pushes the robot along +x.
        solver.add_contact(&p, 0, &Point3::origin(), &Vector3::x(), 0.0, &[1.0, 0.0, 0.0], 0.0, None);
        solver.relax(&p); // no overlap: the relaxation alone is the hard solve
        let common = -m * v / (m + big_m);
        assert_relative_eq!(solver.proxies[0].v.x, common, epsilon = 1e-9);
        assert_relative_eq!(solver.object_velocity()[0], common, epsilon = 1e-9);
        let impulse: Vector3<f64> = solver.contact_impulses().sum();
        assert_relative_eq!(impulse.x, m * (common + v), epsilon = 1e-9);
        assert_relative_eq!(impulse.x, -big_m * common, epsilon = 1e-9);
    }

    /// A proxy sliding along a fixed surface while pressed into it: the tangential impulse is
    /// μ times the normal one and opposes the sliding.
    #[test]
    fn sliding_friction_sits_on_the_cone_and_opposes_the_motion() {
        let p = params(20);
        let mut solver = Solver::<1>::default();
        solver.begin(&[0.0], &[1.0]);
        solver.proxies.push(ball(1.0, Vector3::new(2.0, 0.0, -0.3)));
        solver.add_contact(&p, 0, &Point3::origin(), &Vector3::z(), 0.0, &[0.0, 0.0, 0.0], 0.2, None);
        solver.solve(&p);
        // Friction acts in the relaxation only.
        let pressed: Vector3<f64> = solver.contact_impulses().sum();
        assert_eq!((pressed.x, pressed.y), (0.0, 0.0));
        solver.relax(&p);
        let impulse: Vector3<f64> = solver.contact_impulses().sum();
        assert!(impulse.z > 0.0);
        assert_relative_eq!(impulse.x, -0.2 * impulse.z, max_relative = 1e-9);
        assert_relative_eq!(impulse.y, 0.0, epsilon = 1e-12);
        assert!(solver.proxies[0].v.x > 0.0, "still sliding: {}", solver.proxies[0].v.x);
    }

    /// The solver sized for one joint and the one sized for the most joints solve a one-joint
    /// object alike, to the bit: the padding of the larger one only ever adds zeros.
    #[test]
    fn the_one_joint_solver_and_the_padded_one_agree_exactly() {
        fn run<const N: usize>() -> (Vec<f64>, Vector3<f64>, Vector3<f64>) {
            let p = params(3);
            let mut solver = Solver::<N>::default();
            solver.begin(&[0.4], &[0.7]);
            solver.proxies.push(ball(1.5, Vector3::new(-0.3, 0.2, -0.6)));
            let normal = Vector3::new(0.3, -0.2, 1.0).normalize();
            let jacobian = [0.2, -0.5, 0.1];
            solver.add_contact(
                &p,
                0,
                &Point3::new(0.01, 0.02, 0.0),
                &normal,
                -0.002,
                &jacobian,
                0.4,
                Some(Vector3::new(0.1, 0.0, 0.3)),
            );
            solver.add_limit(&p, 0, false, 0.003);
            solver.add_dry_friction(0, 0.05);
            solver.solve(&p);
            solver.relax(&p);
            let impulse: Vector3<f64> = solver.contact_impulses().sum();
            (solver.object_velocity().to_vec(), solver.proxies[0].v, impulse)
        }
        let (one, padded) = (run::<1>(), run::<MAX_OBJECT_DOFS>());
        assert_eq!(one, padded);
        assert!(one.2.norm() > 0.0, "the contact carries an impulse: {:?}", one.2);
    }

    #[test]
    fn a_gap_closes_no_faster_than_it_can_within_the_step() {
        // 3 mm apart at 1 m/s closing: the row lets the proxy close 3 mm in 15 ms (0.2 m/s), not more.
        let p = params(10);
        let mut solver = Solver::<1>::default();
        solver.begin(&[0.0], &[1.0]);
        solver.proxies.push(ball(1.0, Vector3::new(0.0, 0.0, -1.0)));
        solver.add_contact(&p, 0, &Point3::origin(), &Vector3::z(), 0.003, &[0.0; 3], 0.0, None);
        solver.relax(&p);
        assert_relative_eq!(solver.proxies[0].v.z, -0.003 / 0.015, epsilon = 1e-12);
    }

    #[test]
    fn dry_friction_holds_a_coordinate_until_the_push_exceeds_it() {
        let p = params(10);
        for (push, held) in [(0.5, true), (2.0, false)] {
            let mut solver = Solver::<1>::default();
            // Inverse mass 1: a velocity of `push` is an impulse of `push` to cancel.
            solver.begin(&[push], &[1.0]);
            solver.add_dry_friction(0, 1.0);
            solver.solve(&p);
            if held {
                assert_eq!(solver.object_velocity()[0], 0.0);
            } else {
                assert_relative_eq!(solver.object_velocity()[0], push - 1.0, epsilon = 1e-12);
            }
        }
    }

    #[test]
    fn a_limit_stops_the_coordinate_at_the_limit_and_pushes_back_from_beyond() {
        let p = params(5);
        let mut solver = Solver::<1>::default();
        // 1 mm inside the lower limit moving toward it at 1 m/s: it may move 1 mm, no more.
        solver.begin(&[-1.0], &[0.5]);
        solver.add_limit(&p, 0, true, 0.001);
        solver.solve(&p);
        assert_relative_eq!(solver.object_velocity()[0], -0.001 / 0.015, epsilon = 1e-12);
        // 2 mm beyond it at rest: pushed back at the limit's stiffness, then left at rest.
        solver.begin(&[0.0], &[0.5]);
        solver.add_limit(&p, 0, true, -0.002);
        solver.solve(&p);
        assert_relative_eq!(solver.object_velocity()[0], 0.002 * p.limit_erp_inv_dt, epsilon = 1e-12);
        solver.relax(&p);
        assert_relative_eq!(solver.object_velocity()[0], 0.0, epsilon = 1e-12);
    }
}
