//! Tissue parameters in SI units: what the tissue library (`tissues.toml`)
//! holds, what `needle fit` estimates, and what the fixed-point model is
//! built from ([`super::ModelConfig::from_params`]).
//!
//! Signs: force is positive when it resists insertion; `cn ≤ 0 ≤ cp`,
//! `dn ≤ 0 ≤ dp`, `bp, bn ≥ 0` (book, *The paper's numbers*).

use serde::{Deserialize, Serialize};

/// Which stiffness law the capsule follows before puncture.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum StiffnessLaw {
    /// f = a1·x + a2·x² (paper eq. 4).
    Polynomial,
    /// f = x/(a·x + b) (paper eq. 3).
    Rational,
}

/// One tissue's parameter set.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TissueParams {
    /// Stiffness law in use.
    pub stiffness_law: StiffnessLaw,
    /// Eq. 4 linear term, N/m.
    pub a1_n_per_m: f64,
    /// Eq. 4 quadratic term, N/m².
    pub a2_n_per_m2: f64,
    /// Eq. 3 `a`, 1/N.
    pub rational_a_per_n: f64,
    /// Eq. 3 `b`, m/N (1/b is the stiffness at contact).
    pub rational_b_m_per_n: f64,
    /// Expected peak force at capsule puncture, N.
    pub puncture_force_n: f64,
    /// Expected deformation at puncture (x_s2 − x_s1), m.
    pub puncture_depth_m: f64,
    /// Expected force right after the puncture drop, N.
    pub puncture_drop_to_n: f64,
    /// Spread (sd) of the puncture force from insertion to insertion, N
    /// (≥ 0); `None` when not measured. The puncture detector arms no
    /// lower than four of them below the expected force (within 30–75 %
    /// of it): a capsule the fitted trials never saw give way so early is
    /// not this tissue's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub puncture_force_sd_n: Option<f64>,
    /// Spread (sd) of the puncture's fall (`puncture_force_n −
    /// puncture_drop_to_n`) from insertion to insertion, N (≥ 0); `None`
    /// when not measured (taken as 0). The detector confirms a fall of
    /// half the drop less one spread (half the drop two spreads short),
    /// no less than a quarter of the drop.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub puncture_drop_sd_n: Option<f64>,
    /// Stress relaxation at rest, branch 1 of the Prony series (see
    /// `model::relax`): the share of a held force it relaxes away, 0–1.
    /// Left out with its time constant: no such branch.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relax_gain_1: Option<f64>,
    /// Branch 1's time constant, s (> 0, within 1000 s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relax_tau_1_s: Option<f64>,
    /// Branch 2's gain, 0–1 (the two gains sum to at most 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relax_gain_2: Option<f64>,
    /// Branch 2's time constant, s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relax_tau_2_s: Option<f64>,
    /// Surface relaxation ρ in x_s3 = x_s1 + ρ·(x_s2 − x_s1), 0–1.
    pub relaxation: f64,
    /// Cutting force while advancing into uncut tissue, N.
    pub cutting_force_n: f64,
    /// Dynamic friction per unit length, inserting, N/m (≥ 0).
    pub cp_n_per_m: f64,
    /// Dynamic friction per unit length, withdrawing, N/m (≤ 0).
    pub cn_n_per_m: f64,
    /// Damping per unit length, inserting, N·s/m² (≥ 0).
    pub bp_ns_per_m2: f64,
    /// Damping per unit length, withdrawing, N·s/m² (≥ 0).
    pub bn_ns_per_m2: f64,
    /// Static friction bound per unit length, inserting side, N/m (≥ 0).
    pub dp_n_per_m: f64,
    /// Static friction bound per unit length, withdrawing side, N/m (≤ 0).
    pub dn_n_per_m: f64,
    /// Half width Δv/2 of the zero-velocity band, m/s (> 0).
    pub half_band_mps: f64,
    /// Force that marks contact with the surface, N (> 0).
    pub contact_force_n: f64,
}

