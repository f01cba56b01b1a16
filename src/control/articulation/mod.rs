//! The articulation of an object that has no model, estimated from the hand's path while it pulls the
//! handle: door or drawer, the hinge's axis and position or the slide's direction, each with its
//! uncertainty, and the opening along the estimate.
//!
//! The method is Sturm, Stachniss and Burgard's (JAIR 2011) for the two joint types a handle is on:
//! fit a rotational and a prismatic model to the observed path by least squares and choose between
//! them by the Bayesian information criterion, here with the prior the handle gives (a door's hinge
//! runs along its handle's bar; both open along the handle's outward normal first). The path is the
//! hand's position while hooked, at the state rate; samples are averaged in bins a few millimetres of
//! path apart, each weighted by 1/(σ²/n + σ_floor²) (σ the noise of one sample, n its samples, the
//! floor the hook's play in the handle, which no averaging removes). The geometry is refitted when a
//! bin closes (the path has moved on); the opening and its rate follow every sample.

pub mod fit;
#[cfg(test)]
mod tests;

use nalgebra::{Isometry3, Point3, Unit, Vector3};

pub use fit::{CircleFit, CirclePrior, LineFit, WeightedPoint};

use crate::error::{ensure_finite, Result, SabreError};
use crate::low_pass::LowPass;

/// Cutoff (Hz) of the low-pass on the hand's position that decides where bins end: at a 1 kHz state
/// rate it leaves a few tenths of a millimetre of a 2 mm noise, and lags a hand at 0.2 m/s by 3 mm.
const BIN_CUTOFF: f64 = 10.0;

/// The joint an estimate describes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArticulationKind {
    /// A door: the handle turns about a hinge.
    Revolute,
    /// A drawer: the handle slides along a line.
    Prismatic,
}

/// How the estimator weighs the path and decides.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArticulationConfig {
    /// σ (m, positive) of one measured hand position.
    pub position_noise: f64,
    /// σ (m, ≥ 0) no averaging goes below: the hook's play in the handle, the arm's compliance.
    pub noise_floor: f64,
    /// Path length (m, positive) a bin spans before the next begins.
    pub bin_length: f64,
    /// Most bins kept (≥ 8); beyond, neighbours merge.
    pub max_bins: usize,
    /// σ (rad, positive) of the hinge's tilt away from the handle's bar before the data.
    pub axis_std: f64,
    /// Hinges are vertical or horizontal and slides level, as furniture and appliances have them (a
    /// slide within [`ArticulationConfig::aligned_within`] of the horizontal is put on it); a bar within
    /// [`ArticulationConfig::aligned_within`] of the vertical puts the hinge's prior on the vertical,
    /// one within it of the horizontal puts it in the horizontal plane, each with σ
    /// [`ArticulationConfig::aligned_std`] for the tilt gravity fixes. Off: the bar's direction alone.
    pub gravity_aligned: bool,
    /// The angle (rad, 0–π/4) within which a bar counts as vertical or horizontal.
    pub aligned_within: f64,
    /// σ (rad, positive) of a gravity-aligned hinge's tilt away from the vertical or the horizontal.
    pub aligned_std: f64,
    /// The hinge-to-handle radii (m) a door may have: 0 < lower < upper.
    pub radius: (f64, f64),
    /// Path length (m, positive) before the path is weighed at all.
    pub min_path: f64,
    /// Posterior probability (0.5–1) at which a joint type is decided; a decided type gives way when the
    /// other's reaches 1 − (1 − decide)/50.
    pub decide: f64,
    /// Cutoff (Hz, positive) of the low-passes on the opening and its rate.
    pub rate_cutoff: f64,
    /// A hook let go for longer than this (s, ≥ 0) may go in again elsewhere along the bar: the path
    /// after it is a new stretch, free to sit beside the last along the bar. Shorter gaps (the force
    /// dipping while the hook stays seated) continue the stretch.
    pub rehook_time: f64,
}

