//! ros2_controllers' joint_trajectory_controller (JTC) on its topic interface, as the simulated
//! robot runs it each cycle: the newest trajectory replaces the one in force at its stamp (on
//! arrival when the stamp is zero) and is entered from the desired state of that moment; between
//! points it interpolates with a quintic (positions, velocities, accelerations), a cubic
//! (positions, velocities) or linearly (positions only); after the last point it holds that
//! position at rest; the velocity command interface then sends v_d + k_p (q_d − q).

use super::messages::{Stamp, TrajectoryValue};
use crate::error::{Result, SabreError};

/// A desired state: positions, velocities and accelerations, one each per joint.
#[derive(Debug, Clone, PartialEq)]
struct Desired {
    q: Vec<f64>,
    v: Vec<f64>,
    a: Vec<f64>,
}

/// A trajectory as received: its points' absolute times on the ticks' clock, in the arm's joint order.
#[derive(Debug, Clone)]
struct Trajectory {
    /// When it replaces the one in force (the ticks' clock).
    start: f64,
    times: Vec<f64>,
    points: Vec<Desired>,
    /// 1: positions only (linear), 3: with velocities (cubic), 5: with accelerations (quintic).
    order: usize,
    /// The desired state when it took over, and that time.
    before: Option<(f64, Desired)>,
}

/// JTC's topic interface and velocity command for one arm (see the module).
#[derive(Debug, Clone)]
pub struct TrajectoryFollower {
    names: Vec<String>,
    gains: Vec<f64>,
    pending: Option<Trajectory>,
    active: Option<Trajectory>,
    /// The position held without a trajectory (the first measured one, or a trajectory's last).
    held: Option<Vec<f64>>,
    desired: Desired,
    command: Vec<f64>,
    /// The ticks' time and the stamps' (ns) of the first reception.
    clock: Option<(f64, i64)>,
}

/// Position, velocity and acceleration at `s` ∈ [0, T] of the polynomial of order 1, 3 or 5 that
/// meets (p0, v0, a0) at 0 and (p1, v1, a1) at T (Hermite; the linear one meets positions only).
#[allow(clippy::too_many_arguments)]
fn hermite(order: usize, s: f64, t: f64, p0: f64, v0: f64, a0: f64, p1: f64, v1: f64, a1: f64) -> [f64; 3] {
    let d = p1 - p0;
    let c: [f64; 6] = match order {
        1 => [p0, d / t, 0.0, 0.0, 0.0, 0.0],
        3 => [
            p0,
            v0,
            (3.0 * d - (2.0 * v0 + v1) * t) / t.powi(2),
            (-2.0 * d + (v0 + v1) * t) / t.powi(3),
            0.0,
            0.0,
        ],
        _ => [
            p0,
            v0,
            a0 / 2.0,
            (20.0 * d - (8.0 * v1 + 12.0 * v0) * t - (3.0 * a0 - a1) * t * t) / (2.0 * t.powi(3)),
            (-30.0 * d + (14.0 * v1 + 16.0 * v0) * t + (3.0 * a0 - 2.0 * a1) * t * t) / (2.0 * t.powi(4)),
            (12.0 * d - 6.0 * (v1 + v0) * t + (a1 - a0) * t * t) / (2.0 * t.powi(5)),
        ],
    };
    [derivative(&c, s, 0), derivative(&c, s, 1), derivative(&c, s, 2)]
}

/// The `n`-th derivative at `s` of the polynomial with coefficients `c` (lowest power first).
fn derivative(c: &[f64; 6], s: f64, n: usize) -> f64 {
    let mut value = 0.0;
    for k in (n..6).rev() {
        let factor: f64 = ((k + 1 - n)..=k).map(|i| i as f64).product();
        value = value * s + factor * c[k];
    }
    value
}

impl TrajectoryFollower {
    /// A follower of the arm's joints `names` (the order of its commands) with the velocity
    /// interface's position gains `gains` (1/s, one per joint).
    pub fn new(names: Vec<String>, gains: Vec<f64>) -> Result<Self> {
        let n = names.len();
        if n == 0 || gains.len() != n || !gains.iter().all(|g| g.is_finite() && *g >= 0.0) {
            return Err(SabreError::invalid(
                "gains",
                format!("need one finite, non-negative gain per joint ({n}), got {gains:?}"),
            ));
        }
        Ok(Self {
            names,
            gains,
            pending: None,
            active: None,
            held: None,
            desired: Desired {
                q: vec![0.0; n],
                v: vec![0.0; n],
                a: vec![0.0; n],
            },
            command: vec![0.0; n],
            clock: None,
        })
    }

