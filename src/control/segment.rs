//! The arm's trajectory segments for a joint_trajectory_controller: from the desired state at the
//! splice, the target velocities followed on a grid of knots, then a stop to rest, all as pieces of
//! constant jerk (acceleration continuous, linear within a piece), which JTC's cubic interpolation
//! between positions and velocities reproduces exactly, whenever the robot samples it.
//!
//! Per joint and knot interval Δ the acceleration at the next knot is the velocity error over a time
//! constant T, within ±a_max and within j_max·Δ of the last one (the jerk bound):
//! a⁺ = clamp(clamp((v* − v)/T, ±a_max), a ± j_max·Δ); then v⁺ = v + (a + a⁺)Δ/2 and
//! q⁺ = q + vΔ + (2a + a⁺)Δ²/6, the exact integrals of the linear acceleration. With T ≥ 5Δ the
//! discrete loop's poles are real (0.77 and 0.13 at T = 5Δ): the velocity approaches its target
//! without overshoot. Knots across which no joint's jerk changes are dropped (one cubic spans them).

use crate::error::{Result, SabreError};

/// The limits and grid of [`Segment::build`].
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentShape {
    /// Per joint: velocity (rad/s), acceleration (rad/s²) and jerk (rad/s³) bounds.
    pub velocity: Vec<f64>,
    pub acceleration: Vec<f64>,
    pub jerk: Vec<f64>,
    /// The knot interval Δ (s).
    pub knot: f64,
    /// The velocity's time constant T (s), at least 5Δ.
    pub time_constant: f64,
}

impl SegmentShape {
    pub fn new(velocity: Vec<f64>, acceleration: Vec<f64>, jerk: Vec<f64>, knot: f64, time_constant: f64) -> Result<Self> {
        let n = velocity.len();
        for (name, v) in [("velocity", &velocity), ("acceleration", &acceleration), ("jerk", &jerk)] {
            if v.len() != n || n == 0 || !v.iter().all(|x| x.is_finite() && *x > 0.0) {
                return Err(SabreError::invalid(
                    name,
                    format!("need {n} positive finite limits, got {v:?}"),
                ));
            }
        }
        if !(knot.is_finite() && knot > 0.0) {
            return Err(SabreError::invalid("knot", format!("must be positive, got {knot}")));
        }
        if !(time_constant.is_finite() && time_constant >= 5.0 * knot * (1.0 - 1e-9)) {
            return Err(SabreError::invalid(
                "time_constant",
                format!(
                    "must be at least five knots ({} s) for a velocity that never overshoots, got {time_constant}",
                    5.0 * knot
                ),
            ));
        }
        Ok(Self {
            velocity,
            acceleration,
            jerk,
            knot,
            time_constant,
        })
    }

    pub fn joints(&self) -> usize {
        self.velocity.len()
    }
}

/// A state on the grid: positions, velocities, accelerations (one each per joint).
#[derive(Debug, Clone, PartialEq)]
pub struct KnotState {
    pub q: Vec<f64>,
    pub v: Vec<f64>,
    pub a: Vec<f64>,
}

impl KnotState {
    /// At rest at `q`.
    pub fn rest(q: &[f64]) -> Self {
        Self {
            q: q.to_vec(),
            v: vec![0.0; q.len()],
            a: vec![0.0; q.len()],
        }
    }
}

/// A segment: its knots' times from the splice (s) and states, the first the splice's state.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Segment {
    pub times: Vec<f64>,
    pub states: Vec<KnotState>,
}

/// A stop is complete once every joint is this slow (rad/s) and this little accelerated (rad/s²).
const REST_VELOCITY: f64 = 1e-6;
const REST_ACCELERATION: f64 = 1e-4;
/// The longest stop (s) a segment holds; a stop that takes longer is an error (limits far too low).
const LONGEST_STOP: f64 = 60.0;

/// A segment built knot by knot: from a start, each [`Self::push`] follows a target velocity over one
/// knot interval (see the module); [`Self::finish`] adds the stop to rest and drops the knots one
/// cubic spans. The caller can read the state reached between pushes ([`Self::state`]), as the
/// sequential filter does to filter the next target at the state the segment will be in.
#[derive(Debug, Clone)]
pub struct SegmentBuilder<'a> {
    shape: &'a SegmentShape,
    states: Vec<KnotState>,
}

