//! The ROS 2 messages the bridge's 1 kHz path reads and writes, in their serialized form (the
//! 4-byte encapsulation header, then OMG CDR, as rmw hands them to a raw subscription): joint
//! states, the arm's `Float64MultiArray` command or `JointTrajectory`, the base's `Twist` or
//! `TwistStamped`. The layouts follow the messages' definitions in sensor_msgs, std_msgs,
//! trajectory_msgs and geometry_msgs.

use byteorder::{BigEndian, LittleEndian};
use serde::{Deserialize, Serialize};

use crate::error::{Result, SabreError};

/// The encapsulation header of little-endian plain CDR (what every ROS 2 middleware writes on x86
/// and ARM); big-endian CDR (`00 00`) is read too.
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// builtin_interfaces/Time.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Stamp {
    pub sec: i32,
    pub nanosec: u32,
}

impl Stamp {
    /// Seconds since the epoch of the stamp's clock.
    pub fn seconds(&self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }
    /// Nanoseconds since the epoch of the stamp's clock, exactly.
    pub fn nanoseconds(&self) -> i64 {
        i64::from(self.sec) * 1_000_000_000 + i64::from(self.nanosec)
    }
    /// Seconds from `earlier` to this stamp, exact to the nanosecond (the difference of two
    /// [`Self::seconds`] near today's epoch time loses a tenth of a microsecond).
    pub fn seconds_since(&self, earlier: &Stamp) -> f64 {
        (self.nanoseconds() - earlier.nanoseconds()) as f64 * 1e-9
    }
    /// The stamp of `seconds` (nanoseconds rounded, carried into the seconds at 1e9).
    pub fn from_seconds(seconds: f64) -> Self {
        let mut sec = seconds.floor();
        let mut nanosec = ((seconds - sec) * 1e9).round();
        if nanosec >= 1e9 {
            sec += 1.0;
            nanosec -= 1e9;
        }
        Self {
            sec: sec as i32,
            nanosec: nanosec as u32,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
struct Header<'a> {
    stamp: Stamp,
    frame_id: &'a str,
}

/// A header as read (the CDR reader hands out owned strings).
#[derive(Debug, Clone, PartialEq, Deserialize)]
struct HeaderIn {
    stamp: Stamp,
    frame_id: String,
}

/// sensor_msgs/JointState.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct JointState {
    header: HeaderIn,
    pub name: Vec<String>,
    pub position: Vec<f64>,
    pub velocity: Vec<f64>,
    pub effort: Vec<f64>,
}

impl JointState {
    pub fn stamp(&self) -> Stamp {
        self.header.stamp
    }
    pub fn frame_id(&self) -> &str {
        &self.header.frame_id
    }
}

#[derive(Serialize)]
struct JointStateOut<'a, S: Serialize> {
    header: Header<'a>,
    name: &'a [S],
    position: &'a [f64],
    velocity: &'a [f64],
    effort: &'a [f64],
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct MultiArrayDimension {
    label: String,
    size: u32,
    stride: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct MultiArrayLayout {
    dim: Vec<MultiArrayDimension>,
    data_offset: u32,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
struct Float64MultiArray {
    layout: MultiArrayLayout,
    data: Vec<f64>,
}

#[derive(Serialize)]
struct Float64MultiArrayOut<'a> {
    layout: MultiArrayLayout,
    data: &'a [f64],
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
struct Vector3 {
    x: f64,
    y: f64,
    z: f64,
}

#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
struct Twist {
    linear: Vector3,
    angular: Vector3,
}

#[derive(Serialize)]
struct TwistStampedOut<'a> {
    header: Header<'a>,
    twist: Twist,
}

#[derive(Deserialize)]
struct TwistStamped {
    header: HeaderIn,
    twist: Twist,
}

#[derive(Deserialize)]
struct Wrench {
    force: Vector3,
    torque: Vector3,
}

#[derive(Deserialize)]
struct WrenchStamped {
    header: HeaderIn,
    wrench: Wrench,
}

/// A geometry_msgs/WrenchStamped as read: [f; m] and its header's frame and stamp.
#[derive(Debug, Clone, PartialEq)]
pub struct WrenchValue {
    pub wrench: [f64; 6],
    pub frame_id: String,
    pub stamp: Stamp,
}

/// A base twist: (vx, vy, vz) and (ωx, ωy, ωz), with the header of a `TwistStamped`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TwistValue {
    pub linear: [f64; 3],
    pub angular: [f64; 3],
    pub stamp: Option<Stamp>,
}

/// builtin_interfaces/Duration.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
struct DurationMsg {
    sec: i32,
    nanosec: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct JointTrajectoryPointMsg {
    positions: Vec<f64>,
    velocities: Vec<f64>,
    accelerations: Vec<f64>,
    effort: Vec<f64>,
    time_from_start: DurationMsg,
}

#[derive(Deserialize)]
struct JointTrajectoryIn {
    header: HeaderIn,
    joint_names: Vec<String>,
    points: Vec<JointTrajectoryPointMsg>,
}

#[derive(Serialize)]
struct JointTrajectoryOut<'a, S: Serialize> {
    header: Header<'a>,
    joint_names: &'a [S],
    points: Vec<JointTrajectoryPointMsg>,
}

/// A trajectory_msgs/JointTrajectoryPoint: its time from the trajectory's start (s) and its
/// positions, velocities and accelerations (each empty or one per joint).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TrajectoryPoint {
    pub time_from_start: f64,
    pub positions: Vec<f64>,
    pub velocities: Vec<f64>,
    pub accelerations: Vec<f64>,
}