impl Default for ArticulationConfig {
    fn default() -> Self {
        Self {
            position_noise: 0.002,
            noise_floor: 0.0002,
            bin_length: 0.005,
            max_bins: 256,
            axis_std: 0.1,
            gravity_aligned: true,
            aligned_within: 0.35,
            aligned_std: 0.01,
            radius: (0.2, 1.2),
            min_path: 0.03,
            decide: 0.95,
            rate_cutoff: 5.0,
            rehook_time: 0.3,
        }
    }
}

impl ArticulationConfig {
    /// The config, checked.
    pub fn checked(self) -> Result<Self> {
        let positive = |what: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(SabreError::invalid(what, format!("must be positive and finite, got {v}")))
            }
        };
        positive("position_noise", self.position_noise)?;
        if !(self.noise_floor.is_finite() && self.noise_floor >= 0.0) {
            return Err(SabreError::invalid(
                "noise_floor",
                format!("must be finite and ≥ 0, got {}", self.noise_floor),
            ));
        }
        positive("bin_length", self.bin_length)?;
        positive("axis_std", self.axis_std)?;
        positive("aligned_std", self.aligned_std)?;
        if !(self.aligned_within >= 0.0 && self.aligned_within <= std::f64::consts::FRAC_PI_4) {
            return Err(SabreError::invalid(
                "aligned_within",
                format!("must be in [0, π/4], got {}", self.aligned_within),
            ));
        }
        positive("min_path", self.min_path)?;
        positive("rate_cutoff", self.rate_cutoff)?;
        if !(self.rehook_time.is_finite() && self.rehook_time >= 0.0) {
            return Err(SabreError::invalid(
                "rehook_time",
                format!("must be finite and ≥ 0, got {}", self.rehook_time),
            ));
        }
        if self.max_bins < 8 {
            return Err(SabreError::invalid(
                "max_bins",
                format!("must be at least 8, got {}", self.max_bins),
            ));
        }
        let (lo, hi) = self.radius;
        if !(lo.is_finite() && hi.is_finite() && 0.0 < lo && lo < hi) {
            return Err(SabreError::invalid(
                "radius",
                format!("must be a range 0 < lower < upper, got ({lo}, {hi})"),
            ));
        }
        if !(self.decide >= 0.5 && self.decide < 1.0) {
            return Err(SabreError::invalid(
                "decide",
                format!("must be in [0.5, 1), got {}", self.decide),
            ));
        }
        Ok(self)
    }
}

/// The current estimate. Until a type is decided the geometry is the prismatic one (the handle's
/// outward normal, then the path's line): the direction a first pull takes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArticulationEstimate {
    /// The decided type, None while the evidence is short of [`ArticulationConfig::decide`].
    pub kind: Option<ArticulationKind>,
    /// Posterior probability of a door.
    pub p_revolute: f64,
    /// Revolute: the hinge axis, the opening right-handed about it. Prismatic: the slide's direction,
    /// the opening along it.
    pub axis: Unit<Vector3<f64>>,
    /// Revolute: the hinge's point in the plane of the hand's path. Prismatic: where the path began.
    pub point: Point3<f64>,
    /// Revolute: the handle's distance from the hinge (m); NaN otherwise.
    pub radius: f64,
    /// Standard deviations: the axis's angle (rad), the point across the axis (m), the radius (m).
    pub axis_std: f64,
    pub point_std: f64,
    pub radius_std: f64,
    /// The opening (rad or m by the geometry's type) and its rate, low-passed.
    pub opening: f64,
    pub rate: f64,
    /// Hooked path length (m, between bins, each stretch on its own) and samples seen.
    pub path_length: f64,
    pub samples: usize,
    pub hooked: bool,
}

impl ArticulationEstimate {
    /// The type the geometry describes: the decided one, else prismatic.
    pub fn geometry_kind(&self) -> ArticulationKind {
        self.kind.unwrap_or(ArticulationKind::Prismatic)
    }
}

#[derive(Debug, Clone, Copy)]
struct Bin {
    sum: Vector3<f64>,
    count: usize,
    segment: usize,
}

impl Bin {
    fn new(p: Point3<f64>, segment: usize) -> Self {
        Self {
            sum: p.coords,
            count: 1,
            segment,
        }
    }

