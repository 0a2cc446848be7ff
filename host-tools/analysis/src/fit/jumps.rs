//! Where the needle's velocity jumps (a start, a stop, a stroke reversed at
//! speed) and by how much, from the encoder trace alone: the impulses a
//! mass on the load cell turns into one-sample force pulses.
//!
//! The force law's own velocity is the wrong signal for this: it is built
//! to say *whether* the needle slides (so it rests on a slow turn of an
//! oscillation for a few samples and then jumps), and any such jump of
//! 1 mm/s at 500 Hz is a 75 mN pulse at 0.15 kg. Here a jump is told from
//! a smooth change by Richardson's trick on two window lengths, and put at
//! its sample by where the straight motions either side of it meet.

/// Velocity differences over `k` samples either side of the gap between
/// samples i − 1 and i: ahead from x[i], back up to x[i − 1], each over
/// its own time span (a rig's clock jitters, and loses samples).
fn contrast(t: &[f64], x: &[f64], i: usize, k: usize) -> f64 {
    let ahead = (x[i + k] - x[i]) / (t[i + k] - t[i]).max(1e-12);
    let back = (x[i - 1] - x[i - 1 - k]) / (t[i - 1] - t[i - 1 - k]).max(1e-12);
    ahead - back
}

/// Least-squares line through samples `from..to` (exclusive): (slope,
/// position at t = 0).
fn line(t: &[f64], x: &[f64], from: usize, to: usize) -> (f64, f64) {
    let n = (to - from) as f64;
    let (mt, mx) = (
        t[from..to].iter().sum::<f64>() / n,
        x[from..to].iter().sum::<f64>() / n,
    );
    let (mut stx, mut stt) = (0.0, 0.0);
    for j in from..to {
        stx += (t[j] - mt) * (x[j] - mx);
        stt += (t[j] - mt) * (t[j] - mt);
    }
    let slope = stx / stt.max(1e-300);
    (slope, mx - slope * mt)
}

/// A jump of the velocity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Jump {
    /// When it happened, s (between two samples).
    pub t_s: f64,
    /// Its uncertainty, s (one standard deviation).
    pub sd_s: f64,
    /// The first sample after it, where a sampled force shows it.
    pub index: usize,
    pub dv_mps: f64,
}

impl Jump {
    /// How likely the jump fell before sample `index − 1`, between it and
    /// `index`, or after `index` (so a sampled force shows it one sample
    /// early, on time, or late). A jump estimated a hundredth of a sample
    /// from a sample time is on either side of it.
    pub fn landing(&self, t: &[f64]) -> [f64; 3] {
        let below = |j: usize| {
            if self.sd_s > 0.0 {
                normal_cdf((t[j] - self.t_s) / self.sd_s)
            } else {
                f64::from(u8::from(t[j] >= self.t_s))
            }
        };
        let early = below(self.index - 1);
        let late = 1.0 - below(self.index);
        [early, 1.0 - early - late, late]
    }
}

/// Standard normal CDF, by the logistic approximation (within 0.01; the
/// uncertainty it weighs is itself a rough figure).
pub(crate) fn normal_cdf(z: f64) -> f64 {
    // Past z = 22 it is 1 to the last bit (e^(−37.4) is under half an ulp
    // of 1): no exp, which was most of a moved model's time a sample.
    if z > 22.0 {
        return 1.0;
    }
    1.0 / (1.0 + (-1.702 * z).exp())
}