/// The keys of [`TissueParams`] that hold numbers, as in the TOML file
/// (`stiffness_law` holds a name); the last six may be left out.
pub const NUMBER_KEYS: [&str; 23] = [
    "a1_n_per_m",
    "a2_n_per_m2",
    "rational_a_per_n",
    "rational_b_m_per_n",
    "puncture_force_n",
    "puncture_depth_m",
    "puncture_drop_to_n",
    "relaxation",
    "cutting_force_n",
    "cp_n_per_m",
    "cn_n_per_m",
    "bp_ns_per_m2",
    "bn_ns_per_m2",
    "dp_n_per_m",
    "dn_n_per_m",
    "half_band_mps",
    "contact_force_n",
    "puncture_force_sd_n",
    "puncture_drop_sd_n",
    "relax_gain_1",
    "relax_tau_1_s",
    "relax_gain_2",
    "relax_tau_2_s",
];

/// A parameter that cannot be used, and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParamError {
    /// The offending key, as in the TOML file.
    pub field: &'static str,
    /// What is wrong with it.
    pub problem: &'static str,
}

impl core::fmt::Display for ParamError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "`{}` {}", self.field, self.problem)
    }
}

const fn check(ok: bool, field: &'static str, problem: &'static str) -> Result<(), ParamError> {
    if ok {
        Ok(())
    } else {
        Err(ParamError { field, problem })
    }
}

/// Fails the enclosing `const fn` with the first error.
macro_rules! check_all {
    ($($e:expr),* $(,)?) => {
        $(if let Err(e) = $e { return Err(e); })*
    };
}

