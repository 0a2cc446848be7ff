//! The tip's unloading as it is first drawn back from the cutting front:
//! a column of each trial's nominal corrections ([`super::SPREAD`]).

use super::crossval::Gram;
use super::prepare::Prepared;

/// Contact compliances of the tip [`columns`] chooses from, m: a
/// geometric grid from a hundredth of a millimetre to four tenths of
/// one, each a tenth past the one before.
fn compliances_m() -> impl Iterator<Item = f64> {
    (0..40).map(|k| 0.01e-3 * 1.1f64.powi(k))
}

/// The widest of [`compliances_m`]: how far behind the front the tip's
/// unloading may reach.
pub(super) fn widest_compliance_m() -> f64 {
    compliances_m().fold(0.0, f64::max)
}

/// The tip's force as it unloads on the first retraction from the
/// cutting front, and on every return to it after that: `[unloading,
/// returning]`, each a linear ramp, 1 at the front to 0 a compliance
/// behind it ([`unloading_window`]).
///
/// The tissue ahead of a cutting tip is compressed by the cutting force;
/// drawn back, the tip lets it go over its contact compliance
/// (hundredths to tenths of a millimetre), not at once as in the paper's
/// model, whose cutting force stops with the advance. Each trial's own,
/// load and compliance: the load is the trial's own cutting force, the
/// compliance its tissue's, chosen on the trial (with its friction's
/// scale beside it) by the rule fixed here.
///
/// On a return to the front (an oscillation's turns there, a stroke
/// back in), whether the tissue ahead springs back into the cut and is
/// compressed again before the tip cuts, held at rest there and let go
/// again, or stays out of its way, is the tissue's own. So it is a
/// column of its own, its load and compliance the trial's own, chosen by
/// the same rule.
pub(super) fn columns(p: &Prepared) -> [Vec<f64>; 2] {
    match unloading_window(p) {
        Some(w) => [ramped(p, &w.first), ramped(p, &w.returns)],
        None => [vec![0.0; p.trial.len()], vec![0.0; p.trial.len()]],
    }
}

/// A linear ramp over `window`, 1 at the front to 0 a compliance behind
/// it, the compliance the one of [`compliances_m`] that leaves least of
/// the residual there with the trial's friction scaled beside it.
fn ramped(p: &Prepared, window: &[Drawn]) -> Vec<f64> {
    let mut col = vec![0.0; p.trial.len()];
    let ramp = |back_m: f64, d_m: f64| (1.0 - back_m / d_m).max(0.0);
    let Some((d_m, _)) = compliances_m()
        .map(|d_m| (d_m, unloading_sse(p, window, |back_m| ramp(back_m, d_m))))
        .min_by(|a, b| a.1.total_cmp(&b.1))
    else {
        return col;
    };
    for s in window {
        col[s.i] = s.sliding * ramp(s.back_m, d_m);
    }
    col
}

/// A sample within the widest compliance of the cutting front.
struct Drawn {
    i: usize,
    /// How far the tip is behind the front, m.
    back_m: f64,
    /// The share of the tip's load the nominal does not hold there: on
    /// the first retraction how likely it has the sample sliding (at
    /// rest it holds the tip's force), later what its cutting leaves (0
    /// to 1).
    sliding: f64,
}

/// The samples within the widest compliance of the cutting front.
struct Windows {
    /// The first retraction, from where the tip first draws back from
    /// its first dwell until it is that far behind the front — inside a
    /// withdrawal's stick too, where the tissue round the shaft is
    /// dragged along as a tent while the tip lets go of the tissue ahead
    /// of it.
    first: Vec<Drawn>,
    /// Every later return to within it.
    returns: Vec<Drawn>,
}

