//! Whether the tip cuts, in a tissue whose motion is itself estimated: the
//! cutting state as a hidden state, predicted one sample ahead and then
//! corrected by that sample's force.
//!
//! On the encoder's positions the state is known: the tip cuts while it
//! advances past the deepest point it has cut. In a moving tissue its
//! position relative to the tissue is known only to the fitted
//! displacement's error (tens of µm) and its velocity to `sd_mps`, but
//! cutting turns on or off at the deepest point to the micrometre; a
//! prediction from those alone puts each switch tens of samples off, each
//! off by the whole cutting force (0.94 N, two hundred noise floors).
//!
//! So the state is filtered, as a prediction-error method does with a
//! model's hidden state: each sample's prediction is made before its own
//! force is read, from the state the forces up to the sample before
//! showed, and from how likely the model says the state switches between
//! the two samples. A switch then costs about one sample, shared over the
//! few where the model cannot tell, and the residual is still of a
//! prediction. The switch is a hazard: cutting continues while the needle
//! keeps advancing relative to the tissue, and starts again once it is
//! both advancing and past the deepest point, each with its own unknown
//! offset (the velocity's error, the position's error), which are the
//! same from one sample to the next.
//!
//! Written here: a two-state filter with hazards from the model is a few
//! lines, and no crate has this model's hazards.

use super::jumps::normal_cdf;
use super::predict::other_side_odds;

/// The cutting state as the forces so far show it.
#[derive(Clone, Copy, Debug)]
pub struct CuttingObserver {
    /// How likely the tip cut at the last sample, given the forces up to
    /// and including it.
    seen: f64,
    /// The [`Odds`] that would have switched it since it last switched:
    /// while cutting, the least of each; while not, the greatest. Given
    /// that it has not switched, the unknown offsets lie beyond them (the
    /// encoder's jitter makes the odds dither from sample to sample, and
    /// each dither is not a new chance to switch).
    envelope: Odds,
    /// When the deepest point cut last moved on, s: the position's error
    /// relative to it grows from there.
    deepest_t_s: f64,
}

/// How fast the tip is advancing relative to the tissue (over the
/// sliding band) and how far past the deepest point cut, each with how
/// well it is known.
#[derive(Clone, Copy, Debug)]
pub struct Odds {
    pub v_over_band_mps: f64,
    pub v_sd_mps: f64,
    pub past_m: f64,
    pub past_sd_m: f64,
}

impl Odds {
    /// Sure to cut: advancing and past the deepest point.
    const SURE: Odds = Odds {
        v_over_band_mps: f64::INFINITY,
        v_sd_mps: 1.0,
        past_m: f64::INFINITY,
        past_sd_m: 1.0,
    };

    /// Standard scores of (advancing, past the deepest point) for the
    /// values of `at`, at this sample's uncertainties.
    fn z(&self, at: &Odds) -> [f64; 2] {
        [
            at.v_over_band_mps / self.v_sd_mps.max(f64::MIN_POSITIVE),
            at.past_m / self.past_sd_m.max(f64::MIN_POSITIVE),
        ]
    }
}

/// Below this the filter calls a chance nil.
const TINY: f64 = 1e-9;

impl CuttingObserver {
    /// At the puncture, cutting, at `t_s`.
    pub fn at_puncture(t_s: f64) -> Self {
        Self {
            seen: 1.0,
            envelope: Odds::SURE,
            deepest_t_s: t_s,
        }
    }

    /// How well the tip's position relative to the deepest point is known
    /// at `t_s`: the encoder's jitter `front_m`, and the tissue's velocity
    /// error `sd_mps` since the tip was there (the displacement's error
    /// is smooth, so it is nearly the same a moment later), at most the
    /// displacement's whole error `tissue_sd_m`.
    pub fn past_sd_m(&self, t_s: f64, front_m: f64, sd_mps: f64, tissue_sd_m: f64) -> f64 {
        (front_m + sd_mps * (t_s - self.deepest_t_s).max(0.0)).min(tissue_sd_m.max(front_m))
    }

    /// How likely the tip cuts at this sample, before its force is read.
    pub fn predict(&self, now: Odds) -> f64 {
        let phi = normal_cdf;
        let ([mz, az], [last_mz, last_az]) = (now.z(&now), now.z(&self.envelope));
        let (m, was_moving) = (phi(mz), phi(last_mz));
        // One unknown offset each: still moving iff above both thresholds
        // (and Φ(min(a, b)) = min(Φ(a), Φ(b))).
        let kept_moving = m.min(was_moving);
        let stays = if was_moving > TINY {
            kept_moving / was_moving
        } else {
            m
        };
        // Mostly the state is sure; then the other branch is not needed
        // (this runs for every sample of every evaluation).
        let starts = if self.seen > 1.0 - TINY {
            0.0
        } else {
            let (a, was_ahead) = (phi(az), phi(last_az));
            let was_cutting = was_moving * was_ahead;
            let kept_both = kept_moving * a.min(was_ahead);
            if 1.0 - was_cutting > TINY {
                ((m * a - kept_both) / (1.0 - was_cutting)).clamp(0.0, 1.0)
            } else {
                m * a
            }
        };
        // Never quite sure: where the model has the switch wrong, the
        // force can still correct the state.
        (self.seen * stays + (1.0 - self.seen) * starts).clamp(TINY, 1.0 - TINY)
    }

