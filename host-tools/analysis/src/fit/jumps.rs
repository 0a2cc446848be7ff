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
/// its own time span (a rig's clock jitters, and loses samples); with the
/// time between the two windows' middles, over which a smooth
/// acceleration builds the difference.
fn contrast(t: &[f64], x: &[f64], i: usize, k: usize) -> (f64, f64) {
    let ahead = (x[i + k] - x[i]) / (t[i + k] - t[i]).max(1e-12);
    let back = (x[i - 1] - x[i - 1 - k]) / (t[i - 1] - t[i - 1 - k]).max(1e-12);
    let apart_s = 0.5 * (t[i + k] + t[i]) - 0.5 * (t[i - 1] + t[i - 1 - k]);
    (ahead - back, apart_s)
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
/// A smooth acceleration a gives contrasts a·d_k over k and a·d_2k over
/// 2k, d the time between the windows' middles ((k + 1)·dt and
/// (2k + 1)·dt on a steady clock), a jump Δv gives Δv over both; so
/// (d_2k·c_k − d_k·c_2k)/(d_2k − d_k) is the jump alone, on the clock's
/// own times: read with a steady clock's weights, samples lost as the
/// needle speeds up are a jump of the acceleration times the gap. A jump
/// between samples i − 1 and i lands on i (the first sample after it),
/// found where the lines fitted to the motion either side cross
/// (`crossing`), which must see the same jump.
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
        let ((ck, dk_s), (c2k, d2k_s)) = (contrast(t, x, i, k), contrast(t, x, i, 2 * k));
        let j = (d2k_s * ck - dk_s * c2k) / (d2k_s - dk_s).max(1e-12);
        if ck.abs() >= least_mps && j * ck > 0.0 {
            j
        } else {
            0.0
        }
    };
    let mut i = 2 * k + 1;
    while i + 2 * k < n {
        if jump(i).abs() < least_mps {
            i += 1;
            continue;
        }
        // The strongest sample of this run of large jumps.
        let mut best = i;
        let mut j = i;
        while j + 2 * k < n && jump(j).abs() >= least_mps {
            if jump(j).abs() > jump(best).abs() {
                best = j;
            }
            j += 1;
        }
        steps.extend(crossing(t, x, best, k, jump(best), (least_mps, step_m)));
        i = j.max(best + k);
    }
    steps
}

/// How far the lines' jump may stray from the combination's, as a share
/// of it (beyond the jump the windows can read at all). The lines'
/// slopes differ by the acceleration over the time between them as well
/// as by the jump; the combination has no part of a constant
/// acceleration. Where the two part by more, the lines see the motion
/// bend, not a jump: a stroke of the paper's oscillation read at 100 Hz
/// (its jerk leaves 0.2–0.3 mm/s of the combination, above five encoder
/// steps a window, while the lines part by 5–10 mm/s of its
/// acceleration), a start eased in, or, at 50 Hz, the far side of a
/// stop the long window reaches (half of it apart). A stroke set off or
/// stopped at speed, bent as it is, parts them by an eighth at 50 Hz.
const LINES_AGREE: f64 = 0.25;

/// Where the straight motions before and after sample `i` meet (the
/// sample that time falls on or before) and the jump of their slopes, if
/// that is the jump `j_mps` the windows' combination reads there (to
/// [`LINES_AGREE`] of it and `least_mps`), at least `least_mps`, and
/// the lines meet within a sample of the gap. The samples next to the gap
/// are left out of both lines: one of them mixes both motions.
fn crossing(
    t: &[f64],
    x: &[f64],
    i: usize,
    k: usize,
    j_mps: f64,
    (least_mps, step_m): (f64, f64),
) -> Option<Jump> {
    let (t_jump, dv) = meet(t, x, i, k)?;
    let agree = dv * j_mps > 0.0 && (dv - j_mps).abs() <= LINES_AGREE * j_mps.abs() + least_mps;
    let dt = t[i] - t[i - 1];
    // A jump between samples i − 1 and i: lines that meet more than a
    // sample away from that gap see something else (a stroke bending
    // under a jittered clock's rounding).
    if !agree || dv.abs() < least_mps || t_jump < t[i - 2] - 1e-9 * dt {
        return None;
    }
    // First sample at or after the jump, within a sample of i.
    let index = (i - 1..=i + 1).find(|&j| t[j] >= t_jump - 1e-9 * dt)?;
    // Straight motions meet to within about an encoder step of position:
    // a jump of Δv is placed to within step/Δv of time. A curved one (a
    // stroke of an oscillation setting off at speed) bends away from its
    // line, and the lines through twice the samples meet elsewhere by
    // about what the bend moves them: as much again of uncertainty, for
    // the force to settle.
    let wide = (i > 2 * k && i + 1 + 2 * k <= t.len())
        .then(|| meet(t, x, i, 2 * k))
        .flatten();
    // At most the window: lines through twice the samples may reach
    // another jump.
    let bend_s = wide.map_or(0.0, |(t_wide, _)| {
        (t_wide - t_jump).abs().min(k as f64 * dt)
    });
    Some(Jump {
        t_s: t_jump,
        sd_s: (step_m / dv.abs()).max(bend_s),
        index,
        dv_mps: dv,
    })
}