/// [`Windows`] of a trial with a first dwell.
fn unloading_window(p: &Prepared) -> Option<Windows> {
    let first = p.first_dwell()?;
    let x = &p.trial.x_m;
    // Where the tip stopped at the front: the deepest point before the
    // first dwell's end, first reached (the encoder can count the last
    // steps of a stage easing to a stop inside the dwell).
    let mut front_at = 0;
    for i in 0..first.end {
        if x[i] > x[front_at] {
            front_at = i;
        }
    }
    let front_m = x[front_at];
    let band_mps = p.params.half_band_mps;
    // Drawing back by the encoder, or by its velocity before the encoder
    // counts a step.
    let drawing_back = |i: usize| x[i] < front_m || p.velocity.v_mps[i] < -band_mps;
    let set_off = (front_at..x.len()).find(|&i| drawing_back(i))?;
    // The samples just before, as likely as the nominal has them sliding.
    let mut window: Vec<Drawn> = (front_at..set_off)
        .rev()
        .map(|i| Drawn {
            i,
            back_m: 0.0,
            sliding: p.sliding_odds(i),
        })
        .take_while(|s| s.sliding > 0.0)
        .collect();
    let widest_m = widest_compliance_m();
    let drawn_off = (set_off..x.len())
        .find(|&i| front_m - x[i] >= widest_m)
        .unwrap_or(x.len());
    window.extend((set_off..drawn_off).map(|i| Drawn {
        i,
        back_m: (front_m - x[i]).max(0.0),
        sliding: p.sliding_odds(i),
    }));
    // Every return to the front after it: as far as the nominal's
    // cutting does not already carry the tip's load there.
    let mut returns = Vec::new();
    let mut deepest_m = front_m;
    for (i, &x_m) in x.iter().enumerate().skip(drawn_off) {
        deepest_m = deepest_m.max(x_m);
        let back_m = deepest_m - x_m;
        if back_m < widest_m {
            returns.push(Drawn {
                i,
                back_m,
                sliding: 1.0 - p.cutting[i].clamp(0.0, 1.0),
            });
        }
    }
    Some(Windows {
        first: window,
        returns,
    })
}

/// What an unloading of shape `ramp` (of how far the tip is back) and the
/// trial's friction scaled leave of the residual over `window`.
fn unloading_sse(p: &Prepared, window: &[Drawn], ramp: impl Fn(f64) -> f64) -> f64 {
    let mut g = Gram::new(2);
    for s in window {
        g.add(
            &[s.sliding * ramp(s.back_m), p.friction_n[s.i]],
            p.residual_n[s.i],
        );
    }
    let theta = g.solve();
    g.sse(&theta)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagnose::prepare::prepare;
    use crate::fit::fit_trial;
    use crate::fit::predict::needle_velocity;
    use crate::fit::trial::tests::oscillating;
    use needle_holder::model::params::LIVER1;

    /// `trial` prepared against liver 1, and the least-squares gain of
    /// its returns' column ([`columns`]) on `pressing_n`.
    fn returns_gain(trial: needle_io::trial::Trial, pressing_n: &[f64]) -> (Vec<f64>, f64) {
        let geometry = fit_trial(&trial).unwrap();
        let velocity = needle_velocity(&trial);
        let p = prepare("t".into(), trial, geometry, &LIVER1, velocity);
        let col = p.tip_return;
        let cc: f64 = col.iter().map(|c| c * c).sum();
        let cr: f64 = col.iter().zip(pressing_n).map(|(c, r)| c * r).sum();
        let gain = if cc > 0.0 { cr / cc } else { 0.0 };
        (col, gain)
    }

    /// Liver 1 on the paper's protocol, its tip pressing 0.3 N on the
    /// tissue ahead over the last 0.1 mm before the front on every return
    /// after its first retraction: the returns' column is that ramp, the
    /// load its gain reads off the pressing within 15 % of 0.3 N; none
    /// before the first retraction.
    #[test]
    fn a_tip_pressing_again_on_every_return_is_read_off_the_trial() {
        let plain = oscillating();
        let mut pressing_n = vec![0.0; plain.len()];
        let (mut deepest_m, mut left) = (f64::MIN, false);
        for (x, r) in plain.x_m.iter().zip(pressing_n.iter_mut()) {
            let back_m = deepest_m - x;
            left |= back_m >= widest_compliance_m();
            if left && back_m < 0.1e-3 {
                *r = 0.3 * (1.0 - back_m.max(0.0) / 0.1e-3);
            }
            deepest_m = deepest_m.max(*x);
        }
        let first_return = pressing_n.iter().position(|&r| r > 0.0).expect("a return");
        let mut pressed = plain.clone();
        for (f, r) in pressed.f_n.iter_mut().zip(&pressing_n) {
            *f += r;
        }
        let (col, gain) = returns_gain(pressed, &pressing_n);
        assert!((gain - 0.3).abs() < 0.045, "gain {gain}");
        let first_retraction = plain.x_m[..first_return]
            .iter()
            .rposition(|&x| x >= deepest_m - 1e-9)
            .unwrap_or(0);
        assert!(col[..first_retraction].iter().all(|&c| c == 0.0));
    }
}
