//! The arm's trajectory stream for a joint_trajectory_controller (JTC): what was sent and when the next
//! segment is due, the splice of a new segment onto the one the robot follows, and the stop segment.
//!
//! A segment published at time t (the answered state's stamp) starts at t with the segment in force
//! there and copies it up to the splice t + lead, so that JTC, which replaces its trajectory on arrival
//! and samples the new one at its own time, sees no change wherever in [t, t + lead] the message
//! arrives. From the splice it follows the filtered targets for `tolerated_gap + period`, then stops at
//! rest (see [`super::segment`]): a stream that pauses for up to the tolerated gap is ridden out as
//! planned, one that is lost brings the arm to rest along a path within the segment's limits.

use super::command_stream::Command;
use super::segment::{KnotState, Segment, SegmentBuilder, SegmentShape};
use crate::error::{Result, SabreError};

/// A segment every 10 ms (s): JTC's topic interface takes a trajectory per control cycle it runs, and
/// the sequential filter along a whole segment takes about as long as ten of the velocity stream's ticks.
pub const TRAJECTORY_PERIOD: f64 = 0.01;
/// From a segment's stamp to its splice (s): a message that takes longer to reach the robot changes what
/// it follows abruptly, so the lead covers the delivery latencies of a loaded two-core computer.
pub const TRAJECTORY_LEAD: f64 = 0.03;
/// The pause in deliveries (s) a segment rides out before its stop begins.
pub const TRAJECTORY_TOLERATED_GAP: f64 = 0.1;
/// The sequential filter's step (s): one FILTER-QP per 10 ms of segment.
pub const TRAJECTORY_FILTER_STEP: f64 = 0.01;
/// The segments' knot interval (s) and their velocity's time constant (five knots, the least without
/// overshoot; see [`super::segment`]).
pub const TRAJECTORY_KNOT: f64 = 0.002;
pub const TRAJECTORY_TIME_CONSTANT: f64 = 0.01;

/// The settings of a [`TrajectoryStream`].
#[derive(Debug, Clone, PartialEq)]
pub struct TrajectoryConfig {
    /// The segments' limits and knots (the arm's joints, in the arm command's order).
    pub shape: SegmentShape,
    /// Time between two publications (s).
    pub period: f64,
    /// From a publication's stamp to its splice (s): the longest a message may take to reach the
    /// robot without changing what it follows.
    pub lead: f64,
    /// The longest pause in deliveries (s) a segment rides out before its stop begins.
    pub tolerated_gap: f64,
    /// The sequential filter's step (s): one FILTER-QP per step along the segment, a whole number of
    /// knots.
    pub filter_step: f64,
    /// JTC's position gains k_p (1/s, one per arm joint): the robot executes v_d + k_p (q_d − q). The
    /// segments take it off their targets (v_d = u − k_p (q_d − q), with q_d − q decaying at k_p as the
    /// feedback closes it), so that the robot executes the filtered command u, also while the arm is
    /// held back: a held arm's desired positions then lead it by u/k_p, not by ever more.
    pub position_gain: Vec<f64>,
}

impl TrajectoryConfig {
    /// Checks the settings against each other. Errors name the setting.
    pub fn validate(&self) -> Result<()> {
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(SabreError::invalid(name, format!("must be finite and positive, got {v}")))
            }
        };
        positive("trajectory_period", self.period)?;
        positive("trajectory_filter_step", self.filter_step)?;
        if !(self.lead.is_finite() && self.lead >= 0.0) {
            return Err(SabreError::invalid(
                "trajectory_lead",
                format!("must be finite and non-negative, got {}", self.lead),
            ));
        }
        if !(self.tolerated_gap.is_finite() && self.tolerated_gap >= self.period) {
            return Err(SabreError::invalid(
                "trajectory_tolerated_gap",
                format!(
                    "must be at least the publication period {} s, got {}",
                    self.period, self.tolerated_gap
                ),
            ));
        }
        let knots = self.filter_step / self.shape.knot;
        if (knots - knots.round()).abs() > 1e-6 || knots.round() < 1.0 {
            return Err(SabreError::invalid(
                "trajectory_filter_step",
                format!(
                    "must be a whole number of knots ({} s), got {}",
                    self.shape.knot, self.filter_step
                ),
            ));
        }
        if self.position_gain.len() != self.shape.joints() || !self.position_gain.iter().all(|g| g.is_finite() && *g >= 0.0) {
            return Err(SabreError::invalid(
                "trajectory_position_gain",
                format!(
                    "needs {} finite, non-negative gains, got {:?}",
                    self.shape.joints(),
                    self.position_gain
                ),
            ));
        }
        Ok(())
    }

    /// Knots per filter step.
    pub fn knots_per_step(&self) -> usize {
        (self.filter_step / self.shape.knot).round() as usize
    }

    /// Filter steps a segment follows its targets for: `tolerated_gap + period` from the splice.
    pub fn steps(&self) -> usize {
        ((self.tolerated_gap + self.period) / self.filter_step - 1e-9).ceil().max(1.0) as usize
    }
}

