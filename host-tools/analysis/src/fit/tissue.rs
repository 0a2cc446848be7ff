//! The tissue a fit makes: each parameter the device's model takes, from
//! its estimate where the data give one and from a stated prior where they
//! do not, with a note for every value that is not the estimate as it
//! stands. `needle fit --toml` writes it; the diagnosis and the fitted
//! detectors run on it.

use anyhow::{anyhow, Result};
use needle_holder::config::TissueModel;
use needle_holder::model::params::{StiffnessLaw, TissueParams, NUMBER_KEYS};

use super::report::{Estimate, FitReport};
use super::trial;

/// A fit's tissue, and why each value that is not its estimate is what it
/// is.
#[derive(Clone, Debug, PartialEq)]
pub struct FittedTissue {
    /// How many trials the estimates came from.
    pub trials: usize,
    pub params: TissueParams,
    /// `(key, note)`: each value written as other than estimated (a prior,
    /// a limit of the model's range, a key left out), in the order of the
    /// keys.
    pub notes: Vec<(&'static str, String)>,
}

/// The side of zero a tissue parameter must be on; `Derived` for one not
/// estimated at all (a library value, or one set from the noise).
#[derive(Clone, Copy)]
enum Sign {
    Any,
    Positive,
    Negative,
    Derived,
}

/// The number keys every tissue has, in the order a fit writes them: the
/// library's, but for the six that may be left out.
const WRITTEN: [&str; NUMBER_KEYS.len() - 6] = {
    let mut keys = [""; NUMBER_KEYS.len() - 6];
    let mut k = 0;
    while k < keys.len() {
        keys[k] = NUMBER_KEYS[k];
        k += 1;
    }
    keys
};

impl FitReport {
    /// The tissue these estimates make, checked as the device checks a
    /// tissue it is sent: an error naming the key when it is no tissue
    /// the device can run (beyond its fixed point, say).
    pub fn tissue(&self) -> Result<TissueParams> {
        self.fitted().checked()
    }

    /// The tissue these estimates make, with its notes; unchecked
    /// ([`FitReport::tissue`] checks it).
    pub fn fitted(&self) -> FittedTissue {
        let mut notes = Vec::new();
        // The data cannot resolve the band: the library's usual value.
        let half_band = Estimate::chosen(5e-6);
        // A touch, and a structure's rise and fall (twice and 1.6 times
        // it), must stand as far above this recording's noise as liver's
        // 50 mN does above the 5–10 mN it was tuned for.
        let contact = Estimate::chosen(self.noise_n.value.map_or(0.05, |sd| (5.0 * sd).max(0.05)));
        use Sign::{Any, Derived, Negative, Positive};
        let keys: [(&Estimate, Sign); WRITTEN.len()] = [
            (&self.a1_n_per_m, Positive),
            (&self.a2_n_per_m2, Positive),
            (&self.rational_a_per_n, Any),
            (&self.rational_b_m_per_n, Any),
            (&self.puncture_force_n, Any),
            (&self.puncture_depth_m, Any),
            (&self.puncture_drop_to_n, Positive),
            (&self.relaxation, Any),
            (&self.cutting_force_n, Positive),
            (&self.cp_n_per_m, Positive),
            (&self.cn_n_per_m, Negative),
            (&self.bp_ns_per_m2, Positive),
            (&self.bn_ns_per_m2, Positive),
            (&self.dp_n_per_m, Positive),
            (&self.dn_n_per_m, Negative),
            (&half_band, Derived),
            (&contact, Derived),
        ];
        let mut written = [0.0; WRITTEN.len()];
        for (k, (key, (estimated, sign))) in WRITTEN.iter().zip(keys).enumerate() {
            written[k] = value_of(
                key,
                estimated,
                sign,
                &WRITTEN[..k],
                &written[..k],
                &mut notes,
            );
        }
        let [a1_n_per_m, a2_n_per_m2, rational_a_per_n, rational_b_m_per_n, puncture_force_n, puncture_depth_m, puncture_drop_to_n, relaxation, cutting_force_n, cp_n_per_m, cn_n_per_m, bp_ns_per_m2, bn_ns_per_m2, dp_n_per_m, dn_n_per_m, half_band_mps, contact_force_n] =
            written;
        let (puncture_force_sd_n, puncture_drop_sd_n) = self.spreads(&mut notes);
        let relax = self.relaxation_at_rest(&mut notes);
        let params = TissueParams {
            stiffness_law: if self.stiffness_fit.better == "rational" {
                StiffnessLaw::Rational
            } else {
                StiffnessLaw::Polynomial
            },
            a1_n_per_m,
            a2_n_per_m2,
            rational_a_per_n,
            rational_b_m_per_n,
            puncture_force_n,
            puncture_depth_m,
            puncture_drop_to_n,
            puncture_force_sd_n,
            puncture_drop_sd_n,
            relax_gain_1: relax.map(|r| r.0),
            relax_tau_1_s: relax.map(|r| r.1),
            relax_gain_2: None,
            relax_tau_2_s: None,
            relaxation,
            cutting_force_n,
            cp_n_per_m,
            cn_n_per_m,
            bp_ns_per_m2,
            bn_ns_per_m2,
            dp_n_per_m,
            dn_n_per_m,
            half_band_mps,
            contact_force_n,
        };
        FittedTissue {
            trials: self.trials,
            params,
            notes,
        }
    }

