//! A robot's joint states merged by name from every message that names them (several drivers
//! publish parts of one robot): the newest position and velocity of each joint with the time it
//! arrived, a staleness per joint, and which messages drive a control tick.

use std::collections::HashMap;
use std::hash::{DefaultHasher, Hash, Hasher};

use crate::error::{Result, SabreError};

/// How many distinct name lists keep their route: publishers with a fixed order send a few.
const ROUTE_CACHE: usize = 64;

/// Where one name list's entries go: the message's indices of the joints the merge knows, each
/// joint's index in the merge's order, and whether such a message drives a tick.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Route {
    src: Vec<usize>,
    dst: Vec<usize>,
    ticks: bool,
}

impl Route {
    /// The indices into the message of the joints the merge knows, in the message's order.
    pub fn message_indices(&self) -> &[usize] {
        &self.src
    }
    /// Those joints' indices in the merge's order, one per message index.
    pub fn joint_indices(&self) -> &[usize] {
        &self.dst
    }
    /// Whether the message names every tick joint.
    pub fn drives_tick(&self) -> bool {
        self.ticks
    }
}

/// A cached route with the name list it belongs to.
#[derive(Debug, Clone, PartialEq)]
struct CachedRoute {
    hash: u64,
    names: Vec<String>,
    route: Route,
}

/// Where a name list's route is: in the cache, or (the cache full) in the scratch route.
#[derive(Clone, Copy)]
enum Slot {
    Cached(usize),
    Scratch,
}

/// The newest position and velocity of each of a robot's joints (`names`, in the merge's order),
/// merged from every message that names them, with the time each arrived.
///
/// A message may carry any subset of the joints, in any order, and joints the merge does not know
/// (fingers, another arm): those are ignored. A message whose names and values differ in length,
/// or with a non-finite value for a known joint, is an error and changes nothing. A message that
/// names every tick joint drives a tick (the arm's joint states). A joint older than its timeout
/// is stale; one never received is stale unless its timeout is infinite.
#[derive(Debug, Clone, PartialEq)]
pub struct JointMerge {
    names: Vec<String>,
    index: HashMap<String, usize>,
    tick: Vec<usize>,
    timeouts: Vec<f64>,
    position: Vec<f64>,
    velocity: Vec<f64>,
    received: Vec<f64>,
    routes: Vec<CachedRoute>,
    scratch: Route,
    /// Which joints a message names, while its route is built.
    named: Vec<bool>,
}

/// The hash of a name list, the cache's first comparison.
fn names_hash<S: AsRef<str>>(names: &[S]) -> u64 {
    let mut hasher = DefaultHasher::new();
    names.len().hash(&mut hasher);
    for name in names {
        name.as_ref().hash(&mut hasher);
    }
    hasher.finish()
}

fn quoted<S: AsRef<str>>(names: impl IntoIterator<Item = S>) -> String {
    let list: Vec<String> = names.into_iter().map(|n| format!("'{}'", n.as_ref())).collect();
    format!("[{}]", list.join(", "))
}

impl JointMerge {
    /// A merge of the distinct joints `names`; a message naming all of `tick_joints` (each one of
    /// `names`) drives a tick; `timeouts` (s, one per joint, not negative, infinite: never stale).
    /// Nothing received yet: every position and velocity zero, every arrival time −∞.
    pub fn new<S: AsRef<str>>(names: Vec<String>, tick_joints: &[S], timeouts: Vec<f64>) -> Result<Self> {
        let n = names.len();
        let mut index = HashMap::with_capacity(n);
        let mut repeated = Vec::new();
        for (i, name) in names.iter().enumerate() {
            if index.insert(name.clone(), i).is_some() {
                repeated.push(name.as_str());
            }
        }
        if !repeated.is_empty() {
            let detail = format!("must be distinct; {} repeat in {}", quoted(&repeated), quoted(&names));
            return Err(SabreError::invalid("joint names", detail));
        }
        let unknown: Vec<&str> = tick_joints
            .iter()
            .map(AsRef::as_ref)
            .filter(|t| !index.contains_key(*t))
            .collect();
        if !unknown.is_empty() {
            let detail = format!("{} are not among {}", quoted(&unknown), quoted(&names));
            return Err(SabreError::invalid("tick joints", detail));
        }
        if timeouts.len() != n {
            return Err(SabreError::shape(
                "timeouts",
                format!("({n},)"),
                format!("({},)", timeouts.len()),
            ));
        }
        if let Some(i) = timeouts.iter().position(|t| t.is_nan() || *t < 0.0) {
            let detail = format!("{} of joint '{}' is not a duration (s, not negative)", timeouts[i], names[i]);
            return Err(SabreError::invalid("timeouts", detail));
        }
        let tick = tick_joints.iter().map(|t| index[t.as_ref()]).collect();
        Ok(Self {
            index,
            tick,
            timeouts,
            position: vec![0.0; n],
            velocity: vec![0.0; n],
            received: vec![f64::NEG_INFINITY; n],
            routes: Vec::new(),
            scratch: Route::default(),
            named: vec![false; n],
            names,
        })
    }