/// What a trajectory tick produced: the base's command stream's step and, when one was due and kept
/// the limits, the segment to publish (times from the tick's t).
#[derive(Debug, Clone, Default)]
pub struct TrajectoryTick {
    pub command: Command,
    pub segment: Option<Segment>,
}

/// The filtered steps of the segment planned last: their times and commands (nq each), the base's
/// command until the next.
#[derive(Debug, Clone, Default)]
pub struct FilteredSteps {
    pub times: Vec<f64>,
    pub rows: Vec<f64>,
}

/// What a stream has done.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TrajectoryCounts {
    /// Segments handed out to publish, stops included.
    pub published: u64,
    /// Stop segments among them.
    pub stops: u64,
    /// Segments not sent because they left the joint limits' margin (the one in force went on).
    pub refused: u64,
    /// Filter steps that fell back to u = 0 (the filter's fallback).
    pub fallbacks: u64,
}

/// The stream's state (see the module).
#[derive(Debug, Clone)]
pub struct TrajectoryStream {
    config: TrajectoryConfig,
    /// The segment the robot follows (or will, once it arrives) and its start on the ticks' clock.
    sent: Option<(f64, Segment)>,
    next_due: f64,
    stopped: bool,
    counts: TrajectoryCounts,
}

impl TrajectoryStream {
    /// A stream with `config` (checked), nothing sent yet.
    pub fn new(config: TrajectoryConfig) -> Result<Self> {
        config.validate()?;
        Ok(Self {
            config,
            sent: None,
            next_due: f64::NEG_INFINITY,
            stopped: false,
            counts: TrajectoryCounts::default(),
        })
    }

    pub fn config(&self) -> &TrajectoryConfig {
        &self.config
    }
    pub fn counts(&self) -> &TrajectoryCounts {
        &self.counts
    }
    pub(crate) fn counts_mut(&mut self) -> &mut TrajectoryCounts {
        &mut self.counts
    }
    /// The segment sent last and its start on the ticks' clock.
    pub fn sent(&self) -> Option<(f64, &Segment)> {
        self.sent.as_ref().map(|(t, s)| (*t, s))
    }
    /// Whether the last segment sent was a stop.
    pub fn stopped(&self) -> bool {
        self.stopped
    }

    /// The desired state of the segment sent last at time `t`; None before the first.
    pub fn desired_at(&self, t: f64) -> Option<KnotState> {
        self.sent.as_ref().map(|(from, s)| s.sample(t - from))
    }

    /// Whether a segment is due at `t`.
    pub fn due(&self, t: f64) -> bool {
        t >= self.next_due - 1e-9
    }

    /// Where a segment published at `t` takes over from the one sent last: its splice time, `lead`
    /// after t, and the state there; before the first, the robot holds the measured positions `q`
    /// (the arm's) at rest.
    pub fn splice(&self, t: f64, q: &[f64]) -> (f64, KnotState) {
        let splice = t + self.config.lead;
        match &self.sent {
            Some((from, s)) => (splice, s.sample(splice - from)),
            None => (splice, KnotState::rest(q)),
        }
    }

    /// The segment to publish at `t`: the one sent last up to `splice`, then `new` (which starts there,
    /// see [`Self::splice`]); it becomes the one the robot follows. `stop` marks a stop segment.
    pub fn commit(&mut self, t: f64, splice: f64, new: Segment, stop: bool) -> Result<&Segment> {
        let segment = match &self.sent {
            Some((from, old)) => Segment::spliced(old, t - from, splice - from, &new)?,
            None => {
                let first = new
                    .states
                    .first()
                    .ok_or_else(|| SabreError::invalid("segment", "has no knots"))?;
                let held = Segment {
                    times: vec![0.0],
                    states: vec![KnotState::rest(&first.q)],
                };
                Segment::spliced(&held, 0.0, splice - t, &new)?
            }
        };
        self.next_due = if self.next_due.is_finite() && self.next_due + self.config.period > t {
            self.next_due + self.config.period
        } else {
            t + self.config.period
        };
        self.stopped = stop;
        self.counts.published += 1;
        self.counts.stops += u64::from(stop);
        Ok(&self.sent.insert((t, segment)).1)
    }