/// When the lines through `span` samples before and after sample `i`
/// (the samples next to the gap left out) meet, and the jump of their
/// slopes; `span` samples must lie either side.
fn meet(t: &[f64], x: &[f64], i: usize, span: usize) -> Option<(f64, f64)> {
    let (v_back, x0_back) = line(t, x, i - 1 - span, i - 1);
    let (v_ahead, x0_ahead) = line(t, x, i + 1, i + 1 + span);
    let dv = v_ahead - v_back;
    if dv.abs() < 1e-9 {
        return None;
    }
    Some(((x0_back - x0_ahead) / dv, dv))
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// Positions of a motion with velocity `v(t)`, sampled at 500 Hz and
    /// quantised to 1 µm.
    fn sampled(n: usize, v: impl Fn(f64) -> f64) -> (Vec<f64>, Vec<f64>) {
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.002).collect();
        let x = read_at(&t, v);
        (t, x)
    }

    /// Positions of a motion with velocity `v(t)` read at times `t` to
    /// 1 µm, from 0 at t = 0.
    pub(in crate::fit) fn read_at(t: &[f64], v: impl Fn(f64) -> f64) -> Vec<f64> {
        let (mut x, mut pos, mut from) = (Vec::new(), 0.0, 0.0);
        for &ti in t {
            // Integrate finely so a jump between samples is exact.
            let h = (ti - from) / 100.0;
            for s in 0..100 {
                pos += v(from + (s as f64 + 0.5) * h) * h;
            }
            from = ti;
            x.push((pos / 1e-6).round() * 1e-6);
        }
        x
    }

    /// The paper's oscillation as this project's simulator makes it
    /// (±4 mm at 1.1 Hz): velocity at `t`.
    pub(in crate::fit) fn stroke_mps(t: f64) -> f64 {
        let w = std::f64::consts::TAU * 1.1;
        0.004 * w * (w * t).cos()
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

    /// Read at 100 Hz (windows of 3 samples, five encoder steps a window
    /// 0.17 mm/s), a 1.1 Hz stroke's jerk leaves 0.2–0.3 mm/s of the
    /// combination all along it: no jump for all that.
    #[test]
    fn a_fast_stroke_read_at_100_hz_is_no_jump() {
        let t: Vec<f64> = (0..400).map(|i| i as f64 * 0.01).collect();
        let x = read_at(&t, stroke_mps);
        assert_eq!(velocity_steps(&t, &x, 3, 5e-6 / 0.03, 1e-6), vec![]);
    }

    /// The same stroke on the simulator's jittered clock (each period off
    /// by a normal 10 %, samples now and then lost), at 100 and 500 Hz,
    /// twenty times each: no jump where the stroke turns (under half its
    /// top speed), where a one-sided velocity beside one is mm/s off. At
    /// its top speed, where it hardly accelerates, the clock's rounding
    /// leaves a jump of a few percent of the speed now and then.
    #[test]
    fn a_jittered_clock_makes_no_jump_where_a_stroke_turns() {
        use rand::SeedableRng;
        let top_mps = stroke_mps(0.0);
        for (rate_hz, k) in [(100.0, 3), (500.0, 5)] {
            for seed in 0..20 {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                let t = crate::sim::jittered_times(rate_hz, 6.0, &mut rng);
                let x = read_at(&t, stroke_mps);
                let least_mps = 5e-6 / (k as f64 / rate_hz);
                for jump in velocity_steps(&t, &x, k, least_mps, 1e-6) {
                    let v_mps = stroke_mps(jump.t_s);
                    assert!(
                        v_mps.abs() > 0.5 * top_mps,
                        "{rate_hz} Hz, seed {seed}: {jump:?}"
                    );
                }
            }
        }
    }

    /// A needle creeping back at 2.8 mm/s sets off on a stroke at speed
    /// a tenth of a sample after one: the stroke bends away from the line
    /// through the samples after it, which meets the creep's line about
    /// a third of a millisecond early, ten times what an encoder step
    /// over the jump says. The jump's uncertainty covers that.
    #[test]
    fn a_stroke_set_off_at_speed_is_placed_within_its_uncertainty() {
        let t0 = 1.001;
        let t: Vec<f64> = (0..300).map(|i| i as f64 * 0.01).collect();
        let x = read_at(&t, |t| if t < t0 { -0.0028 } else { stroke_mps(t - t0) });
        let s = velocity_steps(&t, &x, 3, 5e-6 / 0.03, 1e-6);
        let jump = s
            .iter()
            .find(|j| (j.t_s - t0).abs() < 0.01)
            .expect("the set-off");
        assert!((jump.t_s - t0).abs() <= 2.0 * jump.sd_s, "{jump:?}");
    }

    /// Samples lost for 68 ms (a rig's clock drops up to 70 ms) while the
    /// needle speeds up at 0.2 m/s² (a stroke of the paper's oscillation
    /// near its turn): the windows either side of the gap part by the
    /// acceleration over the gap, which is no jump.
    #[test]
    fn samples_lost_while_speeding_up_are_no_jump() {
        let mut t: Vec<f64> = (0..100).map(|i| i as f64 * 0.002).collect();
        t.extend((100..200).map(|i| i as f64 * 0.002 + 0.066));
        let x = read_at(&t, |t| 0.2 * t);
        assert_eq!(velocity_steps(&t, &x, 5, 5e-6 / 0.01, 1e-6), vec![]);
    }
}