impl TissueParams {
    /// Check every field; the error names the first bad one. `const` so the
    /// firmware's compiled-in library is checked at compile time.
    pub const fn validate(&self) -> Result<(), ParamError> {
        const NOT_FINITE: &str = "is not a finite number";
        const Q26: &str = "is not within the device's ±32 000 N/m";
        const Q48: &str = "is not within the device's ±7.6e6";
        const FORCE: &str = "is not within the device's ±2000 N";
        const LENGTH: &str = "is not within the device's 2 m";
        const SPEED: &str = "is not within the device's 2 m/s";
        const RATIONAL_A: &str = "is not within the device's ±3e10 1/N";
        const RATIONAL_B: &str = "is not within the device's ±2e6 m/N";
        let p = self;
        let fields: [(f64, &str); 17] = [
            (p.a1_n_per_m, "a1_n_per_m"),
            (p.a2_n_per_m2, "a2_n_per_m2"),
            (p.rational_a_per_n, "rational_a_per_n"),
            (p.rational_b_m_per_n, "rational_b_m_per_n"),
            (p.puncture_force_n, "puncture_force_n"),
            (p.puncture_depth_m, "puncture_depth_m"),
            (p.puncture_drop_to_n, "puncture_drop_to_n"),
            (p.relaxation, "relaxation"),
            (p.cutting_force_n, "cutting_force_n"),
            (p.cp_n_per_m, "cp_n_per_m"),
            (p.cn_n_per_m, "cn_n_per_m"),
            (p.bp_ns_per_m2, "bp_ns_per_m2"),
            (p.bn_ns_per_m2, "bn_ns_per_m2"),
            (p.dp_n_per_m, "dp_n_per_m"),
            (p.dn_n_per_m, "dn_n_per_m"),
            (p.half_band_mps, "half_band_mps"),
            (p.contact_force_n, "contact_force_n"),
        ];
        let mut i = 0;
        while i < fields.len() {
            check_all!(check(fields[i].0.is_finite(), fields[i].1, NOT_FINITE));
            i += 1;
        }
        // What the device's fixed point holds (see `fixed.rs` and
        // `units.rs`): a value past it would be saturated, silently
        // becoming another tissue on the device than on the host.
        let ranges: [(f64, f64, &str, &str); 16] = [
            (p.a1_n_per_m, 32_000.0, "a1_n_per_m", Q26),
            (p.cp_n_per_m, 32_000.0, "cp_n_per_m", Q26),
            (p.cn_n_per_m, 32_000.0, "cn_n_per_m", Q26),
            (p.dp_n_per_m, 32_000.0, "dp_n_per_m", Q26),
            (p.dn_n_per_m, 32_000.0, "dn_n_per_m", Q26),
            (p.a2_n_per_m2, 7.6e6, "a2_n_per_m2", Q48),
            (p.bp_ns_per_m2, 7.6e6, "bp_ns_per_m2", Q48),
            (p.bn_ns_per_m2, 7.6e6, "bn_ns_per_m2", Q48),
            (p.puncture_force_n, 2000.0, "puncture_force_n", FORCE),
            (p.puncture_drop_to_n, 2000.0, "puncture_drop_to_n", FORCE),
            (p.cutting_force_n, 2000.0, "cutting_force_n", FORCE),
            (p.contact_force_n, 2000.0, "contact_force_n", FORCE),
            (p.puncture_depth_m, 2.0, "puncture_depth_m", LENGTH),
            (p.half_band_mps, 2.0, "half_band_mps", SPEED),
            (p.rational_a_per_n, 3.0e10, "rational_a_per_n", RATIONAL_A),
            (
                p.rational_b_m_per_n,
                2.0e6,
                "rational_b_m_per_n",
                RATIONAL_B,
            ),
        ];
        let mut i = 0;
        while i < ranges.len() {
            let (v, most, name, why) = ranges[i];
            check_all!(check(v.abs() < most, name, why));
            i += 1;
        }
        check_all!(
            check(
                p.a1_n_per_m >= 0.0,
                "a1_n_per_m",
                "is negative (stiffness must resist)"
            ),
            check(
                p.a2_n_per_m2 >= 0.0,
                "a2_n_per_m2",
                "is negative (stiffness must resist)"
            ),
            check(
                p.puncture_force_n > 0.0,
                "puncture_force_n",
                "must be positive"
            ),
            check(
                p.puncture_depth_m > 0.0,
                "puncture_depth_m",
                "must be positive"
            ),
            check(
                p.puncture_drop_to_n >= 0.0,
                "puncture_drop_to_n",
                "is negative"
            ),
            check(
                p.puncture_drop_to_n < p.puncture_force_n,
                "puncture_drop_to_n",
                "must be below puncture_force_n"
            ),
            check(
                p.relaxation >= 0.0 && p.relaxation <= 1.0,
                "relaxation",
                "must be within 0..=1"
            ),
            check(p.cutting_force_n >= 0.0, "cutting_force_n", "is negative"),
            check(
                p.cp_n_per_m >= 0.0,
                "cp_n_per_m",
                "is negative (need cn <= 0 <= cp)"
            ),
            check(
                p.cn_n_per_m <= 0.0,
                "cn_n_per_m",
                "is positive (need cn <= 0 <= cp)"
            ),
            check(p.bp_ns_per_m2 >= 0.0, "bp_ns_per_m2", "is negative"),
            check(p.bn_ns_per_m2 >= 0.0, "bn_ns_per_m2", "is negative"),
            check(
                p.dp_n_per_m >= 0.0,
                "dp_n_per_m",
                "is negative (need dn <= 0 <= dp)"
            ),
            check(
                p.dn_n_per_m <= 0.0,
                "dn_n_per_m",
                "is positive (need dn <= 0 <= dp)"
            ),
            check(
                p.half_band_mps > 0.0,
                "half_band_mps",
                "must be positive (a band of zero width)"
            ),
            check(
                p.contact_force_n > 0.0,
                "contact_force_n",
                "must be positive"
            ),
            check(
                p.contact_force_n < p.puncture_force_n,
                "contact_force_n",
                "must be below puncture_force_n"
            ),
        );
        let spreads = [
            (p.puncture_force_sd_n, "puncture_force_sd_n"),
            (p.puncture_drop_sd_n, "puncture_drop_sd_n"),
        ];
        let mut i = 0;
        while i < spreads.len() {
            if let (Some(sd), name) = spreads[i] {
                check_all!(
                    check(sd.is_finite(), name, NOT_FINITE),
                    check(sd >= 0.0, name, "is negative (a spread is an sd)"),
                    check(sd < 2000.0, name, FORCE),
                );
            }
            i += 1;
        }
        let branches = [
            (
                p.relax_gain_1,
                p.relax_tau_1_s,
                "relax_gain_1",
                "relax_tau_1_s",
            ),
            (
                p.relax_gain_2,
                p.relax_tau_2_s,
                "relax_gain_2",
                "relax_tau_2_s",
            ),
        ];
        let mut total_gain = 0.0;
        let mut i = 0;
        while i < branches.len() {
            let (gain, tau, gain_key, tau_key) = branches[i];
            match (gain, tau) {
                (Some(g), Some(t)) => {
                    check_all!(
                        check(g.is_finite(), gain_key, NOT_FINITE),
                        check(g >= 0.0 && g <= 1.0, gain_key, "must be within 0..=1"),
                        check(t.is_finite(), tau_key, NOT_FINITE),
                        check(
                            t >= 0.001 && t <= 1000.0,
                            tau_key,
                            "must be within the device's 1 ms..=1000 s"
                        ),
                    );
                    // As the device will hold it (Q16), so both sides
                    // refuse the same sums.
                    total_gain += super::fixed::FractionQ16::from_ratio(g).0 as f64 / 65536.0;
                }
                (None, None) => {}
                (Some(_), None) => {
                    check_all!(check(false, tau_key, "is missing (its gain is given)"));
                }
                (None, Some(_)) => {
                    check_all!(check(
                        false,
                        gain_key,
                        "is missing (its time constant is given)"
                    ));
                }
            }
            i += 1;
        }
        check_all!(check(
            total_gain <= 1.0,
            "relax_gain_2",
            "and relax_gain_1 sum to more than 1 (more than the whole force relaxes)"
        ));
        match p.stiffness_law {
            StiffnessLaw::Polynomial => check(
                p.a1_n_per_m > 0.0 || p.a2_n_per_m2 > 0.0,
                "a1_n_per_m",
                "and a2_n_per_m2 are both zero: the capsule would have no stiffness",
            ),
            StiffnessLaw::Rational => check(
                p.rational_b_m_per_n > 0.0,
                "rational_b_m_per_n",
                "must be positive (1/b is the stiffness at contact)",
            ),
        }
    }
}