impl<'a> SegmentBuilder<'a> {
    /// A segment of `shape` from `start`. Errors: a start of the wrong size or not finite.
    pub fn new(shape: &'a SegmentShape, start: &KnotState) -> Result<Self> {
        let n = shape.joints();
        for (name, v) in [("q", &start.q), ("v", &start.v), ("a", &start.a)] {
            if v.len() != n || !v.iter().all(|x| x.is_finite()) {
                return Err(SabreError::invalid(name, format!("need {n} finite values, got {v:?}")));
            }
        }
        Ok(Self {
            shape,
            states: vec![start.clone()],
        })
    }

    /// The state reached so far.
    pub fn state(&self) -> &KnotState {
        self.states.last().expect("the start")
    }

    /// Knots so far, the start included.
    pub fn len(&self) -> usize {
        self.states.len()
    }

    /// Always false: a builder holds its start.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// One knot interval following `target` (one velocity per joint). Errors: a target of the wrong
    /// size or not finite; nothing changes then.
    pub fn push(&mut self, target: &[f64]) -> Result<()> {
        let n = self.shape.joints();
        if target.len() != n || !target.iter().all(|x| x.is_finite()) {
            return Err(SabreError::invalid(
                "targets",
                format!("need {n} finite velocities each, got {target:?}"),
            ));
        }
        let next = Segment::step(self.shape, self.state(), target);
        self.states.push(next);
        Ok(())
    }

    /// The segment: the knots pushed, then a stop to rest (see the module). Errors: a stop longer
    /// than a minute (limits far too low).
    pub fn finish(mut self) -> Result<Segment> {
        let zero = vec![0.0; self.shape.joints()];
        let stop_knots = (LONGEST_STOP / self.shape.knot).ceil() as usize;
        for _ in 0..=stop_knots {
            let state = self.state();
            if state.v.iter().all(|v| v.abs() < REST_VELOCITY) && state.a.iter().all(|a| a.abs() < REST_ACCELERATION) {
                let last = self.states.last_mut().expect("the start");
                last.v.iter_mut().chain(last.a.iter_mut()).for_each(|x| *x = 0.0);
                return Ok(Segment::compressed(self.shape.knot, self.states));
            }
            let next = Segment::step(self.shape, state, &zero);
            self.states.push(next);
        }
        Err(SabreError::invalid(
            "limits",
            format!("the stop takes longer than {LONGEST_STOP} s"),
        ))
    }
}

impl Segment {
    /// The segment from `start` that follows `targets[k]` (velocities, one per joint) over knot
    /// interval k, then stops at rest (see the module).
    pub fn build(shape: &SegmentShape, start: &KnotState, targets: &[Vec<f64>]) -> Result<Self> {
        let mut builder = SegmentBuilder::new(shape, start)?;
        for target in targets {
            builder.push(target)?;
        }
        builder.finish()
    }