    /// Takes a trajectory received at `now` (the ticks' clock) and `wall` (the stamps' clock): it
    /// waits for its stamp (zero: starts at once) and replaces any trajectory still waiting. JTC's
    /// refusals are errors: joint names that are not the arm's, no points, times that do not
    /// increase, a point of the wrong size or not finite, mixed point kinds, a trajectory that ended
    /// before it arrived.
    pub fn receive(&mut self, message: &TrajectoryValue, now: f64, wall: f64) -> Result<()> {
        let n = self.names.len();
        let mut index = Vec::with_capacity(n);
        for name in &self.names {
            match message.joint_names.iter().position(|m| m == name) {
                Some(i) => index.push(i),
                None => {
                    return Err(SabreError::invalid(
                        "joint_names",
                        format!("{:?} lacks {name:?} (partial goals are not allowed)", message.joint_names),
                    ))
                }
            }
        }
        if message.joint_names.len() != n {
            return Err(SabreError::invalid(
                "joint_names",
                format!("{:?} are not the arm's {n}", message.joint_names),
            ));
        }
        let Some(first) = message.points.first() else {
            return Err(SabreError::invalid("points", "an empty trajectory"));
        };
        let order = match (first.velocities.is_empty(), first.accelerations.is_empty()) {
            (true, _) => 1,
            (false, true) => 3,
            (false, false) => 5,
        };
        let sized = |v: &[f64], wanted: bool| if wanted { v.len() == n } else { v.is_empty() };
        let mut previous = -f64::INFINITY;
        for (k, p) in message.points.iter().enumerate() {
            let kinds = sized(&p.positions, true) && sized(&p.velocities, order >= 3) && sized(&p.accelerations, order == 5);
            let finite = [&p.positions, &p.velocities, &p.accelerations]
                .iter()
                .all(|v| v.iter().all(|x| x.is_finite()));
            if !(kinds && finite && p.time_from_start >= 0.0 && p.time_from_start > previous) {
                return Err(SabreError::invalid(
                    "points",
                    format!(
                        "point {k}: sizes, finiteness or time_from_start {} (after {previous})",
                        p.time_from_start
                    ),
                ));
            }
            previous = p.time_from_start;
        }
        // JTC reads stamps on its own clock. Here the stamps' clock is mapped onto the ticks' by the
        // pair (now, wall) of the first reception (re-taken only when the two moved apart by more
        // than a cycle: a clock that jumped): two clocks read one after the other differ by the
        // instants between the reads, and a pair per message would shift each replacement by those
        // microseconds. Stamps stay in nanoseconds (epoch seconds in an f64 lose a tenth of a µs).
        let wall_ns = (wall * 1e9).round() as i64;
        let reference = match self.clock {
            Some((t0, w0)) if ((now - t0) - (wall_ns - w0) as f64 * 1e-9).abs() <= 1e-3 => (t0, w0),
            _ => (now, wall_ns),
        };
        self.clock = Some(reference);
        let start = if message.stamp == Stamp::default() {
            now
        } else {
            reference.0 + (message.stamp.nanoseconds() - reference.1) as f64 * 1e-9
        };
        if start + previous < now {
            return Err(SabreError::invalid("header.stamp", "the trajectory ended before it arrived"));
        }
        let pick = |v: &[f64]| {
            if v.is_empty() {
                vec![0.0; n]
            } else {
                index.iter().map(|&i| v[i]).collect()
            }
        };
        self.pending = Some(Trajectory {
            start,
            times: message.points.iter().map(|p| start + p.time_from_start).collect(),
            points: message
                .points
                .iter()
                .map(|p| Desired {
                    q: pick(&p.positions),
                    v: pick(&p.velocities),
                    a: pick(&p.accelerations),
                })
                .collect(),
            order,
            before: None,
        });
        Ok(())
    }

    /// The velocity command (one per joint) at `t` (the ticks' clock) with the arm at `q`: the
    /// waiting trajectory takes over once its start has come, then v_d + k_p (q_d − q).
    pub fn command(&mut self, t: f64, q: &[f64]) -> &[f64] {
        if self.held.is_none() {
            self.held = Some(q.to_vec());
        }
        if self.pending.as_ref().is_some_and(|p| p.start <= t) {
            let mut next = self.pending.take().expect("checked");
            self.sample(t);
            next.before = Some((t, self.desired.clone()));
            self.active = Some(next);
        }
        self.sample(t);
        for (((c, &qd), &vd), (&qj, &k)) in self
            .command
            .iter_mut()
            .zip(&self.desired.q)
            .zip(&self.desired.v)
            .zip(q.iter().zip(&self.gains))
        {
            *c = vd + k * (qd - qj);
        }
        &self.command
    }