/// A trajectory_msgs/JointTrajectory: its stamp (zero: start on arrival), joint names and points.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TrajectoryValue {
    pub stamp: Stamp,
    pub joint_names: Vec<String>,
    pub points: Vec<TrajectoryPoint>,
}

/// A serialized trajectory_msgs/JointTrajectory.
pub fn decode_joint_trajectory(raw: &[u8]) -> Result<TrajectoryValue> {
    let m: JointTrajectoryIn = decode("JointTrajectory", raw)?;
    let points = m
        .points
        .into_iter()
        .map(|p| TrajectoryPoint {
            time_from_start: f64::from(p.time_from_start.sec) + f64::from(p.time_from_start.nanosec) * 1e-9,
            positions: p.positions,
            velocities: p.velocities,
            accelerations: p.accelerations,
        })
        .collect();
    Ok(TrajectoryValue {
        stamp: m.header.stamp,
        joint_names: m.joint_names,
        points,
    })
}

/// Serializes a trajectory_msgs/JointTrajectory into `out` (times from the start rounded to ns).
pub fn encode_joint_trajectory<S: Serialize>(
    out: &mut Vec<u8>,
    stamp: Stamp,
    joint_names: &[S],
    points: &[TrajectoryPoint],
) -> Result<()> {
    let points = points
        .iter()
        .map(|p| {
            let t = Stamp::from_seconds(p.time_from_start);
            JointTrajectoryPointMsg {
                positions: p.positions.clone(),
                velocities: p.velocities.clone(),
                accelerations: p.accelerations.clone(),
                effort: Vec::new(),
                time_from_start: DurationMsg {
                    sec: t.sec,
                    nanosec: t.nanosec,
                },
            }
        })
        .collect();
    let header = Header { stamp, frame_id: "" };
    encode(
        "JointTrajectory",
        &JointTrajectoryOut {
            header,
            joint_names,
            points,
        },
        out,
    )
}

fn malformed(what: &str, detail: impl std::fmt::Display) -> SabreError {
    SabreError::invalid(what, format!("malformed serialized message: {detail}"))
}

/// The CDR payload of a serialized message and whether it is little-endian.
fn payload<'a>(what: &str, raw: &'a [u8]) -> Result<(&'a [u8], bool)> {
    if raw.len() < 4 {
        return Err(malformed(what, format!("{} bytes, shorter than its header", raw.len())));
    }
    match raw[1] {
        0x01 => Ok((&raw[4..], true)),
        0x00 => Ok((&raw[4..], false)),
        kind => Err(malformed(what, format!("encapsulation {kind:#04x} is not plain CDR"))),
    }
}

fn decode<T: for<'de> Deserialize<'de>>(what: &str, raw: &[u8]) -> Result<T> {
    let (body, little) = payload(what, raw)?;
    let decoded = if little {
        cdr_encoding::from_bytes::<T, LittleEndian>(body)
    } else {
        cdr_encoding::from_bytes::<T, BigEndian>(body)
    };
    decoded.map(|(value, _)| value).map_err(|e| malformed(what, e))
}