    pub fn names(&self) -> &[String] {
        &self.names
    }
    pub fn timeouts(&self) -> &[f64] {
        &self.timeouts
    }
    /// The tick joints' indices in the merge's order.
    pub fn tick_joints(&self) -> &[usize] {
        &self.tick
    }
    pub fn position(&self) -> &[f64] {
        &self.position
    }
    pub fn velocity(&self) -> &[f64] {
        &self.velocity
    }
    /// When each joint's newest value arrived (−∞: never).
    pub fn received(&self) -> &[f64] {
        &self.received
    }

    /// Finds or builds the route of a message naming `names`, caching a new one while the cache
    /// has room.
    fn slot<S: AsRef<str>>(&mut self, names: &[S]) -> Slot {
        let hash = names_hash(names);
        let same = |c: &CachedRoute| {
            c.hash == hash && c.names.len() == names.len() && c.names.iter().zip(names).all(|(a, b)| a == b.as_ref())
        };
        if let Some(k) = self.routes.iter().position(same) {
            return Slot::Cached(k);
        }
        let mut route = std::mem::take(&mut self.scratch);
        route.src.clear();
        route.dst.clear();
        self.named.fill(false);
        for (k, name) in names.iter().enumerate() {
            if let Some(&i) = self.index.get(name.as_ref()) {
                route.src.push(k);
                route.dst.push(i);
                self.named[i] = true;
            }
        }
        route.ticks = self.tick.iter().all(|&i| self.named[i]);
        if self.routes.len() < ROUTE_CACHE {
            let names = names.iter().map(|n| n.as_ref().to_owned()).collect();
            self.routes.push(CachedRoute { hash, names, route });
            Slot::Cached(self.routes.len() - 1)
        } else {
            self.scratch = route;
            Slot::Scratch
        }
    }

    fn at(&self, slot: Slot) -> &Route {
        match slot {
            Slot::Cached(k) => &self.routes[k].route,
            Slot::Scratch => &self.scratch,
        }
    }

    /// The route of a message naming `names` (no allocation once a name list is cached).
    pub fn route<S: AsRef<str>>(&mut self, names: &[S]) -> &Route {
        let slot = self.slot(names);
        self.at(slot)
    }

    /// Whether a message naming `names` drives a tick.
    pub fn drives_tick<S: AsRef<str>>(&mut self, names: &[S]) -> bool {
        self.route(names).ticks
    }

    /// Takes a joint-state message's known joints, arrived at `received` (an empty `velocity`:
    /// zeros); returns whether it drives a tick. Names and values of different lengths, or a
    /// non-finite value for a known joint, are an error naming the joints, and nothing changes.
    pub fn update<S: AsRef<str>>(&mut self, names: &[S], position: &[f64], velocity: &[f64], received: f64) -> Result<bool> {
        let slot = self.slot(names);
        let n = names.len();
        if position.len() != n || !(velocity.is_empty() || velocity.len() == n) {
            let detail = format!(
                "{} positions and {} velocities for the {n} names {}",
                position.len(),
                velocity.len(),
                quoted(names)
            );
            return Err(SabreError::invalid("joint state", detail));
        }
        let route = match slot {
            Slot::Cached(k) => &self.routes[k].route,
            Slot::Scratch => &self.scratch,
        };
        let value = |k: usize| (position[k], velocity.get(k).copied().unwrap_or(0.0));
        let finite = |k: &usize| {
            let (p, v) = value(*k);
            p.is_finite() && v.is_finite()
        };
        if !route.src.iter().all(finite) {
            let bad = route.src.iter().zip(&route.dst).filter(|(k, _)| !finite(k));
            let detail = format!("non-finite value for {}", quoted(bad.map(|(_, &i)| &self.names[i])));
            return Err(SabreError::invalid("joint state", detail));
        }
        for (&k, &i) in route.src.iter().zip(&route.dst) {
            (self.position[i], self.velocity[i]) = value(k);
            self.received[i] = received;
        }
        Ok(route.ticks)
    }