    /// The desired state at `t` into `self.desired`.
    fn sample(&mut self, t: f64) {
        let d = &mut self.desired;
        let Some(traj) = &self.active else {
            let held = self.held.as_deref().expect("set before sampling");
            d.q.copy_from_slice(held);
            d.v.iter_mut().chain(d.a.iter_mut()).for_each(|x| *x = 0.0);
            return;
        };
        let last = traj.times.len() - 1;
        if t >= traj.times[last] {
            d.q.copy_from_slice(&traj.points[last].q);
            d.v.iter_mut().chain(d.a.iter_mut()).for_each(|x| *x = 0.0);
            return;
        }
        let i = traj.times.partition_point(|&ti| ti <= t);
        let (t0, p0, t1, p1) = if i == 0 {
            let (tb, before) = traj.before.as_ref().expect("set at takeover");
            (*tb, before, traj.times[0], &traj.points[0])
        } else {
            (traj.times[i - 1], &traj.points[i - 1], traj.times[i], &traj.points[i])
        };
        let span = t1 - t0;
        for j in 0..d.q.len() {
            let [q, v, a] = if span <= 0.0 {
                [p1.q[j], p1.v[j], p1.a[j]]
            } else {
                hermite(traj.order, t - t0, span, p0.q[j], p0.v[j], p0.a[j], p1.q[j], p1.v[j], p1.a[j])
            };
            d.q[j] = q;
            d.v[j] = v;
            d.a[j] = a;
        }
    }

    /// The velocity command of the last [`Self::command`] (zeros before the first).
    pub fn last_command(&self) -> &[f64] {
        &self.command
    }