/// Writes `value` as a serialized message (header and little-endian CDR) into `out`, replacing
/// its contents; the buffer's capacity is reused.
fn encode<T: Serialize>(what: &str, value: &T, out: &mut Vec<u8>) -> Result<()> {
    out.clear();
    out.extend_from_slice(&CDR_LE);
    cdr_encoding::to_writer::<T, LittleEndian, _>(&mut *out, value).map_err(|e| malformed(what, e))?;
    // rmw pads a message to a multiple of four bytes.
    while !out.len().is_multiple_of(4) {
        out.push(0);
    }
    Ok(())
}

/// A serialized sensor_msgs/JointState.
pub fn decode_joint_state(raw: &[u8]) -> Result<JointState> {
    decode("joint state", raw)
}

/// Serializes a sensor_msgs/JointState into `out`.
pub fn encode_joint_state<S: Serialize>(
    out: &mut Vec<u8>,
    stamp: Stamp,
    frame_id: &str,
    name: &[S],
    position: &[f64],
    velocity: &[f64],
    effort: &[f64],
) -> Result<()> {
    let header = Header { stamp, frame_id };
    let message = JointStateOut {
        header,
        name,
        position,
        velocity,
        effort,
    };
    encode("joint state", &message, out)
}

/// A serialized std_msgs/Float64MultiArray: (data, layout.data_offset).
pub fn decode_float64_array(raw: &[u8]) -> Result<(Vec<f64>, u32)> {
    let message: Float64MultiArray = decode("Float64MultiArray", raw)?;
    Ok((message.data, message.layout.data_offset))
}

/// Serializes a std_msgs/Float64MultiArray without dimensions (a flat vector, as ros2_control's
/// forward command controllers take it) into `out`.
pub fn encode_float64_array(out: &mut Vec<u8>, data: &[f64], data_offset: u32) -> Result<()> {
    let layout = MultiArrayLayout {
        dim: Vec::new(),
        data_offset,
    };
    encode("Float64MultiArray", &Float64MultiArrayOut { layout, data }, out)
}

/// A serialized geometry_msgs/Twist, or TwistStamped when `stamped`.
pub fn decode_twist(raw: &[u8], stamped: bool) -> Result<TwistValue> {
    let (twist, stamp) = if stamped {
        let m: TwistStamped = decode("TwistStamped", raw)?;
        (m.twist, Some(m.header.stamp))
    } else {
        (decode::<Twist>("Twist", raw)?, None)
    };
    let (l, a) = (twist.linear, twist.angular);
    Ok(TwistValue {
        linear: [l.x, l.y, l.z],
        angular: [a.x, a.y, a.z],
        stamp,
    })
}

/// A serialized geometry_msgs/WrenchStamped.
pub fn decode_wrench(raw: &[u8]) -> Result<WrenchValue> {
    let m: WrenchStamped = decode("WrenchStamped", raw)?;
    let (f, t) = (m.wrench.force, m.wrench.torque);
    Ok(WrenchValue {
        wrench: [f.x, f.y, f.z, t.x, t.y, t.z],
        frame_id: m.header.frame_id,
        stamp: m.header.stamp,
    })
}

