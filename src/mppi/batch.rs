//! The rows of a sampler's batch, each built on its own: the nominal, the zero sequence, the
//! task's guides, the best previous samples shifted in time, and fresh samples drawn from the
//! row's own random stream, so that a rollout's worker builds its row and a seed gives the same
//! batch on any number of threads.

use rand::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use super::guide::ServoGuidePlan;

/// log2 of the words of a row's random stream. A row draws a few words per value it holds, and a
/// batch holds at most 2^28 values (the rollouts' batch limit), so rows never overlap: 2^24 rows
/// of 2^40 words fit ChaCha's 2^68 words of one stream.
const ROW_STREAM_BITS: u32 = 40;

/// Value of a K × nu sequence at fractional index `s`, linearly interpolated, clamped at both ends.
pub fn interpolate(seq: &[f64], nu: usize, s: f64, out: &mut [f64]) {
    let k = seq.len() / nu;
    if k == 0 {
        out.fill(0.0);
        return;
    }
    let s = s.clamp(0.0, (k - 1) as f64);
    let i = s.floor() as usize;
    let j = (i + 1).min(k - 1);
    let a = s - i as f64;
    for d in 0..nu {
        out[d] = (1.0 - a) * seq[i * nu + d] + a * seq[j * nu + d];
    }
}

/// `out` = the K × nu sequence `seq` shifted forward by `steps` (fractional), padded with its
/// last value; a copy for `steps` ≤ 0.
pub(super) fn shifted_into(seq: &[f64], nu: usize, steps: f64, out: &mut [f64]) {
    if steps <= 0.0 {
        out.copy_from_slice(seq);
        return;
    }
    for (i, step) in out.chunks_exact_mut(nu).enumerate() {
        interpolate(seq, nu, i as f64 + steps, step);
    }
}

/// Shifts a K × nu sequence forward by `steps` (fractional) in place, padding with its last value.
pub(super) fn shift(seq: &mut [f64], nu: usize, steps: f64, scratch: &mut Vec<f64>) {
    if steps <= 0.0 {
        return;
    }
    scratch.clear();
    scratch.extend_from_slice(seq);
    shifted_into(scratch, nu, steps, seq);
}

/// The key of a sampler's random streams for `seed`.
pub(super) fn stream_key(seed: u64) -> [u8; 32] {
    ChaCha8Rng::seed_from_u64(seed).get_seed()
}

/// Everything the rows of one batch are built from (rows of K × nu, row-major).
pub(super) struct RowPlan<'a> {
    pub nu: usize,
    pub nominal: &'a [f64],
    /// M × K × nu sequences proposed by the task, rows 2 to M + 1, then the first P guides of a
    /// plan, integrated here.
    pub guides: &'a [f64],
    pub planned: Option<(&'a ServoGuidePlan, usize)>,
    /// The previous batch and its rows kept, best first, for the rows after the guides.
    pub previous: &'a [f64],
    pub kept: &'a [usize],
    /// Steps the kept rows move forward: the time between the two batches.
    pub kept_shift: f64,
    /// Standard deviation of each input's fresh noise, noise scale included.
    pub std: &'a [f64],
    /// Steps between independent noise values, linearly interpolated in between (1: white).
    pub interval: usize,
    pub lower: &'a [f64],
    pub upper: &'a [f64],
    pub key: [u8; 32],
    /// The batch's number since the sampler's seed was set: one random stream per batch.
    pub batch: u64,
}

impl RowPlan<'_> {
    /// Writes row `i` of the batch into `out`, projected onto the input bounds.
    pub fn fill(&self, i: usize, out: &mut [f64]) {
        let row = out.len();
        let given = 2 + self.guides.len() / row.max(1);
        let planned = given + self.planned.map_or(0, |(_, count)| count);
        match i {
            0 => out.copy_from_slice(self.nominal),
            1 => out.fill(0.0),
            i if i < given => out.copy_from_slice(&self.guides[(i - 2) * row..(i - 1) * row]),
            i if i < planned => {
                if let Some((plan, _)) = self.planned {
                    plan.write(i - given, out);
                }
            }
            i => match self.kept.get(i - planned) {
                Some(&kept) => shifted_into(&self.previous[kept * row..(kept + 1) * row], self.nu, self.kept_shift, out),
                None => self.draw(i, out),
            },
        }
        for step in out.chunks_exact_mut(self.nu) {
            for ((v, &lo), &hi) in step.iter_mut().zip(self.lower).zip(self.upper) {
                *v = v.clamp(lo, hi);
            }
        }
    }

    /// A fresh sample: the nominal plus noise, independent at every `interval`-th step (a knot)
    /// and linearly interpolated between knots, from row `i`'s own stream.
    fn draw(&self, i: usize, out: &mut [f64]) {
        let nu = self.nu;
        let mut rng = ChaCha8Rng::from_seed(self.key);
        rng.set_stream(self.batch);
        rng.set_word_pos((i as u128) << ROW_STREAM_BITS);
        let mut normals = |knot: &mut [f64]| knot.iter_mut().for_each(|e| *e = normal(&mut rng));
        let (mut here, mut next) = (vec![0.0; nu], vec![0.0; nu]);
        normals(&mut here);
        normals(&mut next);
        let interval = self.interval.max(1);
        for (s, (step, nominal)) in out.chunks_exact_mut(nu).zip(self.nominal.chunks_exact(nu)).enumerate() {
            let offset = s % interval;
            if offset == 0 && s > 0 {
                std::mem::swap(&mut here, &mut next);
                normals(&mut next);
            }
            let a = offset as f64 / interval as f64;
            for d in 0..nu {
                // On a knot (a = 0, every step of white noise) the interpolation is the knot.
                let e = if a == 0.0 {
                    here[d]
                } else {
                    (1.0 - a) * here[d] + a * next[d]
                };
                step[d] = nominal[d] + self.std[d] * e;
            }
        }
    }
}

fn normal(rng: &mut impl RngCore) -> f64 {
    StandardNormal.sample(rng)
}
