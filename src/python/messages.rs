//! Bindings of the bridge's serialized ROS 2 messages: bytes as rclpy's raw subscriptions deliver
//! them and as `Publisher.publish` sends them, stamps as integer nanoseconds.

use numpy::{PyArray1, PyReadonlyArrayDyn};
use pyo3::prelude::*;
use pyo3::types::PyBytes;

use super::convert::view;
use super::error::run;
use crate::bridge::messages::{self, Stamp};

const NS: i64 = 1_000_000_000;

/// The stamp of `ns` nanoseconds since the clock's epoch.
pub(crate) fn stamp_of(ns: i64) -> Stamp {
    Stamp {
        sec: ns.div_euclid(NS) as i32,
        nanosec: ns.rem_euclid(NS) as u32,
    }
}

pub(crate) fn nanoseconds(stamp: Stamp) -> i64 {
    i64::from(stamp.sec) * NS + i64::from(stamp.nanosec)
}

type DecodedJointState<'py> = (
    i64,
    String,
    Vec<String>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
);

/// A serialized sensor_msgs/JointState: (stamp in ns, frame_id, names, position, velocity, effort).
#[pyfunction]
pub fn decode_joint_state<'py>(py: Python<'py>, raw: &[u8]) -> PyResult<DecodedJointState<'py>> {
    let m = run(|| messages::decode_joint_state(raw))?;
    Ok((
        nanoseconds(m.stamp()),
        m.frame_id().to_owned(),
        m.name.clone(),
        PyArray1::from_slice(py, &m.position),
        PyArray1::from_slice(py, &m.velocity),
        PyArray1::from_slice(py, &m.effort),
    ))
}

/// Serializes a sensor_msgs/JointState (stamp in ns; velocity and effort may be empty).
#[pyfunction]
#[pyo3(signature = (stamp_ns, frame_id, names, position, velocity, effort))]
pub fn encode_joint_state<'py>(
    py: Python<'py>,
    stamp_ns: i64,
    frame_id: &str,
    names: Vec<String>,
    position: PyReadonlyArrayDyn<'py, f64>,
    velocity: PyReadonlyArrayDyn<'py, f64>,
    effort: PyReadonlyArrayDyn<'py, f64>,
) -> PyResult<Bound<'py, PyBytes>> {
    let mut out = Vec::new();
    run(|| {
        let (p, v, e) = (
            view("position", &position, &[-1])?,
            view("velocity", &velocity, &[-1])?,
            view("effort", &effort, &[-1])?,
        );
        messages::encode_joint_state(&mut out, stamp_of(stamp_ns), frame_id, &names, p, v, e)
    })?;
    Ok(PyBytes::new(py, &out))
}

/// A serialized std_msgs/Float64MultiArray: (data, layout.data_offset).
#[pyfunction]
pub fn decode_float64_array<'py>(py: Python<'py>, raw: &[u8]) -> PyResult<(Bound<'py, PyArray1<f64>>, u32)> {
    let (data, offset) = run(|| messages::decode_float64_array(raw))?;
    Ok((PyArray1::from_vec(py, data), offset))
}

/// Serializes a flat std_msgs/Float64MultiArray.
#[pyfunction]
pub fn encode_float64_array<'py>(
    py: Python<'py>,
    data: PyReadonlyArrayDyn<'py, f64>,
    data_offset: u32,
) -> PyResult<Bound<'py, PyBytes>> {
    let mut out = Vec::new();
    run(|| messages::encode_float64_array(&mut out, view("data", &data, &[-1])?, data_offset))?;
    Ok(PyBytes::new(py, &out))
}

/// A serialized geometry_msgs/Twist (or TwistStamped when `stamped`): (linear (3), angular (3),
/// stamp in ns or None).
#[pyfunction]
pub fn decode_twist(raw: &[u8], stamped: bool) -> PyResult<([f64; 3], [f64; 3], Option<i64>)> {
    let t = run(|| messages::decode_twist(raw, stamped))?;
    Ok((t.linear, t.angular, t.stamp.map(nanoseconds)))
}

/// Serializes a geometry_msgs/Twist, or a TwistStamped in `frame_id` when `stamp_ns` is given.
#[pyfunction]
#[pyo3(signature = (linear, angular, stamp_ns=None, frame_id=""))]
pub fn encode_twist<'py>(
    py: Python<'py>,
    linear: [f64; 3],
    angular: [f64; 3],
    stamp_ns: Option<i64>,
    frame_id: &str,
) -> PyResult<Bound<'py, PyBytes>> {
    let mut out = Vec::new();
    run(|| messages::encode_twist(&mut out, linear, angular, stamp_ns.map(stamp_of), frame_id))?;
    Ok(PyBytes::new(py, &out))
}