    /// Notes a segment planned at `t` and not sent: the next one is due a period later.
    pub fn skip(&mut self, t: f64) {
        self.next_due = t + self.config.period;
        self.counts.refused += 1;
    }

    /// The stop segment to publish at `t`: the one sent last up to the splice, then a stop to rest
    /// within the segment's limits. None when nothing was sent or the last segment already stops.
    pub fn stop(&mut self, t: f64) -> Result<Option<&Segment>> {
        if self.stopped || self.sent.is_none() {
            return Ok(None);
        }
        let (splice, start) = self.splice(t, &[]);
        let stop = SegmentBuilder::new(&self.config.shape, &start)?.finish()?;
        self.commit(t, splice, stop, true).map(Some)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> TrajectoryConfig {
        TrajectoryConfig {
            shape: SegmentShape::new(vec![2.0, 1.0], vec![5.0, 3.0], vec![2000.0, 1000.0], 0.002, 0.01).unwrap(),
            period: 0.01,
            lead: 0.02,
            tolerated_gap: 0.1,
            filter_step: 0.01,
            position_gain: vec![10.0, 10.0],
        }
    }

    #[test]
    fn a_new_segment_is_the_old_one_up_to_the_splice_and_the_stop_ends_at_rest() {
        let mut stream = TrajectoryStream::new(config()).unwrap();
        assert!(stream.due(0.0) && stream.desired_at(0.0).is_none());
        let shape = config().shape;
        let (splice, start) = stream.splice(0.0, &[0.3, -0.2]);
        assert_eq!((splice, start.clone()), (0.02, KnotState::rest(&[0.3, -0.2])));
        let built = Segment::build(&shape, &start, &vec![vec![1.0, -0.5]; 60]).unwrap();
        // the first holds the measured positions up to its splice
        let first = stream.commit(0.0, splice, built.clone(), false).unwrap().clone();
        assert_eq!(first.sample(0.01), start);
        let (a, b) = (first.sample(0.03), built.sample(0.01));
        assert!(a
            .q
            .iter()
            .chain(&a.v)
            .zip(b.q.iter().chain(&b.v))
            .all(|(x, y)| (x - y).abs() < 1e-12));
        assert!(!stream.due(0.005) && stream.due(0.01));
        // the next one at 0.013 turns the other way from 0.033
        let (splice, start) = stream.splice(0.013, &[]);
        assert!((splice - 0.033).abs() < 1e-15);
        let new = Segment::build(&shape, &start, &vec![vec![-1.0, 0.5]; 60]).unwrap();
        let published = stream.commit(0.013, splice, new.clone(), false).unwrap().clone();
        for k in 0..=200 {
            let s = 0.013 + k as f64 * 0.0007;
            let (a, b) = (published.sample(s - 0.013), first.sample(s));
            let tail = new.sample(s - splice);
            let expected = if s <= splice { &b } else { &tail };
            for j in 0..2 {
                assert!((a.q[j] - expected.q[j]).abs() < 1e-12, "s {s}: {a:?} vs {expected:?}");
                assert!((a.v[j] - expected.v[j]).abs() < 1e-9, "s {s}");
            }
        }
        // a stop from there: at rest in the end, within the shape's limits all along, and only once
        let stop = stream.stop(0.05).unwrap().unwrap().clone();
        assert!(stream.stopped() && stream.stop(0.06).unwrap().is_none());
        let end = stop.sample(stop.end() + 0.1);
        assert!(end.v.iter().all(|v| *v == 0.0));
        let mut s = 0.0;
        while s < stop.end() {
            let x = stop.sample(s);
            assert!(x.v.iter().zip(&shape.velocity).all(|(v, m)| v.abs() <= m + 1e-9));
            assert!(x.a.iter().zip(&shape.acceleration).all(|(a, m)| a.abs() <= m + 1e-9));
            s += 0.001;
        }
        assert_eq!(stream.counts().published, 3);
        assert_eq!(stream.counts().stops, 1);
    }

    #[test]
    fn settings_that_cannot_work_are_refused_by_name() {
        let refused = |f: fn(&mut TrajectoryConfig), name: &str| {
            let mut c = config();
            f(&mut c);
            let e = TrajectoryStream::new(c).unwrap_err().to_string();
            assert!(e.contains(name), "{e}");
        };
        refused(|c| c.period = 0.0, "trajectory_period");
        refused(|c| c.tolerated_gap = 0.005, "trajectory_tolerated_gap");
        refused(|c| c.filter_step = 0.003, "trajectory_filter_step");
        refused(|c| c.lead = f64::NAN, "trajectory_lead");
        refused(|c| c.position_gain = vec![1.0], "trajectory_position_gain");
    }
}