/// Serializes a geometry_msgs/Twist, or a TwistStamped in `frame_id` when `stamp` is given, into `out`.
pub fn encode_twist(out: &mut Vec<u8>, linear: [f64; 3], angular: [f64; 3], stamp: Option<Stamp>, frame_id: &str) -> Result<()> {
    let v = |a: [f64; 3]| Vector3 {
        x: a[0],
        y: a[1],
        z: a[2],
    };
    let twist = Twist {
        linear: v(linear),
        angular: v(angular),
    };
    match stamp {
        Some(stamp) => {
            let header = Header { stamp, frame_id };
            encode("TwistStamped", &TwistStampedOut { header, twist }, out)
        }
        None => encode("Twist", &twist, out),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A JointState as rclpy serialized it (stamp 12 s 345 ns, frame "f", names ["a", "bc"],
    /// position [1.0, -2.5], velocity [0.5, 0.0], no effort), with the bytes it left in the
    /// padding (here "pp") written as zeros: `rclpy.serialization.serialize_message`.
    const RCLPY_JOINT_STATE: &str = "000100000c00000059010000020000006600pppp02000000020000006100pppp03000000626300pp\
                                     02000000000000000000f03f00000000000004c002000000pppppppp000000000000e03f00000000\
                                     0000000000000000pppppppp";

    fn reference_joint_state() -> Vec<u8> {
        let hex: String = RCLPY_JOINT_STATE.replace("pp", "00").split_whitespace().collect();
        (0..hex.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
            .collect()
    }

    #[test]
    fn joint_state_reads_and_writes_the_cdr_layout() {
        let raw = reference_joint_state();
        let js = decode_joint_state(&raw).unwrap();
        assert_eq!(js.stamp(), Stamp { sec: 12, nanosec: 345 });
        assert_eq!(js.frame_id(), "f");
        assert_eq!(js.name, vec!["a", "bc"]);
        assert_eq!(js.position, vec![1.0, -2.5]);
        assert_eq!(js.velocity, vec![0.5, 0.0]);
        assert!(js.effort.is_empty());
        let mut out = Vec::new();
        encode_joint_state(&mut out, js.stamp(), "f", &["a", "bc"], &[1.0, -2.5], &[0.5, 0.0], &[]).unwrap();
        // the same bytes; rclpy pads the whole to 8 bytes, this to 4
        assert_eq!(out[..], raw[..out.len()]);
        assert_eq!(raw.len() - out.len(), 4);
    }

    #[test]
    fn float_array_and_twists_round_trip() {
        let mut out = Vec::new();
        encode_float64_array(&mut out, &[1.0, 2.0, 3.0], 77).unwrap();
        // layout: no dims (4), data_offset (4), count (4), padding to 8 (4), 3 doubles
        assert_eq!(out.len(), 4 + 16 + 24);
        assert_eq!(decode_float64_array(&out).unwrap(), (vec![1.0, 2.0, 3.0], 77));
        encode_twist(&mut out, [0.1, 0.2, 0.0], [0.0, 0.0, 0.3], None, "").unwrap();
        assert_eq!(out.len(), 4 + 48);
        let t = decode_twist(&out, false).unwrap();
        assert_eq!((t.linear, t.angular, t.stamp), ([0.1, 0.2, 0.0], [0.0, 0.0, 0.3], None));
        let stamp = Stamp { sec: 3, nanosec: 9 };
        encode_twist(&mut out, [0.1, 0.2, 0.0], [0.0, 0.0, 0.3], Some(stamp), "base_link").unwrap();
        let t = decode_twist(&out, true).unwrap();
        assert_eq!((t.linear, t.stamp), ([0.1, 0.2, 0.0], Some(stamp)));
    }

    #[test]
    fn big_endian_cdr_is_read_too() {
        // a Float64MultiArray in big-endian CDR, by hand: no dimensions, data_offset 77, one double
        // (1.5) after the padding to its 8-byte alignment
        let raw: Vec<u8> = [
            [0x00, 0x00, 0x00, 0x00],
            [0x00, 0x00, 0x00, 0x00],
            [0x00, 0x00, 0x00, 0x4d],
            [0x00, 0x00, 0x00, 0x01],
            [0x00, 0x00, 0x00, 0x00],
            [0x3f, 0xf8, 0x00, 0x00],
            [0x00, 0x00, 0x00, 0x00],
        ]
        .concat();
        assert_eq!(decode_float64_array(&raw).unwrap(), (vec![1.5], 77));
    }

    #[test]
    fn truncated_or_foreign_messages_are_errors() {
        let raw = reference_joint_state();
        assert!(decode_joint_state(&raw[..20]).is_err());
        assert!(decode_joint_state(&raw[..2]).is_err());
        let mut xcdr = raw.clone();
        xcdr[1] = 0x07;
        assert!(decode_joint_state(&xcdr).is_err());
    }

    #[test]
    fn stamps_convert_to_seconds_and_back() {
        let s = Stamp::from_seconds(1.999_999_999_7);
        assert_eq!(s, Stamp { sec: 2, nanosec: 0 });
        assert_eq!(
            Stamp::from_seconds(5.25),
            Stamp {
                sec: 5,
                nanosec: 250_000_000
            }
        );
        assert!(
            (Stamp {
                sec: 5,
                nanosec: 250_000_000
            }
            .seconds()
                - 5.25)
                .abs()
                < 1e-12
        );
    }
}