    /// The segment that follows `old` (in force from its own time 0) from its time `from` to `splice`
    /// and then `new`, which must start at `old`'s state at `splice`: times from `from`. Sampled, it
    /// is `old` itself up to `splice` (a cubic's piece is that cubic), so a robot that takes it over
    /// anywhere in [from, splice] sees no change. Errors: `splice` before `from`, or `new` not
    /// starting where `old` is at `splice`.
    pub fn spliced(old: &Segment, from: f64, splice: f64, new: &Segment) -> Result<Self> {
        if !(from.is_finite() && splice.is_finite() && splice >= from) {
            return Err(SabreError::invalid(
                "splice",
                format!("must be finite and not before {from}, got {splice}"),
            ));
        }
        let at = old.sample(splice);
        let first = new
            .states
            .first()
            .ok_or_else(|| SabreError::invalid("segment", "has no knots"))?;
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-9 * (1.0 + x.abs()));
        if !(close(&at.q, &first.q) && close(&at.v, &first.v) && close(&at.a, &first.a)) {
            return Err(SabreError::invalid(
                "segment",
                "does not start where the segment in force is at the splice",
            ));
        }
        let mut times = vec![0.0];
        let mut states = vec![old.sample(from)];
        // a knot closer than this to the ends is left out: a message carries times in whole
        // nanoseconds, which must increase
        let apart = 1e-6;
        for (&t, s) in old.times.iter().zip(&old.states) {
            if t > from + apart && t < splice - apart {
                times.push(t - from);
                states.push(s.clone());
            }
        }
        let offset = splice - from;
        let skip = usize::from(offset <= 0.0);
        for (k, (&t, s)) in new.times.iter().zip(&new.states).enumerate().skip(skip) {
            // the splice's own state: the segment in force's there, exactly
            states.push(if k == 0 { at.clone() } else { s.clone() });
            times.push(t + offset);
        }
        Ok(Self { times, states })
    }

    /// The time (s from its start) at which the segment is at rest for good: its last knot's.
    pub fn end(&self) -> f64 {
        self.times.last().copied().unwrap_or(0.0)
    }

    fn step(shape: &SegmentShape, s: &KnotState, target: &[f64]) -> KnotState {
        let dt = shape.knot;
        let mut next = s.clone();
        for (j, &goal) in target.iter().enumerate() {
            let (v_max, a_max, step) = (shape.velocity[j], shape.acceleration[j], shape.jerk[j] * dt);
            let wanted = ((goal.clamp(-v_max, v_max) - s.v[j]) / shape.time_constant).clamp(-a_max, a_max);
            let a = wanted.clamp(s.a[j] - step, s.a[j] + step);
            next.q[j] = s.q[j] + s.v[j] * dt + (2.0 * s.a[j] + a) * dt * dt / 6.0;
            next.v[j] = s.v[j] + (s.a[j] + a) * dt / 2.0;
            next.a[j] = a;
        }
        next
    }

    /// The knots at `knot` spacing, without those across which no joint's jerk changes.
    fn compressed(knot: f64, states: Vec<KnotState>) -> Self {
        let jerk = |k: usize, j: usize| (states[k + 1].a[j] - states[k].a[j]) / knot;
        let last = states.len() - 1;
        let mut times = Vec::new();
        let mut kept = Vec::new();
        for (k, s) in states.iter().enumerate() {
            let interior = k > 0 && k < last;
            let same = interior && (0..s.q.len()).all(|j| (jerk(k - 1, j) - jerk(k, j)).abs() <= 1e-9 * (1.0 + jerk(k, j).abs()));
            if !same {
                times.push(k as f64 * knot);
                kept.push(s.clone());
            }
        }
        Self { times, states: kept }
    }

    /// The state at `t` (s from the splice) as a cubic between the knots' positions and
    /// velocities (JTC's interpolation), at rest at the last knot after it.
    pub fn sample(&self, t: f64) -> KnotState {
        let last = self.times.len() - 1;
        if t >= self.times[last] {
            return KnotState::rest(&self.states[last].q);
        }
        let i = self.times.partition_point(|&ti| ti <= t).max(1);
        let (t0, t1) = (self.times[i - 1], self.times[i]);
        let (p0, p1) = (&self.states[i - 1], &self.states[i]);
        let (s, h) = (t - t0, t1 - t0);
        let mut out = p0.clone();
        for j in 0..p0.q.len() {
            let d = p1.q[j] - p0.q[j];
            let c2 = (3.0 * d - (2.0 * p0.v[j] + p1.v[j]) * h) / (h * h);
            let c3 = (-2.0 * d + (p0.v[j] + p1.v[j]) * h) / (h * h * h);
            out.q[j] = p0.q[j] + p0.v[j] * s + c2 * s * s + c3 * s * s * s;
            out.v[j] = p0.v[j] + 2.0 * c2 * s + 3.0 * c3 * s * s;
            out.a[j] = 2.0 * c2 + 6.0 * c3 * s;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape() -> SegmentShape {
        // jerk bounds that bind: a full swing of the acceleration takes several knots
        SegmentShape::new(vec![2.0, 1.0], vec![3.0, 1.5], vec![500.0, 300.0], 0.002, 0.01).unwrap()
    }

    #[test]
    fn a_segment_follows_its_targets_without_overshoot_and_ends_at_rest_within_the_limits() {
        let s = shape();
        let start = KnotState {
            q: vec![0.1, -0.2],
            v: vec![0.5, -0.3],
            a: vec![1.0, 0.0],
        };
        let targets: Vec<Vec<f64>> = (0..700)
            .map(|k| if k < 400 { vec![1.5, -2.0] } else { vec![-0.5, 0.4] })
            .collect();
        let seg = Segment::build(&s, &start, &targets).unwrap();
        assert_eq!(seg.states[0], start);
        let end = seg.states.last().unwrap();
        assert!(end.v == vec![0.0; 2] && end.a == vec![0.0; 2]);
        // sampled as JTC samples it, at 1 kHz from a phase off the knots
        let mut previous: Option<KnotState> = None;
        let mut t = 0.0003;
        while t < seg.times.last().unwrap() + 0.01 {
            let x = seg.sample(t);
            for j in 0..2 {
                assert!(x.v[j].abs() <= s.velocity[j] + 1e-9, "t {t} joint {j}: {x:?}");
                assert!(x.a[j].abs() <= s.acceleration[j] + 1e-9, "t {t} joint {j}: {x:?}");
                if let Some(p) = &previous {
                    // the acceleration is continuous: its change over 1 ms is at most the jerk bound's
                    assert!((x.a[j] - p.a[j]).abs() <= s.jerk[j] * 0.001 + 1e-9, "t {t}: {p:?} → {x:?}");
                    // and the velocity is the acceleration's integral (the trapezoid misses a kink in
                    // the acceleration at a knot by at most a jerk change times dt²/8)
                    let kink = 2.0 * s.jerk[j] * 1e-6 / 8.0;
                    assert!((x.v[j] - p.v[j] - (x.a[j] + p.a[j]) * 0.0005).abs() <= kink + 1e-12, "t {t}");
                }
            }
            previous = Some(x);
            t += 0.001;
        }
        // joint 1's target −2 is beyond its 1 rad/s bound: it reaches −1 from above, never past it
        let reached = seg.sample(0.799);
        assert!(
            (reached.v[1] + 1.0).abs() < 1e-3 && reached.v[1] >= -1.0 - 1e-12,
            "{reached:?}"
        );
        assert!(
            (reached.v[0] - 1.5).abs() < 1e-3 && reached.v[0] <= 1.5 + 1e-12,
            "{reached:?}"
        );
    }

    #[test]
    fn the_cubic_between_kept_knots_is_the_constant_jerk_profile_itself() {
        let s = shape();
        let start = KnotState::rest(&[0.0, 0.0]);
        let targets = vec![vec![1.0, 0.5]; 25];
        let seg = Segment::build(&s, &start, &targets).unwrap();
        // the uncompressed profile, stepped knot by knot, is where the sampled segment is at every knot time
        let mut state = start;
        for k in 1..=60 {
            let target = targets.get(k - 1).cloned().unwrap_or(vec![0.0; 2]);
            state = Segment::step(&s, &state, &target);
            let x = seg.sample(k as f64 * s.knot);
            for j in 0..2 {
                assert!(
                    (x.q[j] - state.q[j]).abs() < 1e-12 && (x.v[j] - state.v[j]).abs() < 1e-12,
                    "knot {k}"
                );
            }
        }
        assert!(
            seg.times.len() < 60,
            "constant-jerk stretches span one cubic: {} knots",
            seg.times.len()
        );
    }

    #[test]
    fn bad_limits_and_inputs_are_refused() {
        assert!(
            SegmentShape::new(vec![1.0], vec![1.0], vec![1.0], 0.002, 0.005).is_err(),
            "T under five knots"
        );
        assert!(SegmentShape::new(vec![1.0], vec![0.0], vec![1.0], 0.002, 0.01).is_err());
        assert!(SegmentShape::new(vec![1.0, 1.0], vec![1.0], vec![1.0], 0.002, 0.01).is_err());
        let s = shape();
        assert!(Segment::build(&s, &KnotState::rest(&[0.0]), &[]).is_err());
        assert!(Segment::build(&s, &KnotState::rest(&[0.0, 0.0]), &[vec![f64::NAN, 0.0]]).is_err());
    }
}