include!(concat!(env!("OUT_DIR"), "/tissues.rs"));

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_library_is_valid_and_liver_1_matches_the_paper() {
        for (name, params) in LIBRARY {
            assert_eq!(params.validate(), Ok(()), "{name}");
        }
        assert_eq!(LIVER1.a1_n_per_m, 48.0);
        assert_eq!(LIVER1.a2_n_per_m2, 5200.0);
        assert_eq!(LIVER1.bp_ns_per_m2, 1327.0);
        assert_eq!(tissue("liver1_journal").map(|p| p.cp_n_per_m), Some(10.57));
        assert!(tissue("spleen").is_none());
    }

    #[test]
    fn invalid_parameters_are_rejected_naming_the_field() {
        type Spoil = fn(&mut TissueParams);
        let cases: [(Spoil, &str); 15] = [
            (|p| p.a1_n_per_m = f64::NAN, "a1_n_per_m"),
            (|p| p.a2_n_per_m2 = -1.0, "a2_n_per_m2"),
            (|p| p.dp_n_per_m = -0.1, "dp_n_per_m"),
            (|p| p.dn_n_per_m = 0.1, "dn_n_per_m"),
            (|p| p.half_band_mps = 0.0, "half_band_mps"),
            (|p| p.relaxation = 1.5, "relaxation"),
            (|p| p.bp_ns_per_m2 = f64::INFINITY, "bp_ns_per_m2"),
            // Past the fixed point: saturated, they made another tissue.
            (|p| p.a1_n_per_m = 32_000.0, "a1_n_per_m"),
            (|p| p.puncture_force_n = 5000.0, "puncture_force_n"),
            (|p| p.cutting_force_n = 1e300, "cutting_force_n"),
            (|p| p.cn_n_per_m = -1e6, "cn_n_per_m"),
            // Relaxation: a gain past 1, a branch half given, gains that
            // sum past the whole force, a time constant under 1 ms.
            (
                |p| (p.relax_gain_1, p.relax_tau_1_s) = (Some(1.5), Some(1.0)),
                "relax_gain_1",
            ),
            (|p| p.relax_gain_1 = Some(0.3), "relax_tau_1_s"),
            (
                |p| {
                    (p.relax_gain_1, p.relax_tau_1_s) = (Some(0.6), Some(1.0));
                    (p.relax_gain_2, p.relax_tau_2_s) = (Some(0.5), Some(5.0));
                },
                "relax_gain_2",
            ),
            (
                |p| (p.relax_gain_2, p.relax_tau_2_s) = (Some(0.2), Some(1e-4)),
                "relax_tau_2_s",
            ),
        ];
        for (spoil, field) in cases {
            let mut p = LIVER1;
            spoil(&mut p);
            assert_eq!(p.validate().map_err(|e| e.field), Err(field));
        }
    }
}