    /// Whether a trajectory is in force or waiting.
    pub fn has_trajectory(&self) -> bool {
        self.active.is_some() || self.pending.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::super::messages::{Stamp, TrajectoryPoint};
    use super::*;

    fn names() -> Vec<String> {
        vec!["a".into(), "b".into()]
    }

    fn message(stamp: f64, points: Vec<TrajectoryPoint>) -> TrajectoryValue {
        TrajectoryValue {
            stamp: if stamp == 0.0 {
                Stamp::default()
            } else {
                Stamp::from_seconds(stamp)
            },
            joint_names: names(),
            points,
        }
    }

    fn point(t: f64, q: [f64; 2], v: Option<[f64; 2]>, a: Option<[f64; 2]>) -> TrajectoryPoint {
        TrajectoryPoint {
            time_from_start: t,
            positions: q.to_vec(),
            velocities: v.map_or(Vec::new(), |v| v.to_vec()),
            accelerations: a.map_or(Vec::new(), |a| a.to_vec()),
        }
    }

    /// A polynomial's value and first two derivatives at t (coefficients lowest power first).
    fn poly(c: &[f64], t: f64) -> [f64; 3] {
        let mut out = [0.0; 3];
        for (k, &ck) in c.iter().enumerate() {
            let k = k as i32;
            out[0] += ck * t.powi(k);
            if k >= 1 {
                out[1] += f64::from(k) * ck * t.powi(k - 1);
            }
            if k >= 2 {
                out[2] += f64::from(k * (k - 1)) * ck * t.powi(k - 2);
            }
        }
        out
    }

    /// Points at `times` of joint a following `ca` and joint b following `cb`, with `order`'s kinds.
    fn sampled(ca: &[f64], cb: &[f64], times: &[f64], order: usize) -> Vec<TrajectoryPoint> {
        times
            .iter()
            .map(|&t| {
                let (a, b) = (poly(ca, t), poly(cb, t));
                point(
                    t,
                    [a[0], b[0]],
                    (order >= 3).then_some([a[1], b[1]]),
                    (order == 5).then_some([a[2], b[2]]),
                )
            })
            .collect()
    }

    /// Follows `m` received at 0 from the first point's state, without feedback: the desired
    /// velocity at each t.
    fn follow(m: &TrajectoryValue, ts: &[f64]) -> Vec<Vec<f64>> {
        let mut f = TrajectoryFollower::new(names(), vec![0.0, 0.0]).unwrap();
        f.receive(m, 0.0, 100.0).unwrap();
        ts.iter().map(|&t| f.command(t, &m.points[0].positions).to_vec()).collect()
    }

    #[test]
    fn cubic_and_quintic_pieces_reproduce_polynomials_of_their_order_exactly() {
        let times = [0.0, 0.013, 0.03, 0.05];
        let ts: Vec<f64> = (0..50).map(|k| 0.001 * f64::from(k)).collect();
        for (order, ca, cb) in [
            (3, vec![0.1, 0.2, -0.3, 0.5], vec![-1.0, 0.0, 2.0, -4.0]),
            (
                5,
                vec![0.1, 0.2, -0.3, 0.5, 7.0, -40.0],
                vec![-1.0, 0.0, 2.0, -4.0, 0.0, 90.0],
            ),
            (1, vec![0.3, -0.7], vec![0.0, 0.25]),
        ] {
            let v = follow(&message(0.0, sampled(&ca, &cb, &times, order)), &ts);
            for (t, v) in ts.iter().zip(&v) {
                let (a, b) = (poly(&ca, *t), poly(&cb, *t));
                assert!(
                    (v[0] - a[1]).abs() < 1e-9 && (v[1] - b[1]).abs() < 1e-9,
                    "order {order} t {t}: {v:?}"
                );
            }
        }
    }

    #[test]
    fn after_the_last_point_its_position_is_held_at_rest_by_the_position_gain() {
        let m = message(0.0, vec![point(0.01, [0.5, -0.5], Some([0.2, 0.0]), None)]);
        let mut f = TrajectoryFollower::new(names(), vec![10.0, 2.0]).unwrap();
        f.receive(&m, 0.0, 100.0).unwrap();
        let v = f.command(0.5, &[0.4, -0.5]).to_vec();
        assert!((v[0] - 10.0 * 0.1).abs() < 1e-12 && v[1].abs() < 1e-12, "{v:?}");
    }

    #[test]
    fn a_stamped_trajectory_waits_for_its_stamp_and_is_entered_from_the_desired_state() {
        let mut f = TrajectoryFollower::new(names(), vec![0.0, 0.0]).unwrap();
        // in force: a ramp of 0.4 rad/s on joint a from rest at q = 0
        f.receive(&message(0.0, sampled(&[0.0, 0.4], &[0.0], &[0.0, 1.0], 3)), 0.0, 100.0)
            .unwrap();
        assert!((f.command(0.1, &[0.0, 0.0])[0] - 0.4).abs() < 1e-12);
        // stamped 0.125 s after it arrives: holds back until then, then starts from q_d(0.25) = 0.1
        let later = message(100.25, vec![point(0.125, [0.1, 0.0], Some([0.0, 0.0]), None)]);
        f.receive(&later, 0.125, 100.125).unwrap();
        assert!(
            (f.command(0.24, &[0.0, 0.0])[0] - 0.4).abs() < 1e-12,
            "the old one until the stamp"
        );
        let v = f.command(0.25, &[0.0, 0.0])[0];
        assert!((v - 0.4).abs() < 1e-9, "entered from the desired velocity, no step: {v}");
        assert!(f.command(0.3, &[0.0, 0.0])[0] < 0.4, "now the new one: slowing down");
        // a cubic from (0.1, 0.4) at 0.25 to (0.1, 0) at 0.375 ends at rest
        let end = f.command(0.375, &[0.1, 0.0])[0];
        assert!(end.abs() < 1e-12, "{end}");
    }

    #[test]
    fn the_newest_waiting_trajectory_replaces_an_older_one_and_stamp_zero_starts_on_arrival() {
        let mut f = TrajectoryFollower::new(names(), vec![0.0, 0.0]).unwrap();
        f.receive(&message(101.0, vec![point(0.1, [1.0, 1.0], None, None)]), 0.0, 100.0)
            .unwrap();
        f.receive(&message(0.0, vec![point(0.1, [0.0, 0.2], None, None)]), 0.0, 100.0)
            .unwrap();
        let v = f.command(0.0, &[0.0, 0.0]).to_vec();
        assert!(
            v[0].abs() < 1e-12 && (v[1] - 2.0).abs() < 1e-12,
            "linear to (0, 0.2) in 0.1 s: {v:?}"
        );
        assert!((f.command(0.9, &[0.0, 0.0])[1]).abs() < 1e-12, "never the replaced one");
    }

    #[test]
    fn trajectories_jtc_refuses_are_refused() {
        let mut f = TrajectoryFollower::new(names(), vec![1.0, 1.0]).unwrap();
        let good = point(0.1, [0.0, 0.0], None, None);
        let mut partial = message(0.0, vec![good.clone()]);
        partial.joint_names = vec!["a".into()];
        let mut foreign = message(0.0, vec![good.clone()]);
        foreign.joint_names = vec!["a".into(), "c".into()];
        let backwards = message(0.0, vec![good.clone(), point(0.05, [0.0, 0.0], None, None)]);
        let mixed = message(
            0.0,
            vec![
                point(0.1, [0.0, 0.0], Some([0.0, 0.0]), None),
                point(0.2, [0.0, 0.0], None, None),
            ],
        );
        let nan = message(0.0, vec![point(0.1, [f64::NAN, 0.0], None, None)]);
        let past = message(99.0, vec![good.clone()]);
        for m in [partial, foreign, backwards, mixed, nan, past, message(0.0, vec![])] {
            assert!(f.receive(&m, 0.0, 100.0).is_err(), "{m:?}");
        }
        assert!(!f.has_trajectory());
        assert!(TrajectoryFollower::new(names(), vec![1.0]).is_err());
    }
}
