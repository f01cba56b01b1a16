"""Hand-made mutants of the cascade's core (its tick, plans, τ_ext conditioning, low-pass, command shaping): each is
applied to a checkout, the Rust tests that cover it run, and the mutant is put back; prints killed or SURVIVED.

    python tools/cascade_mutants.py <a scratch checkout>   # edits files there while it runs; never this one
"""

import pathlib
import sys

from mutants import Mutant, run

#: (file, code, its mutant, what the mutant breaks)
MUTANTS = [
    (
        "src/control/cascade.rs",
        "let passivity = tank.as_ref().map(|tank| (tau_ext, tank.energy()));",
        "let passivity: Option<(&[f64], f64)> = None;",
        "the passivity row dropped",
    ),
    (
        "src/control/cascade.rs",
        "Some(tank.step(tau_ext, &out.command, dt)?)",
        "Some(tank.step(tau_ext, &out.reference, dt)?)",
        "the tank booked against the reference",
    ),
    (
        "src/control/cascade.rs",
        "let measured = -EnergyTank::power(tau_ext, &out.reference);",
        "let measured = EnergyTank::power(tau_ext, &out.reference);",
        "the refill's measured power sign",
    ),
    (
        "src/control/cascade.rs",
        "t >= at - TAKEOVER_TOLERANCE",
        "t >= at - 0.0 * TAKEOVER_TOLERANCE",
        "takeover without the tolerance",
    ),
    (
        "src/control/cascade.rs",
        "Some(at) if self.plan.is_some() => self.pending = Some((handed, at)),",
        "Some(at) if self.plan.is_some() => { if self.pending.is_none() { self.pending = Some((handed, at)) } }",
        "a newer waiting plan does not replace the older",
    ),
    (
        "src/control/cascade.rs",
        "let floor = plan.gain_inertia_floor().unwrap_or(controller.config().gain_inertia_floor);",
        "let floor = controller.config().gain_inertia_floor;",
        "the plan's gain floor ignored",
    ),
    (
        "src/control/cascade.rs",
        "if self.plan.is_none() && self.pending.is_none() {",
        "if false {",
        "no-plan check dropped before the reading",
    ),
    (
        "src/control/cascade.rs",
        "if record_every > 0 && step % record_every == 0 {",
        "if record_every > 0 && step % record_every == 1 % record_every.max(2) {",
        "recording offset",
    ),
    (
        "src/control/tau_ext.rs",
        "let fresh = self.timeout.is_none_or(|timeout| now - self.received <= timeout);",
        "let fresh = true;",
        "staleness never detected",
    ),
    ("src/control/tau_ext.rs", "self.readings += 1;", "", "readings not counted"),
    ("src/low_pass.rs", "1.0 - (-2.0 * PI * cutoff * dt).exp()", "1.0 - (-PI * cutoff * dt).exp()", "the blend's 2π"),
    (
        "src/low_pass.rs",
        "            _ => {\n                self.value.copy_from_slice(sample);\n                self.started = true;",
        "            _ => {\n                self.value.copy_from_slice(sample);",
        "the first sample never starts the filter",
    ),
    (
        "src/control/shaping.rs",
        "self.base_target = [c * vx + s * vy, -s * vx + c * vy, command[iyaw]];",
        "self.base_target = [c * vx + s * vy, s * vx + c * vy, command[iyaw]];",
        "the base rotation's sign",
    ),
    (
        "src/control/shaping.rs",
        ".all(|&i| i < nq && !std::mem::replace(&mut seen[i], true));",
        ".all(|&i| i < nq);",
        "duplicate joints accepted",
    ),
    ("src/control/cascade.rs", "        self.ticks += 1;\n        Ok(&self.out)", "        Ok(&self.out)", "ticks not counted"),
]
#: The Rust tests that cover these files (the cascade, τ_ext, the low-pass, the shaping; the loops on the plant).
COMMAND = (
    "cargo test --profile quick-release --lib -- control:: low_pass"
    " && cargo test --profile quick-release --test inner_loop --test safety_loop"
)
if __name__ == "__main__":
    run(pathlib.Path(sys.argv[1]).resolve(), [Mutant(*m, tests=COMMAND) for m in MUTANTS], timeout=600.0)