    /// After the sample: its force `f_n` against the model without and
    /// with cutting, at the load cell's noise `sd_n`, corrects `predicted`.
    /// Returns whether it cut, as the force shows it.
    pub fn correct(
        &mut self,
        now: Odds,
        predicted: f64,
        f_n: f64,
        model_n: [f64; 2],
        sd_n: f64,
    ) -> bool {
        let was_cut = self.seen > 0.5;
        self.seen = other_side_odds(predicted, f_n, model_n, sd_n);
        let cut = self.seen > 0.5;
        let e = &mut self.envelope;
        if cut != was_cut {
            *e = now;
        } else if cut {
            e.v_over_band_mps = e.v_over_band_mps.min(now.v_over_band_mps);
            e.past_m = e.past_m.min(now.past_m);
        } else {
            e.v_over_band_mps = e.v_over_band_mps.max(now.v_over_band_mps);
            e.past_m = e.past_m.max(now.past_m);
        }
        cut
    }

    /// The deepest point cut moved on at `t_s`.
    pub fn advanced(&mut self, t_s: f64) {
        self.deepest_t_s = t_s;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SD: f64 = 0.005;
    const SIDES: [f64; 2] = [0.1, 1.04];

    #[test]
    fn a_switch_the_model_cannot_place_costs_one_sample() {
        // Advancing slowly about the deepest point, which the model cannot
        // tell from its position error: it keeps the state the force
        // showed, and follows the force when it changes.
        let mut obs = CuttingObserver::at_puncture(0.0);
        let unclear = Odds {
            v_over_band_mps: 0.002,
            v_sd_mps: 0.0005,
            past_m: 0.0,
            past_sd_m: 30e-6,
        };
        // The odds stay the same throughout, so the model gives no more
        // chance of a switch on one sample than the last: each switch
        // is the force's.
        let forces = [1.04, 1.04, 0.1, 0.1, 0.1, 1.04, 1.04];
        let mut predictions = Vec::new();
        for f in forces {
            let p = obs.predict(unclear);
            predictions.push(p);
            obs.correct(unclear, p, f, SIDES, SD);
        }
        assert!(
            predictions[..3].iter().all(|&p| p > 0.99),
            "{predictions:?}"
        );
        assert!(
            predictions[3..6].iter().all(|&p| p < 0.01),
            "{predictions:?}"
        );
        assert!(predictions[6] > 0.99, "{predictions:?}");
    }

    #[test]
    fn the_model_still_says_what_it_can_tell() {
        // Cutting, then retracting: certainly stops, whatever came before.
        let mut obs = CuttingObserver::at_puncture(0.0);
        let cutting = Odds {
            v_over_band_mps: 0.003,
            v_sd_mps: 0.00005,
            past_m: 10e-6,
            past_sd_m: 3e-6,
        };
        let p = obs.predict(cutting);
        assert!(p > 0.999);
        obs.correct(cutting, p, 1.04, SIDES, SD);
        let back = Odds {
            v_over_band_mps: -0.003,
            v_sd_mps: 0.00005,
            past_m: -30e-6,
            past_sd_m: 3e-6,
        };
        assert!(obs.predict(back) < 1e-6);
        obs.correct(back, 0.0, 0.1, SIDES, SD);
        // Coming forward again past the deepest point by far more than
        // its error: cutting again, before the force shows it.
        let again = Odds {
            v_over_band_mps: 0.003,
            v_sd_mps: 0.00005,
            past_m: 100e-6,
            past_sd_m: 3e-6,
        };
        assert!(obs.predict(again) > 0.99);
        // Crossing the deepest point over a few samples: the chance of the
        // switch rises over them, a hazard, not all at once.
        let mut obs2 = obs;
        obs2.correct(back, 0.0, 0.1, SIDES, SD);
        let steps: Vec<f64> = [-2.0, -1.0, 0.0, 1.0]
            .iter()
            .map(|&z| {
                let now = Odds {
                    v_over_band_mps: 0.003,
                    v_sd_mps: 0.00005,
                    past_m: z * 10e-6,
                    past_sd_m: 10e-6,
                };
                let p = obs2.predict(now);
                obs2.correct(now, p, 0.1, SIDES, SD);
                p
            })
            .collect();
        assert!(steps.windows(2).all(|w| w[1] > w[0]), "{steps:?}");
        assert!(steps[0] < 0.05 && steps[3] > 0.3, "{steps:?}");
        // Its position error grows with the time since the tip was there,
        // up to the displacement's whole error.
        obs2.advanced(1.0);
        assert!((obs2.past_sd_m(1.5, 3e-6, 40e-6, 30e-6) - 23e-6).abs() < 1e-12);
        assert_eq!(obs2.past_sd_m(3.0, 3e-6, 40e-6, 30e-6), 30e-6);
    }
}