    fn mean(&self) -> Point3<f64> {
        Point3::from(self.sum / self.count as f64)
    }
}

/// The estimator: `update` once per measured hand position.
#[derive(Debug, Clone)]
pub struct ArticulationEstimator {
    config: ArticulationConfig,
    handle: Isometry3<f64>,
    prior: f64,
    bins: Vec<Bin>,
    open: Option<Bin>,
    segment: usize,
    path_length: f64,
    line: Option<LineFit>,
    circle: Option<CircleFit>,
    estimate: ArticulationEstimate,
    last_time: Option<f64>,
    opening_filter: LowPass,
    rate_filter: LowPass,
    last_opening: Option<f64>,
    /// When the hook was last seen hooked.
    hooked_at: Option<f64>,
    /// The hand low-passed at [`BIN_CUTOFF`]: bins close on its travel, not on one sample's noise.
    smooth_hand: LowPass,
    /// The low-passed hand where the open bin began.
    bin_start: Option<Point3<f64>>,
    /// Where the hand holds the handle with the object closed (world): the opening's zero.
    reference: Point3<f64>,
}

impl ArticulationEstimator {
    /// An estimator for the handle at `handle` (world pose of its frame: origin at the bar's centre, x
    /// along the bar, z into the panel), a door with prior probability `p_revolute` (0–1: 0.5 says
    /// nothing, a door announced as a drawer is still found).
    pub fn new(handle: Isometry3<f64>, p_revolute: f64, config: ArticulationConfig) -> Result<Self> {
        let config = config.checked()?;
        if !(0.0..=1.0).contains(&p_revolute) {
            return Err(SabreError::invalid(
                "p_revolute",
                format!("must be a probability in [0, 1], got {p_revolute}"),
            ));
        }
        ensure_finite("handle", handle.translation.vector.as_slice())?;
        let outward = -(handle.rotation * Vector3::z_axis());
        let estimate = ArticulationEstimate {
            kind: None,
            p_revolute,
            axis: outward,
            point: Point3::from(handle.translation.vector),
            radius: f64::NAN,
            axis_std: f64::INFINITY,
            point_std: f64::INFINITY,
            radius_std: f64::INFINITY,
            opening: 0.0,
            rate: 0.0,
            path_length: 0.0,
            samples: 0,
            hooked: false,
        };
        Ok(Self {
            config,
            handle,
            prior: p_revolute,
            bins: Vec::new(),
            open: None,
            segment: 0,
            path_length: 0.0,
            line: None,
            circle: None,
            estimate,
            last_time: None,
            opening_filter: LowPass::new(1, Some(config.rate_cutoff)),
            rate_filter: LowPass::new(1, Some(config.rate_cutoff)),
            last_opening: None,
            hooked_at: None,
            smooth_hand: LowPass::new(3, Some(BIN_CUTOFF)),
            bin_start: None,
            reference: Point3::from(handle.translation.vector),
        })
    }

    pub fn config(&self) -> &ArticulationConfig {
        &self.config
    }

    pub fn handle(&self) -> &Isometry3<f64> {
        &self.handle
    }

    pub fn estimate(&self) -> &ArticulationEstimate {
        &self.estimate
    }

    /// The last fits (None before the path is long enough).
    pub fn line(&self) -> Option<&LineFit> {
        self.line.as_ref()
    }

    pub fn circle(&self) -> Option<&CircleFit> {
        self.circle.as_ref()
    }

    /// The bins' means and weights, as the fits see them.
    pub fn points(&self) -> Vec<WeightedPoint> {
        let (s2, f2) = (self.config.position_noise.powi(2), self.config.noise_floor.powi(2));
        self.bins
            .iter()
            .map(|b| WeightedPoint {
                p: b.mean(),
                w: 1.0 / (s2 / b.count as f64 + f2),
                segment: b.segment,
            })
            .collect()
    }

    /// Forgets the path and the estimate (the reference stays).
    pub fn reset(&mut self) {
        let reference = self.reference;
        *self = Self::new(self.handle, self.prior, self.config).expect("checked on construction");
        self.reference = reference;
    }