    /// The spreads between trials the puncture detector takes its margins
    /// from (none from one trial).
    fn spreads(&self, notes: &mut Vec<(&'static str, String)>) -> (Option<f64>, Option<f64>) {
        let mut sd = |key: &'static str, of: &Estimate| {
            if of.sd.is_none() {
                notes.push((key, format!("{key} is left out: one trial has no spread")));
            }
            of.sd
        };
        (
            sd("puncture_force_sd_n", &self.puncture_force_n),
            sd("puncture_drop_sd_n", &self.puncture_drop_n),
        )
    }

    /// The relaxation at rest the device models (`relax_gain_1`,
    /// `relax_tau_1_s`): one Prony branch, the trials' mean gain and time
    /// constant over their longest rest in the tissue, when the force
    /// falls there by more than three noise sd on average. One branch: a
    /// 5 s rest at 12 mN of noise does not tell two apart.
    fn relaxation_at_rest(&self, notes: &mut Vec<(&'static str, String)>) -> Option<(f64, f64)> {
        const KEY: &str = "relax_gain_1";
        let Some((dwell, Some(gain), Some(tau_s), Some(fall_n))) = self
            .dwell_relaxation
            .as_ref()
            .map(|d| (d, d.gain.value, d.tau_s.value, d.fall_n.value))
        else {
            notes.push((KEY, format!("relax_gain_1 and relax_tau_1_s are left out: no trial rests in the tissue for {} s or more", trial::DWELL_MIN_S)));
            return None;
        };
        // Worth modelling when the fall left out would cost the residual
        // more than the noise (over a noise sd), and it is the tissue's,
        // not chance: three standard errors from the trials' spread (one
        // trial: its own two 0.1 s levels' noise).
        let noise_n = self.noise_n.value.unwrap_or(0.0);
        let trials = (dwell.trials as f64).max(1.0);
        let error_n = match dwell.fall_n.sd {
            Some(sd) => sd / trials.sqrt(),
            None => noise_n * 0.45,
        };
        if fall_n <= noise_n.max(3.0 * error_n) || gain <= 0.0 {
            notes.push((KEY, format!("relax_gain_1 and relax_tau_1_s are left out: at rest the force fell {fall_n:.4} N on average (± {error_n:.4} N), not more than the noise ({noise_n:.4} N) and three standard errors")));
            return None;
        }
        Some((gain.min(1.0), tau_s.clamp(0.001, 1000.0)))
    }
}

/// The number the model takes for `key`: its estimate on the side of zero
/// the model takes, else its prior; each value not the estimate noted.
fn value_of(
    key: &'static str,
    estimated: &Estimate,
    sign: Sign,
    keys_before: &[&str],
    written_before: &[f64],
    notes: &mut Vec<(&'static str, String)>,
) -> f64 {
    let estimate = estimated.written();
    let value = match (estimate, sign) {
        (None, _) => prior(key, keys_before, written_before),
        (Some(v), Sign::Positive) => v.max(0.0),
        (Some(v), Sign::Negative) => v.min(0.0),
        (Some(v), Sign::Any | Sign::Derived) => v,
    };
    let identified = estimated.value.is_some();
    let derived = matches!(sign, Sign::Derived);
    let note = match estimate {
        Some(raw) if raw != value => Some(format!(
            "{key} was fitted as {raw:?}; the model takes no value past {value:?}"
        )),
        // A bound, the model's choice, or nothing at all.
        None if !derived => Some(format!(
            "{key} is not identified by the data; written as its prior {value:?}"
        )),
        _ if !identified && !derived => Some(format!(
            "{key} is not identified by the data; written as {value:?}"
        )),
        _ => None,
    };
    notes.extend(note.map(|n| (key, n)));
    value
}

/// The paper's liver cutting force, N: the prior of a cutting force the
/// data do not give.
pub const CUTTING_PRIOR_N: f64 = 0.94;

/// What a value the data do not give is written as: never 0 where 0 means
/// another tissue (no static band holds nothing at rest, which a needle
/// standing in tissue and holding a force shows it does). The static band
/// is taken symmetric (the paper's D_p 30.4, D_n −29.3 N/m), so an
/// unidentified side is the other side mirrored; anything else is the
/// paper's liver value (book, *The paper's numbers*: b_p 904, b_n 458
/// N·s/m², cutting 0.94 N, C_p = C_n ≈ 0 in liver).
fn prior(key: &str, keys_before: &[&str], written_before: &[f64]) -> f64 {
    let other = |k: &str| {
        keys_before
            .iter()
            .position(|w| *w == k)
            .map(|i| written_before[i])
    };
    match key {
        "dn_n_per_m" => other("dp_n_per_m").map_or(-29.3, |dp| -dp),
        "dp_n_per_m" => 30.4,
        "bp_ns_per_m2" => 904.0,
        "bn_ns_per_m2" => 458.0,
        "cutting_force_n" => CUTTING_PRIOR_N,
        _ => 0.0,
    }
}

/// How `--toml` marks a value written as other than estimated.
pub const NOTE: &str = "# note:";

impl FittedTissue {
    /// The parameters, checked as the device checks a tissue it is sent.
    pub fn checked(&self) -> Result<TissueParams> {
        TissueModel::validated(&self.params).map_err(|e| {
            anyhow!("the parameters fitted from these trials are no tissue the device can run: {e}")
        })?;
        Ok(self.params)
    }

    /// As a tissue-library entry, `[fitted]`, each note on the line before
    /// its key (keys of `TissueParams`; what `--params` loads).
    pub fn to_toml(&self) -> String {
        let p = &self.params;
        let mut out = String::from("# Written by `needle fit`.\n[fitted]\n");
        out += &format!("source = \"needle fit over {} trials\"\n", self.trials);
        let law = match p.stiffness_law {
            StiffnessLaw::Polynomial => "polynomial",
            StiffnessLaw::Rational => "rational",
        };
        out += &format!("stiffness_law = \"{law}\"\n");
        let numbers = [
            p.a1_n_per_m,
            p.a2_n_per_m2,
            p.rational_a_per_n,
            p.rational_b_m_per_n,
            p.puncture_force_n,
            p.puncture_depth_m,
            p.puncture_drop_to_n,
            p.relaxation,
            p.cutting_force_n,
            p.cp_n_per_m,
            p.cn_n_per_m,
            p.bp_ns_per_m2,
            p.bn_ns_per_m2,
            p.dp_n_per_m,
            p.dn_n_per_m,
            p.half_band_mps,
            p.contact_force_n,
        ];
        let optional = [
            ("puncture_force_sd_n", p.puncture_force_sd_n),
            ("puncture_drop_sd_n", p.puncture_drop_sd_n),
            ("relax_gain_1", p.relax_gain_1),
            ("relax_tau_1_s", p.relax_tau_1_s),
        ];
        let lines = WRITTEN
            .iter()
            .zip(numbers.map(Some))
            .chain(optional.iter().map(|(k, v)| (k, *v)));
        for (key, value) in lines {
            for (_, note) in self.notes.iter().filter(|(k, _)| k == key) {
                out += &format!("{NOTE} {note}\n");
            }
            if let Some(value) = value {
                out += &format!("{key} = {value:?}\n");
            }
        }
        out
    }
}