    /// Sets the joints at `indices` (the merge's order) to `position` and `velocity`, arrived at
    /// `received` (the base from odometry). An index out of range, lengths that differ from the
    /// indices' or a non-finite value are an error, and nothing changes.
    pub fn set(&mut self, indices: &[usize], position: &[f64], velocity: &[f64], received: f64) -> Result<()> {
        let m = indices.len();
        if position.len() != m || velocity.len() != m {
            let got = format!("{} positions and {} velocities", position.len(), velocity.len());
            return Err(SabreError::shape("joint values", format!("{m} of each, one per index"), got));
        }
        if let Some(&i) = indices.iter().find(|&&i| i >= self.names.len()) {
            let detail = format!("index {i} is out of range for {} joints", self.names.len());
            return Err(SabreError::invalid("joint indices", detail));
        }
        if let Some(k) = (0..m).find(|&k| !(position[k].is_finite() && velocity[k].is_finite())) {
            let detail = format!("non-finite value for '{}'", self.names[indices[k]]);
            return Err(SabreError::invalid("joint values", detail));
        }
        for (k, &i) in indices.iter().enumerate() {
            self.position[i] = position[k];
            self.velocity[i] = velocity[k];
            self.received[i] = received;
        }
        Ok(())
    }

    /// Whether every joint is within its timeout at `now` (now − received ≤ timeout).
    pub fn fresh(&self, now: f64) -> bool {
        self.received.iter().zip(&self.timeouts).all(|(r, t)| now - r <= *t)
    }

    /// The joints older than their timeout at `now`, in the merge's order.
    pub fn stale(&self, now: f64) -> impl Iterator<Item = &str> + '_ {
        let old = move |(r, t): (&f64, &f64)| now - r > *t;
        let flags = self.received.iter().zip(&self.timeouts).map(old);
        self.names
            .iter()
            .zip(flags)
            .filter(|(_, old)| *old)
            .map(|(name, _)| name.as_str())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type BadMessage<'a> = (&'a [&'a str], &'a [f64], &'a [f64], &'a str);

    fn merge() -> JointMerge {
        let names = ["base_x", "base_y", "base_yaw", "j1", "j2"].map(String::from).to_vec();
        JointMerge::new(names, &["j1", "j2"], vec![0.1, 0.1, 0.1, 0.01, 0.01]).unwrap()
    }

    #[test]
    fn subset_messages_merge_by_name_and_unknown_joints_are_ignored() {
        let mut m = merge();
        // the fingers with one base joint, no velocity field: merged as zeros, no tick
        assert!(!m.update(&["finger", "base_x"], &[0.04, 1.0], &[], 0.0).unwrap());
        assert!(m
            .update(&["j2", "finger", "j1"], &[2.0, 0.04, 1.0], &[0.2, 0.0, 0.1], 0.5)
            .unwrap());
        assert_eq!(m.position(), &[1.0, 0.0, 0.0, 1.0, 2.0]);
        assert_eq!(m.velocity(), &[0.0, 0.0, 0.0, 0.1, 0.2]);
        assert_eq!(m.received(), &[0.0, f64::NEG_INFINITY, f64::NEG_INFINITY, 0.5, 0.5]);
        // owned names (a driver's message) find the same route as borrowed ones
        let owned = vec!["j2".to_string(), "finger".to_string(), "j1".to_string()];
        assert!(m.drives_tick(&owned) && !m.drives_tick(&["j1"]) && m.drives_tick(&["j1", "x", "j2"]));
        let route = m.route(&owned);
        assert_eq!((route.message_indices(), route.joint_indices()), (&[0, 2][..], &[4, 3][..]));
        // one joint's message leaves the others as they were; a non-finite value for a joint the
        // merge does not know is not its concern
        m.update(&["finger", "j1"], &[f64::NAN, 1.5], &[f64::NAN, 0.3], 0.6).unwrap();
        assert_eq!(m.position(), &[1.0, 0.0, 0.0, 1.5, 2.0]);
        assert_eq!(m.received()[3..], [0.6, 0.5]);
    }

