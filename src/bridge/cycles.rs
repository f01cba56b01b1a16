//! What the simulated robot sees of the arm's command at each of its cycles, the way a Franka
//! checks it: the command in effect held against the reflexes, its largest velocity, acceleration
//! and jerk, and the gaps between deliveries. A cycle the robot itself ran late (a catch-up tick) is
//! excused: it is neither checked nor counted as a missed delivery, and the cycle after it is only
//! followed, since its difference to the held command is the robot's lateness, not the stream's.

use super::reflexes::FrankaReflexes;

/// Gaps are counted in cycles up to this many; longer ones in the last bin.
const MAX_GAP: usize = 10_000;

/// The per-cycle record (see the module).
#[derive(Debug, Clone)]
pub struct CycleRecord {
    dt: f64,
    previous: Vec<f64>,
    previous_a: Vec<f64>,
    /// On-time cycles in a row (saturating at 2): a difference needs 1, a second difference 2.
    in_row: usize,
    /// Largest |v|, |Δv|/dt and |Δ²v|/dt² of on-time cycles.
    pub maxima: [Vec<f64>; 3],
    since_delivery: usize,
    gap_known: bool,
    /// Cycles between consecutive deliveries (index: cycles; 1 is a delivery every cycle).
    gaps: Vec<u64>,
}

impl CycleRecord {
    pub fn new(dt: f64, joints: usize) -> Self {
        Self {
            dt,
            previous: vec![0.0; joints],
            previous_a: vec![0.0; joints],
            // the robot starts at rest, commanded zero for as long as it has been on
            in_row: 2,
            maxima: [vec![0.0; joints], vec![0.0; joints], vec![0.0; joints]],
            since_delivery: 0,
            gap_known: false,
            gaps: vec![0; MAX_GAP + 1],
        }
    }

    /// One cycle with `v` in effect, after a delivery since the last cycle when `delivered`; an
    /// `excused` cycle is the robot's own late one. Checks `reflexes` (when given and not
    /// aborted) unless excused or just after one, and returns the reflex tripped.
    pub fn cycle(&mut self, v: &[f64], delivered: bool, excused: bool, reflexes: Option<&mut FrankaReflexes>) -> Option<String> {
        if excused {
            self.in_row = 0;
            self.gap_known = false;
            self.previous.copy_from_slice(v);
            if let Some(r) = reflexes {
                r.follow(v);
            }
            return None;
        }
        if delivered {
            if self.gap_known {
                self.gaps[self.since_delivery.clamp(1, MAX_GAP)] += 1;
            }
            self.gap_known = true;
            self.since_delivery = 0;
        }
        self.since_delivery += 1;
        let mut tripped = None;
        if let Some(r) = reflexes.filter(|r| r.aborted().is_none()) {
            if self.in_row >= 1 {
                tripped = r.check(v).map(str::to_string);
            } else {
                r.follow(v);
            }
        }
        for (j, &vj) in v.iter().enumerate() {
            let a = (vj - self.previous[j]) / self.dt;
            self.maxima[0][j] = self.maxima[0][j].max(vj.abs());
            if self.in_row >= 1 {
                self.maxima[1][j] = self.maxima[1][j].max(a.abs());
            }
            if self.in_row >= 2 {
                self.maxima[2][j] = self.maxima[2][j].max(((a - self.previous_a[j]) / self.dt).abs());
            }
            self.previous_a[j] = a;
        }
        self.previous.copy_from_slice(v);
        self.in_row = (self.in_row + 1).min(2);
        tripped
    }

    /// Counts of the gaps between deliveries, by length in cycles (index 0 unused; the last bin
    /// holds every longer gap).
    pub fn gaps(&self) -> &[u64] {
        &self.gaps
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reflexes() -> FrankaReflexes {
        FrankaReflexes::new(0.001, &[2.0], &[10.0], &[5000.0]).unwrap()
    }

    #[test]
    fn a_stalled_stream_trips_the_jerk_reflex_unless_the_robot_itself_was_late() {
        // a ramp at 4 rad/s² (0.004 per cycle): within every limit while it streams
        let ramp: Vec<f64> = (0..10).map(|k| 0.004 * f64::from(k)).collect();
        let run = |late: bool| {
            let (mut c, mut r) = (CycleRecord::new(0.001, 1), reflexes());
            let mut tripped = None;
            for (k, &v) in ramp.iter().enumerate() {
                tripped = tripped.or(c.cycle(&[v], true, false, Some(&mut r)));
                if k == 4 {
                    // three cycles with the same command, then the stream goes on one step further:
                    // acceleration 4 → 0 → 4 rad/s² within a cycle, a jerk of 4000 rad/s³ each way
                    for _ in 0..3 {
                        tripped = tripped.or(c.cycle(&[v], false, late, Some(&mut r)));
                    }
                }
            }
            (tripped, c)
        };
        let (tripped, c) = run(false);
        assert!(tripped.is_none(), "4000 rad/s³ is within the limit: {tripped:?}");
        assert!((c.maxima[2][0] - 4000.0).abs() < 1e-6, "{:?}", c.maxima);
        assert_eq!(c.gaps()[4], 1, "one gap of four cycles");
        assert_eq!(c.gaps()[1], 8);

        // at 6 rad/s² (reached within the jerk limit), a held command is a jerk of 6000 rad/s³
        let stream = [0.0, 0.004, 0.010, 0.016, 0.016, 0.016, 0.022, 0.028];
        let late = [false, false, false, false, true, true, false, false];
        let trips = |excuse: bool| {
            let (mut c, mut r) = (CycleRecord::new(0.001, 1), reflexes());
            let trips: Vec<_> = stream
                .iter()
                .zip(late)
                .map(|(&v, l)| c.cycle(&[v], !l, l && excuse, Some(&mut r)))
                .collect();
            (trips, c)
        };
        let (held, _) = trips(false);
        assert!(
            held[..4].iter().all(Option::is_none) && held[4].is_some(),
            "a stream that stalls: {held:?}"
        );
        let (excused, c) = trips(true);
        assert!(
            excused.iter().all(Option::is_none),
            "the robot's own late cycles excused: {excused:?}"
        );
        assert_eq!(c.gaps().iter().sum::<u64>(), 4, "no gap booked across the late cycles");
        assert_eq!(c.gaps()[1], 4);
    }
}
