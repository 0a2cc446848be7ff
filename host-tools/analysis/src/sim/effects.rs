//! The unmodelled effects the simulator can add to the paper's model, each
//! with a physical parameterisation and a default strength. Names are the
//! names of the book, *Names*.
//!
//! | effect | form | default | why this form |
//! |---|---|---|---|
//! | `viscoelasticity` | Maxwell branch in parallel: dF/dt = k·v − F/τ while in tissue | k = 20 N/m, τ = 1 s | standard linear solid (Fung); relaxes during dwells |
//! | `rate_dependent_friction` | damping b·(\|v\|/v_ref)^(n−1) | n = 0.5, v_ref = 3 mm/s | the paper's b_p falls from 1327 to 377 between 0.2 and 0.8 Hz |
//! | `presliding_hysteresis` | friction follows the Karnopp value with a Dahl-like lag over x_c of travel | x_c = 0.3 mm | pre-sliding displacement, paper §3.2 / Fig. 8b |
//! | `internal_structures` | vessel walls at random depths: k_v·(x − depth) until rupture at F_r | 1–3 walls, k_v = 200 N/m, F_r 0.15–0.4 N, each ≥ 1 mm clear of the next one’s loading | paper §3, Figs. 2–3 |
//! | `depth_dependent_cutting` | cutting·(1 + g·depth) | g = 15 /m | paper §3.3: cutting "increased slightly with depth" |
//! | `holder_inertia` | m·a of the moving holder | m = 0.15 kg | load cell between drive and needle holder |
//! | `sensor_drift` | load-cell offset drifting linearly in time | 3 mN/s | thermal drift of a bridge |
//! | `tissue_motion` | the tissue moves A·sin(2π f t) along the axis | A = 1.5 mm, f = 0.25 Hz | breathing (paper §4.3) |

use anyhow::{bail, Result};
use serde::Serialize;

/// Every effect name, in the order of the book, *Names*.
pub const NAMES: [&str; 8] = [
    "viscoelasticity",
    "rate_dependent_friction",
    "presliding_hysteresis",
    "internal_structures",
    "depth_dependent_cutting",
    "holder_inertia",
    "sensor_drift",
    "tissue_motion",
];

/// One effect with its parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "effect", rename_all = "snake_case")]
pub enum Effect {
    Viscoelasticity {
        k_n_per_m: f64,
        tau_s: f64,
    },
    RateDependentFriction {
        exponent: f64,
        v_ref_mps: f64,
    },
    PreslidingHysteresis {
        x_c_m: f64,
    },
    InternalStructures {
        max_count: u32,
        k_n_per_m: f64,
        rupture_min_n: f64,
        rupture_max_n: f64,
    },
    DepthDependentCutting {
        g_per_m: f64,
    },
    HolderInertia {
        mass_kg: f64,
    },
    SensorDrift {
        rate_n_per_s: f64,
    },
    TissueMotion {
        amplitude_m: f64,
        freq_hz: f64,
    },
}

/// `depth_dependent_cutting`'s standard growth of cutting with depth, /m.
pub const DEPTH_CUTTING_G_PER_M: f64 = 15.0;

impl Effect {
    /// The effect of this name at `strength` times its default size.
    pub fn named(name: &str, strength: f64) -> Result<Self> {
        let s = strength;
        Ok(match name {
            "viscoelasticity" => Effect::Viscoelasticity {
                k_n_per_m: 20.0 * s,
                tau_s: 1.0,
            },
            "rate_dependent_friction" => Effect::RateDependentFriction {
                exponent: 1.0 - 0.5 * s,
                v_ref_mps: 0.003,
            },
            "presliding_hysteresis" => Effect::PreslidingHysteresis { x_c_m: 0.0003 * s },
            "internal_structures" => Effect::InternalStructures {
                max_count: 3,
                k_n_per_m: 200.0,
                rupture_min_n: 0.15 * s,
                rupture_max_n: 0.4 * s,
            },
            "depth_dependent_cutting" => Effect::DepthDependentCutting {
                g_per_m: DEPTH_CUTTING_G_PER_M * s,
            },
            "holder_inertia" => Effect::HolderInertia { mass_kg: 0.15 * s },
            "sensor_drift" => Effect::SensorDrift {
                rate_n_per_s: 0.003 * s,
            },
            "tissue_motion" => Effect::TissueMotion {
                amplitude_m: 0.0015 * s,
                freq_hz: 0.25,
            },
            other => bail!("unknown effect `{other}` (known: {})", NAMES.join(", ")),
        })
    }

    /// The name (book, *Names*).
    pub fn name(&self) -> &'static str {
        match self {
            Effect::Viscoelasticity { .. } => NAMES[0],
            Effect::RateDependentFriction { .. } => NAMES[1],
            Effect::PreslidingHysteresis { .. } => NAMES[2],
            Effect::InternalStructures { .. } => NAMES[3],
            Effect::DepthDependentCutting { .. } => NAMES[4],
            Effect::HolderInertia { .. } => NAMES[5],
            Effect::SensorDrift { .. } => NAMES[6],
            Effect::TissueMotion { .. } => NAMES[7],
        }
    }
}

/// The strongest effect a simulation takes, in times its standard size:
/// `tissue_motion=1e300` wrote `inf` into trial CSVs.
pub const MOST_STRENGTH: f64 = 10.0;

/// Parse `e1,e2,…` (optionally `name=strength`) into effects.
pub fn parse_list(list: &str) -> Result<Vec<Effect>> {
    list.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty() && *s != "none")
        .map(|item| match item.split_once('=') {
            Some((name, strength)) => {
                let s: f64 = strength.parse().map_err(|_| {
                    anyhow::anyhow!("effect `{name}`: strength `{strength}` is not a number")
                })?;
                if !(0.0..=MOST_STRENGTH).contains(&s) {
                    bail!("effect `{name}`: strength {strength} must be within 0..={MOST_STRENGTH} (times the effect's standard size)");
                }
                Effect::named(name, s)
            }
            None => Effect::named(item, 1.0),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_design_name_parses_and_round_trips() {
        for name in NAMES {
            assert_eq!(Effect::named(name, 1.0).unwrap().name(), name);
        }
        let list = parse_list("sensor_drift, holder_inertia=2").unwrap();
        assert_eq!(list[1], Effect::HolderInertia { mass_kg: 0.3 });
        assert!(parse_list("").unwrap().is_empty());
        assert!(parse_list("none").unwrap().is_empty());
        assert!(parse_list("gravity")
            .unwrap_err()
            .to_string()
            .contains("unknown effect `gravity`"));
        assert!(parse_list("sensor_drift=x").is_err());
    }
}