    #[test]
    fn bad_input_is_an_error_naming_the_joints_and_changes_nothing() {
        let mut m = merge();
        m.update(&["j1", "j2", "base_x"], &[1.0, 2.0, 3.0], &[0.1, 0.2, 0.3], 0.0)
            .unwrap();
        let before = (m.position().to_vec(), m.velocity().to_vec(), m.received().to_vec());
        // names, positions, velocities, and what the error names
        let bad: [BadMessage; 5] = [
            (&["j1", "j2"], &[1.0], &[0.0, 0.0], "['j1', 'j2']"),
            (&["j1", "j2"], &[1.0, 2.0], &[0.0], "['j1', 'j2']"),
            (&["j1", "j2"], &[1.0, f64::NAN], &[0.0, 0.0], "non-finite value for ['j2']"),
            (&["j1", "j2"], &[1.0, f64::NAN], &[], "non-finite value for ['j2']"),
            (
                &["j1", "x", "base_y"],
                &[1.0, 2.0, 3.0],
                &[0.0, 0.0, f64::INFINITY],
                "for ['base_y']",
            ),
        ];
        for (names, position, velocity, named) in bad {
            let error = m.update(names, position, velocity, 1.0).unwrap_err().to_string();
            assert!(error.contains(named), "{error}");
        }
        assert_eq!((m.position().to_vec(), m.velocity().to_vec(), m.received().to_vec()), before);
        assert!(m.set(&[1, 2], &[0.5], &[0.0, 0.0], 1.0).is_err());
        assert!(m.set(&[1, 5], &[0.5, 0.1], &[0.0, 0.0], 1.0).is_err());
        assert!(m.set(&[1, 2], &[0.5, f64::NAN], &[0.0, 0.0], 1.0).is_err());
        assert_eq!((m.position().to_vec(), m.velocity().to_vec(), m.received().to_vec()), before);
    }

    #[test]
    fn each_joint_goes_stale_after_its_own_timeout() {
        let mut m = merge();
        assert!(!m.fresh(0.0), "never received: stale");
        m.update(&["j1", "j2", "base_x"], &[0.0; 3], &[], 0.0).unwrap();
        assert_eq!(m.stale(0.005).collect::<Vec<_>>(), ["base_y", "base_yaw"]);
        m.set(&[1, 2], &[0.5, 0.1], &[0.0, 0.0], 0.0).unwrap();
        assert!(m.fresh(0.005) && m.fresh(0.01) && m.stale(0.01).next().is_none());
        assert!(!m.fresh(0.0101));
        assert_eq!(m.stale(0.05).collect::<Vec<_>>(), ["j1", "j2"]);
        m.update(&["j1", "j2"], &[0.0; 2], &[], 0.05).unwrap();
        assert!(m.fresh(0.055) && !m.fresh(0.061));
        assert_eq!(
            m.stale(0.11).collect::<Vec<_>>(),
            ["base_x", "base_y", "base_yaw", "j1", "j2"]
        );
        let forever = JointMerge::new(vec!["a".into()], &[] as &[&str], vec![f64::INFINITY]).unwrap();
        assert!(forever.fresh(1e9), "an infinite timeout never goes stale, received or not");
    }

    #[test]
    fn routes_beyond_the_cache_still_merge_and_bad_set_ups_are_refused() {
        let mut m = merge();
        for k in 0..ROUTE_CACHE + 10 {
            let extra = format!("other{k}");
            let names = [extra.as_str(), "j2", "j1"];
            assert!(m.update(&names, &[9.0, k as f64, -(k as f64)], &[], k as f64).unwrap());
            assert_eq!(m.position()[3..], [-(k as f64), k as f64]);
        }
        assert_eq!(m.routes.len(), ROUTE_CACHE);
        let names = || ["a", "b"].map(String::from).to_vec();
        assert!(JointMerge::new(vec!["a".into(), "a".into()], &[] as &[&str], vec![0.1; 2]).is_err());
        assert!(JointMerge::new(names(), &["c"], vec![0.1; 2]).is_err());
        assert!(JointMerge::new(names(), &["a"], vec![0.1]).is_err());
        assert!(JointMerge::new(names(), &["a"], vec![0.1, f64::NAN]).is_err());
    }
}
