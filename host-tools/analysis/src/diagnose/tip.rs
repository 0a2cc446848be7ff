//! The tip's unloading as it is first drawn back from the cutting front:
//! a column of each trial's nominal corrections ([`super::SPREAD`]).

use super::crossval::Gram;
use super::prepare::Prepared;

/// Contact compliances of the tip [`unloading`] chooses from, m: a
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
/// cutting front. The tissue ahead of a cutting tip is compressed by the
/// cutting force; drawn back, the tip lets it go over its contact
/// compliance (hundredths to tenths of a millimetre), not at once as in
/// the paper's model, whose cutting force stops with the advance. The
/// column is a linear unloading, 1 at the front to 0 a compliance behind
/// it ([`unloading_window`]). Each trial's own, load and compliance: the
/// load is the trial's own cutting force, the compliance its tissue's,
/// chosen on the trial (with its friction's scale beside it) by the rule
/// fixed here.
pub(super) fn unloading(p: &Prepared) -> Vec<f64> {
    let mut col = vec![0.0; p.trial.len()];
    let Some(window) = unloading_window(p) else {
        return col;
    };
    let ramp = |back_m: f64, d_m: f64| (1.0 - back_m / d_m).max(0.0);
    let Some((d_m, _)) = compliances_m()
        .map(|d_m| (d_m, unloading_sse(p, &window, |back_m| ramp(back_m, d_m))))
        .min_by(|a, b| a.1.total_cmp(&b.1))
    else {
        return col;
    };
    for s in &window {
        col[s.i] = s.sliding * ramp(s.back_m, d_m);
    }
    col
}

/// A sample of the first retraction from the cutting front.
struct Drawn {
    i: usize,
    /// How far the tip is behind the front, m.
    back_m: f64,
    /// How likely the nominal has the sample sliding (0 to 1).
    sliding: f64,
}

/// The samples of the first retraction from the cutting front: from
/// where the tip first draws back from its first dwell until it is the
/// widest compliance behind the front — inside a withdrawal's stick too,
/// where the tissue round the shaft is dragged along as a tent while the
/// tip lets go of the tissue ahead of it.
fn unloading_window(p: &Prepared) -> Option<Vec<Drawn>> {
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
    for (i, x_m) in x.iter().enumerate().skip(set_off) {
        let back_m = front_m - x_m;
        if back_m >= widest_m {
            break;
        }
        window.push(Drawn {
            i,
            back_m: back_m.max(0.0),
            sliding: p.sliding_odds(i),
        });
    }
    Some(window)
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