    /// Sets where the hand holds the handle with the object closed (world, m): the opening's zero
    /// (default: the handle frame's origin). A task whose hook holds the bar elsewhere than at the
    /// frame's origin gives its hook point, so that an object that moved before the hook went in reads
    /// as open by as much.
    pub fn set_reference(&mut self, reference: Point3<f64>) -> Result<()> {
        ensure_finite("reference", reference.coords.as_slice())?;
        self.reference = reference;
        Ok(())
    }

    pub fn reference(&self) -> Point3<f64> {
        self.reference
    }

    /// Takes the hand's position `hand` (world, m) at time `t` (s): `hooked`, the hand holds the handle
    /// and the opening follows it (else it holds at rest); `record`, the hook pulls, seated, and the
    /// path is the handle's (a hook still seating itself moves across the bar: its path is not the
    /// object's). A time at or before the previous one counts as no time passed.
    pub fn update(&mut self, t: f64, hand: Point3<f64>, hooked: bool, record: bool) -> Result<&ArticulationEstimate> {
        ensure_finite("hand", hand.coords.as_slice())?;
        ensure_finite("t", &[t])?;
        let dt = self.last_time.map_or(0.0, |last| (t - last).max(0.0));
        self.last_time = Some(t.max(self.last_time.unwrap_or(t)));
        self.estimate.samples += 1;
        let record = hooked && record;
        if record {
            if self.hooked_at.is_some_and(|at| t - at > self.config.rehook_time) {
                // a gap the hook may have moved in along the bar: a new stretch, its own bins
                self.bins.extend(self.open.take());
                self.smooth_hand.reset();
                if !self.bins.is_empty() {
                    self.segment += 1;
                }
            }
            self.hooked_at = Some(t);
        }
        if hooked && !self.estimate.hooked {
            // a hook taken (again): the opening starts from where the hand holds the handle now
            self.opening_filter.reset();
            self.rate_filter.reset();
        }
        self.estimate.hooked = hooked;
        if !hooked {
            self.last_opening = None;
            self.estimate.rate = 0.0;
            self.rate_filter.reset();
            return Ok(&self.estimate);
        }
        if !record {
            self.follow(hand, dt);
            return Ok(&self.estimate);
        }
        let smooth = Point3::from_slice(self.smooth_hand.update(hand.coords.as_slice(), dt));
        let closed = match (&mut self.open, self.bin_start) {
            (Some(bin), Some(start)) if (smooth - start).norm() <= self.config.bin_length => {
                bin.sum += hand.coords;
                bin.count += 1;
                false
            }
            (Some(_), _) => true,
            (None, _) => {
                self.open = Some(Bin::new(hand, self.segment));
                self.bin_start = Some(smooth);
                false
            }
        };
        if closed {
            self.bin_start = Some(smooth);
            if let (Some(done), Some(last)) = (self.open, self.bins.last()) {
                if done.segment == last.segment {
                    self.path_length += (done.mean() - last.mean()).norm();
                }
            }
            self.bins.extend(self.open.take());
            self.open = Some(Bin::new(hand, self.segment));
            self.merge_if_full();
            self.refit();
        }
        self.follow(hand, dt);
        Ok(&self.estimate)
    }

    /// Halves the bins by merging neighbours on the same stretch once they fill the budget.
    fn merge_if_full(&mut self) {
        if self.bins.len() < self.config.max_bins {
            return;
        }
        let mut merged: Vec<Bin> = Vec::with_capacity(self.bins.len() / 2 + 1);
        let mut i = 0;
        while i < self.bins.len() {
            let mut b = self.bins[i];
            if let Some(next) = self.bins.get(i + 1).filter(|n| n.segment == b.segment) {
                b.sum += next.sum;
                b.count += next.count;
                i += 1;
            }
            merged.push(b);
            i += 1;
        }
        self.bins = merged;
    }

