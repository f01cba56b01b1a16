//! The cascade's command shaping for a robot's command interface: its command (sabre's joints) split
//! into the arm's joints and the base's twist in the base frame, through the rate-limited gate
//! ([`CommandGate`]) that follows it, ramps to zero instead, or ramps down once no state comes.

use super::command_stream::{Command, CommandGate};
use crate::error::{ensure_finite, Result, SabreError};

/// The error of a cascade asked to shape commands before it was given a [`CommandShaping`].
pub fn shapes_no_commands() -> SabreError {
    SabreError::invalid(
        "command shaping",
        "this cascade shapes no commands: give it a command shaping first",
    )
}

/// How a command of sabre's joints reaches the robot's command streams (see the module).
#[derive(Debug, Clone)]
pub struct CommandShaping {
    gate: CommandGate,
    arm_index: Vec<usize>,
    base_index: Option<[usize; 3]>,
    arm_target: Vec<f64>,
    base_target: [f64; 3],
}

impl CommandShaping {
    /// The shaping of a robot of `nq` joints: the arm command carries sabre's joints `arm_index` in
    /// its order, the base command the joints `base_index` (x, y, yaw; None: a fixed base), through
    /// `gate`, whose limiters must match (the arm's length, a base limiter exactly with a base).
    pub fn new(gate: CommandGate, arm_index: Vec<usize>, base_index: Option<[usize; 3]>, nq: usize) -> Result<Self> {
        let na = gate.shaper().arm().len();
        let mut seen = vec![false; nq];
        let distinct = arm_index
            .iter()
            .chain(base_index.iter().flatten())
            .all(|&i| i < nq && !std::mem::replace(&mut seen[i], true));
        if arm_index.len() != na || !distinct {
            return Err(SabreError::invalid(
                "arm_index",
                format!("needs {na} distinct joints of {nq} (none of the base's), got {arm_index:?}"),
            ));
        }
        if base_index.is_some() != gate.shaper().base().is_some() {
            return Err(SabreError::invalid(
                "base_index",
                "a base command needs the base's three joints and a base limiter, a fixed base neither",
            ));
        }
        Ok(Self {
            gate,
            arm_target: vec![0.0; na],
            arm_index,
            base_index,
            base_target: [0.0; 3],
        })
    }

    pub fn gate(&self) -> &CommandGate {
        &self.gate
    }
    /// The gate, for its watchdog and a shutdown's ramp.
    pub fn gate_mut(&mut self) -> &mut CommandGate {
        &mut self.gate
    }
    pub fn arm_index(&self) -> &[usize] {
        &self.arm_index
    }
    pub fn base_index(&self) -> Option<[usize; 3]> {
        self.base_index
    }

    /// The gate's step at `now` toward `command` (nq, in sabre's joints; the base's in world rates,
    /// turned into the base frame at the measured state `x`'s yaw). Errors: a command of the wrong
    /// length or a non-finite one; nothing changes then.
    pub fn follow(&mut self, now: f64, command: &[f64], x: &[f64]) -> Result<&Command> {
        ensure_finite("command", command)?;
        if self
            .arm_index
            .iter()
            .chain(self.base_index.iter().flatten())
            .any(|&i| i >= command.len() || i >= x.len())
        {
            return Err(SabreError::invalid("command", "does not carry the commanded joints"));
        }
        for (target, &i) in self.arm_target.iter_mut().zip(&self.arm_index) {
            *target = command[i];
        }
        if let Some([ix, iy, iyaw]) = self.base_index {
            // world rates → the base frame's twist (vx, vy, ωz)
            let (c, s) = (x[iyaw].cos(), x[iyaw].sin());
            let (vx, vy) = (command[ix], command[iy]);
            self.base_target = [c * vx + s * vy, -s * vx + c * vy, command[iyaw]];
        }
        let base = self.base_index.map(|_| self.base_target.as_slice());
        self.gate.on_tick(now, Some(&self.arm_target), base)
    }

    /// A step of the ramp to zero at `now` (a state answered without following the plan). A ramp is
    /// never held for the state timeout: without a state it goes on two periods later
    /// ([`CommandGate::forbid_hold`]), so that a stop never waits.
    pub fn stop(&mut self, now: f64) -> Result<&Command> {
        self.gate.on_tick(now, None, None)?;
        self.gate.forbid_hold();
        Ok(self.gate.command())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::command_stream::CommandShaper;
    use crate::control::RateLimiter;

    /// Limits loose enough that one step reaches any target within them.
    fn limiter(n: usize) -> RateLimiter {
        RateLimiter::new(vec![10.0; n], vec![1e6; n], vec![1e9; n], 0.001).unwrap()
    }

    fn gate(with_base: bool) -> CommandGate {
        let base = with_base.then(|| limiter(3));
        CommandGate::new(CommandShaper::new(limiter(2), base, 1), 0.05).unwrap()
    }

    #[test]
    fn the_arm_takes_its_joints_and_the_base_its_world_rates_in_its_own_frame() {
        // joints: base x, y, yaw (0, 1, 2), arm (3, 4); the base turned by 90°
        let mut shaping = CommandShaping::new(gate(true), vec![4, 3], Some([0, 1, 2]), 5).unwrap();
        let mut x = vec![0.0; 10];
        x[2] = std::f64::consts::FRAC_PI_2;
        let command = [1.0, 0.0, 0.3, 0.2, -0.1];
        let out = shaping.follow(0.0, &command, &x).unwrap().clone();
        assert!(
            out.arm.iter().zip([-0.1, 0.2]).all(|(a, e)| (a - e).abs() < 1e-9),
            "{:?}",
            out.arm
        );
        // 1 m/s along world x is along the base's −y once the base faces world +y
        let expected = [0.0, -1.0, 0.3];
        assert!(
            out.base_due && out.base.iter().zip(expected).all(|(b, e)| (b - e).abs() < 1e-9),
            "{:?}",
            out.base
        );
        let stop = shaping.stop(0.001).unwrap();
        assert!(
            stop.arm.iter().all(|a| a.abs() < 0.2),
            "a ramp step toward zero: {:?}",
            stop.arm
        );
        assert!(shaping.follow(0.002, &[f64::NAN; 5], &x).is_err());
        assert!(shaping.follow(0.002, &command[..3], &x).is_err());
    }

    #[test]
    fn a_shaping_refuses_joints_the_gate_or_the_robot_cannot_carry() {
        let invalid = |r: Result<CommandShaping>| matches!(r, Err(SabreError::InvalidValue { .. }));
        assert!(
            invalid(CommandShaping::new(gate(false), vec![0], None, 5)),
            "two arm limiters, one joint"
        );
        assert!(
            invalid(CommandShaping::new(gate(false), vec![0, 0], None, 5)),
            "a joint twice"
        );
        assert!(
            invalid(CommandShaping::new(gate(false), vec![0, 7], None, 5)),
            "past the robot"
        );
        assert!(
            invalid(CommandShaping::new(gate(true), vec![3, 4], None, 5)),
            "a base limiter, no base"
        );
        assert!(
            invalid(CommandShaping::new(gate(false), vec![3, 4], Some([0, 1, 2]), 5)),
            "a base, no limiter"
        );
        assert!(
            invalid(CommandShaping::new(gate(true), vec![2, 4], Some([0, 1, 2]), 5)),
            "yaw in the arm"
        );
        assert!(CommandShaping::new(gate(true), vec![3, 4], Some([0, 1, 2]), 5).is_ok());
    }
}