/// The velocity jumps of the trace, over windows of `k` samples, of at
/// least `least_mps`, read by an encoder of resolution `step_m`.
///
/// A smooth acceleration a gives contrasts a·(k + 1)·dt over k and
/// a·(2k + 1)·dt over 2k, a jump Δv gives Δv over both; so
/// ((2k + 1)·c_k − (k + 1)·c_2k)/k is the jump alone. A jump between
/// samples i − 1 and i lands on i (the first sample after it), found where
/// the lines fitted to the motion either side cross.
pub fn velocity_steps(t: &[f64], x: &[f64], k: usize, least_mps: f64, step_m: f64) -> Vec<Jump> {
    let n = x.len();
    let mut steps = Vec::new();
    if k == 0 || n < 4 * k + 4 {
        return steps;
    }
    // Up to 2k samples either side of a jump, the long window sees it and
    // the short one does not, which the combination turns into a phantom
    // jump the other way; the short window's own contrast rules it out.
    let jump = |i: usize| {
        let (ck, c2k) = (contrast(t, x, i, k), contrast(t, x, i, 2 * k));
        let j = ((2 * k + 1) as f64 * ck - (k + 1) as f64 * c2k) / k as f64;
        if ck.abs() >= least_mps && j * ck > 0.0 {
            j.abs()
        } else {
            0.0
        }
    };
    let mut i = 2 * k + 1;
    while i + 2 * k < n {
        if jump(i) < least_mps {
            i += 1;
            continue;
        }
        // The strongest sample of this run of large jumps.
        let mut best = i;
        let mut j = i;
        while j + 2 * k < n && jump(j) >= least_mps {
            if jump(j) > jump(best) {
                best = j;
            }
            j += 1;
        }
        steps.extend(crossing(t, x, best, k, step_m));
        i = j.max(best + k);
    }
    steps
}

/// Where the straight motions before and after sample `i` meet (the
/// sample that time falls on or before) and the jump of their slopes. The
/// samples next to the gap are left out of both lines: one of them mixes
/// both motions.
fn crossing(t: &[f64], x: &[f64], i: usize, k: usize, step_m: f64) -> Option<Jump> {
    let (v_back, x0_back) = line(t, x, i - 1 - k, i - 1);
    let (v_ahead, x0_ahead) = line(t, x, i + 1, i + 1 + k);
    let dv = v_ahead - v_back;
    if dv.abs() < 1e-9 {
        return None;
    }
    let t_jump = (x0_back - x0_ahead) / dv;
    let dt = t[i] - t[i - 1];
    // First sample at or after the jump, within a sample of i.
    let index = (i - 1..=i + 1).find(|&j| t[j] >= t_jump - 1e-9 * dt)?;
    // The lines meet to within about an encoder step of position: a jump
    // of Δv is placed to within step/Δv of time.
    Some(Jump {
        t_s: t_jump,
        sd_s: step_m / dv.abs(),
        index,
        dv_mps: dv,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Positions of a motion with velocity `v(t)`, sampled at 500 Hz and
    /// quantised to 1 µm.
    fn sampled(n: usize, v: impl Fn(f64) -> f64) -> (Vec<f64>, Vec<f64>) {
        let dt = 0.002;
        let (mut t, mut x, mut pos) = (Vec::new(), Vec::new(), 0.0);
        for i in 0..n {
            let ti = i as f64 * dt;
            // Integrate finely so a jump between samples is exact.
            for s in 0..100 {
                pos += v(ti - dt + (s as f64 + 0.5) * dt / 100.0) * dt / 100.0;
            }
            t.push(ti);
            x.push((pos / 1e-6).round() * 1e-6);
        }
        (t, x)
    }

    #[test]
    fn a_start_lands_on_the_first_sample_after_it() {
        // At rest, then 3 mm/s from t = 0.1003 s (between samples 50 and 51).
        let (t, x) = sampled(200, |t| if t >= 0.1003 { 0.003 } else { 0.0 });
        let s = velocity_steps(&t, &x, 5, 0.001, 1e-6);
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].index, 51);
        assert!((s[0].t_s - 0.1003).abs() < 2e-4, "{:?}", s[0]);
        assert!((s[0].dv_mps - 0.003).abs() < 2e-4, "{:?}", s[0]);
    }

    #[test]
    fn a_smooth_turn_is_no_jump() {
        // An oscillation of 2.65 mm at 1.13 Hz: turns slowly, never jumps.
        let w = std::f64::consts::TAU * 1.13;
        let (t, x) = sampled(2000, |t| 0.00265 * w * (w * t).cos());
        assert_eq!(velocity_steps(&t, &x, 5, 0.001, 1e-6), vec![]);
    }

    #[test]
    fn a_stop_at_speed_is_one_jump() {
        let (t, x) = sampled(300, |t| if t < 0.3011 { 0.0188 } else { 0.0 });
        let s = velocity_steps(&t, &x, 5, 0.001, 1e-6);
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].index, 151);
        assert!((s[0].dv_mps + 0.0188).abs() < 5e-4, "{:?}", s[0]);
    }
}