    fn path_extent(&self) -> f64 {
        self.bins
            .first()
            .zip(self.bins.last())
            .map_or(0.0, |(a, b)| (b.mean() - a.mean()).norm())
    }

    /// The hinge before the data: along the handle's bar, or on the vertical or in the horizontal plane
    /// when the bar is near them and hinges are taken as gravity-aligned.
    pub fn circle_prior(&self) -> CirclePrior {
        let c = &self.config;
        let bar = Unit::new_normalize(self.handle.rotation * Vector3::x());
        let up = Vector3::z();
        let elevation = bar.dot(&up).abs().clamp(0.0, 1.0).asin(); // the bar's angle from the horizontal
        if !c.gravity_aligned || (elevation > c.aligned_within && elevation < std::f64::consts::FRAC_PI_2 - c.aligned_within) {
            return CirclePrior::isotropic(bar, c.axis_std, c.radius);
        }
        if elevation >= std::f64::consts::FRAC_PI_2 - c.aligned_within {
            return CirclePrior::isotropic(Vector3::z_axis(), c.aligned_std, c.radius);
        }
        // horizontal: gravity fixes the tilt toward the vertical, the bar's direction the rest
        let axis = Unit::new_normalize(bar.into_inner() - bar.dot(&up) * up);
        let level = axis.cross(&up).normalize();
        CirclePrior {
            axis,
            tilts: [(up, c.aligned_std), (level, c.axis_std)],
            radius: c.radius,
        }
    }

    /// The bins as the fits take them: each stretch after the first moved along the bar so that its
    /// centroid is level with the first's (a hook that went in again elsewhere along the bar); the bar
    /// runs along a door's hinge and across a drawer's slide, so neither's own motion is moved.
    pub fn aligned_points(&self) -> Vec<WeightedPoint> {
        let mut points = self.points();
        let bar = self.handle.rotation * Vector3::x();
        let mut sums: Vec<(f64, f64)> = vec![(0.0, 0.0); self.segment + 1];
        for q in &points {
            sums[q.segment].0 += q.w;
            sums[q.segment].1 += q.w * q.p.coords.dot(&bar);
        }
        let level = |s: usize| (sums[s].0 > 0.0).then(|| sums[s].1 / sums[s].0);
        let first = points.first().and_then(|q| level(q.segment));
        for q in &mut points {
            if let (Some(first), Some(own)) = (first, level(q.segment)) {
                q.p -= (own - first) * bar;
            }
            q.segment = 0;
        }
        points
    }

    /// Fits both types to the bins and weighs them.
    fn refit(&mut self) {
        let points = self.aligned_points();
        self.estimate.path_length = self.path_length;
        if points.len() < 3 || self.path_extent() < self.config.min_path {
            return;
        }
        let prior = self.circle_prior();
        self.line = fit::fit_line(&points);
        self.circle = fit::fit_circle(&points, &prior);
        let (Some(line), Some(circle)) = (self.line, self.circle) else {
            return;
        };
        // The evidence for a door over a drawer: the likelihood ratio of the best circle and the best
        // line (χ² scaled by the better model's reduced χ² where the path is noisier than the weights
        // say: the hook's play, a compliant arm), times the Occam factor of the one parameter a line
        // lacks, the curvature, uniform over the doors' range before the data. A short path cannot
        // tell the two apart, and the ratio stays at the prior.
        let n = (2 * points.len()) as f64;
        let dof = (n - circle.parameters.max(line.parameters) as f64).max(1.0);
        let scale = (line.chi2.min(circle.chi2) / dof).max(1.0);
        let (r_lo, r_hi) = self.config.radius;
        let span = 1.0 / r_lo - 1.0 / r_hi;
        let occam = ((2.0 * std::f64::consts::PI).sqrt() * circle.curvature_std * scale.sqrt() / span)
            .min(1.0)
            .ln();
        let mut log_ratio = -0.5 * (circle.chi2 - line.chi2) / scale + occam;
        if circle.at_bound && circle.radius >= r_hi * (1.0 - 1e-9) {
            // the best arc is the straightest a door may have: the path asks for straighter still,
            // and what the arc fits better than the line (a kink) is no hinge's
            log_ratio = log_ratio.min(0.0);
        }
        let prior = self.prior.clamp(1e-6, 1.0 - 1e-6);
        let logit = (prior / (1.0 - prior)).ln() + log_ratio;
        let p = 1.0 / (1.0 + (-logit.clamp(-700.0, 700.0)).exp());
        self.estimate.p_revolute = p;
        // a decided type gives way only to the other's near certainty: a path spoilt at its end (a
        // hook slipping off) does not turn a drawer into a door
        let (to_door, to_drawer) = match self.estimate.kind {
            Some(ArticulationKind::Prismatic) => (1.0 - (1.0 - self.config.decide) / 50.0, self.config.decide),
            Some(ArticulationKind::Revolute) => (self.config.decide, 1.0 - (1.0 - self.config.decide) / 50.0),
            None => (self.config.decide, self.config.decide),
        };
        let decided = if p >= to_door {
            Some(ArticulationKind::Revolute)
        } else if 1.0 - p >= to_drawer {
            Some(ArticulationKind::Prismatic)
        } else {
            self.estimate.kind
        };
        let before = self.estimate.geometry_kind();
        self.estimate.kind = decided;
        if self.estimate.geometry_kind() != before {
            // the opening changes its unit (m to rad or back): its filters start over
            self.opening_filter.reset();
            self.rate_filter.reset();
            self.last_opening = None;
        }
        self.set_geometry(&points, &line, &circle);
    }

    fn set_geometry(&mut self, points: &[WeightedPoint], line: &LineFit, circle: &CircleFit) {
        let (first, last) = (points[0].p, points[points.len() - 1].p);
        let travel = last - first;
        let e = &mut self.estimate;
        match e.geometry_kind() {
            ArticulationKind::Prismatic => {
                let mut d = line.direction.into_inner();
                // drawers slide level: a direction near the horizontal is put on it
                let up = Vector3::z();
                if self.config.gravity_aligned && d.dot(&up).abs().clamp(0.0, 1.0).asin() <= self.config.aligned_within {
                    d -= d.dot(&up) * up;
                }
                e.axis = Unit::new_normalize(if d.dot(&travel) < 0.0 { -d } else { d });
                e.point = first;
                e.radius = f64::NAN;
                e.axis_std = line.direction_std;
                e.point_std = 0.0;
                e.radius_std = f64::NAN;
            }
            ArticulationKind::Revolute => {
                let a = circle.axis.into_inner();
                let rho = first - circle.center;
                let a = if rho.cross(&travel).dot(&a) < 0.0 { -a } else { a };
                e.axis = Unit::new_normalize(a);
                e.point = circle.center;
                e.radius = circle.radius;
                e.axis_std = circle.axis_std;
                e.point_std = circle.center_std;
                e.radius_std = circle.radius_std;
            }
        }
    }

    /// The opening the hand at `hand` puts along the current geometry from the reference (≥ 0: the
    /// object's closed stop).
    pub fn opening_at(&self, hand: Point3<f64>) -> f64 {
        let e = &self.estimate;
        let first = self.reference;
        let a = e.axis.into_inner();
        let o = match e.geometry_kind() {
            ArticulationKind::Prismatic => (hand - first).dot(&a),
            ArticulationKind::Revolute => {
                let across = |p: Point3<f64>| {
                    let d = p - e.point;
                    d - d.dot(&a) * a
                };
                let (r0, r) = (across(first), across(hand));
                r0.cross(&r).dot(&a).atan2(r0.dot(&r))
            }
        };
        o.max(0.0)
    }

    fn follow(&mut self, hand: Point3<f64>, dt: f64) {
        let raw = self.opening_at(hand);
        let opening = self.opening_filter.update(&[raw], dt)[0];
        let rate = match self.last_opening {
            Some(prev) if dt > 0.0 => self.rate_filter.update(&[(opening - prev) / dt], dt)[0],
            _ => self.estimate.rate,
        };
        self.last_opening = Some(opening);
        self.estimate.opening = opening;
        self.estimate.rate = rate;
    }
}
