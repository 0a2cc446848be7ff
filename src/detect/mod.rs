//! Event detectors and the plausibility checks that run beside them, one
//! call per sample, all integer.
//!
//! | phase before the sample | detector | module |
//! |---|---|---|
//! | out | contact; force with no contact (fault) | [`contact`] |
//! | loading | capsule puncture; stuck encoder (fault) | [`puncture`] |
//! | inserted, advancing | interior structure; exit into another medium | [`interior`] |
//!
//! Every event carries a confidence figure: 500 ‰ when the evidence just
//! meets its threshold, rising linearly to 1000 ‰ at twice the threshold.

use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

pub mod contact;
pub mod interior;
pub mod puncture;

use crate::faults::Faults;
use crate::insertion::{Event, EventKind, Phase};
use crate::model::params::TissueParams;
use crate::model::stiffness::Stiffness;
use crate::units::{MicroNewtons, Nanometres, NanometresPerSecond};

/// The fall that confirms a puncture, N: half the drop the tissue
/// expects less the drop's spread between insertions
/// (`puncture_drop_sd_n`, 0 when not measured) — half a drop two spreads
/// short of the expected one — but no less than a quarter of the drop (a
/// spread read as large as the drop itself would leave the noise to
/// confirm), and no less than twice the contact force (ten noise sd when
/// `needle fit --toml` set it), so a tissue whose fall was read small (an
/// artery rolling over) does not fire on noise.
const fn puncture_drop_n(p: &TissueParams) -> f64 {
    let drop_n = p.puncture_force_n - p.puncture_drop_to_n;
    let spread_n = match p.puncture_drop_sd_n {
        Some(sd_n) => sd_n,
        None => 0.0,
    };
    let mut fall_n = 0.5 * drop_n - spread_n;
    if fall_n < 0.25 * drop_n {
        fall_n = 0.25 * drop_n;
    }
    let floor_n = 2.0 * p.contact_force_n;
    if fall_n > floor_n {
        fall_n
    } else {
        floor_n
    }
}

/// The least peak a capsule's puncture can fall from, N: 30 % of the
/// expected force (a capsule may give way far below it: liver 1 is
/// 2.30 ± 0.83 N); when the tissue's spread is measured
/// (`puncture_force_sd_n`, as `needle fit` writes it), four spreads
/// under it — a peak that far under every fitted trial's is a dip on the
/// climb, not this tissue's capsule — but never above three quarters of
/// it: a spread read from a few trials, or from a simulation whose every
/// trial is alike, can be far smaller than the tissue's own.
const fn puncture_min_peak_n(p: &TissueParams) -> f64 {
    let f_n = p.puncture_force_n;
    let (share_n, most_n) = (0.3 * f_n, 0.75 * f_n);
    match p.puncture_force_sd_n {
        Some(sd_n) => {
            let spread_n = f_n - 4.0 * sd_n;
            // A negative spread is no tissue's: left uncapped, it arms the
            // detector above the force, which the device's check refuses.
            let capped_n = if spread_n < most_n || sd_n < 0.0 {
                spread_n
            } else {
                most_n
            };
            if capped_n > share_n {
                capped_n
            } else {
                share_n
            }
        }
        None => share_n,
    }
}

/// Detector thresholds, derived from a tissue's parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct DetectConfig {
    /// Force above which the tip is taken to touch the surface.
    pub contact_force: MicroNewtons,
    /// Deformation the stiffness law needs to reach `contact_force`: the
    /// surface is that far behind the position where the threshold is met.
    pub contact_offset: Nanometres,
    /// Smallest peak that counts as a capsule puncture.
    pub puncture_min_peak: MicroNewtons,
    /// Fall, within 30 ms, that confirms a puncture from the force the
    /// tissue expects (half its expected drop less the drop's spread:
    /// `puncture_drop_n`); from a smaller peak a quarter of the peak
    /// suffices ([`puncture::needed_drop`]).
    pub puncture_drop: MicroNewtons,
    /// Least rise of the force that can be an interior structure.
    pub structure_rise: MicroNewtons,
    /// Least fall after it.
    pub structure_drop: MicroNewtons,
    /// Least sharp fall at the cutting front that means the tip left the
    /// tissue: half the cutting force the model expects.
    pub exit_drop: MicroNewtons,
    /// Rise of the force, while loading the capsule with the encoder
    /// standing still, that means the encoder is stuck.
    pub stuck_rise: MicroNewtons,
    /// The interior baseline follows the force upwards by 2^-this per
    /// sample: a time constant of about 2 s at any sample rate
    /// ([`DetectConfig::at_sample_rate`]).
    pub baseline_shift: u32,
    /// Samples the encoder may read no advance before the needle counts
    /// as stopped (10 ms, two at least): at 1 mm/s and 2 kHz a 1 µm
    /// encoder steps every other sample, and a sample between two steps
    /// is no stop.
    pub still_samples: u32,
}

impl DetectConfig {
    /// Thresholds for a tissue: contact at its `contact_force_n`; puncture
    /// once the force has peaked above 30 % of the expected puncture force
    /// (or four measured spreads under it: `puncture_min_peak_n`) and
    /// fallen by half the expected drop within 30 ms
    /// (`puncture_drop_n`); exit at half the cutting
    /// force; a stuck encoder once the force has risen by a quarter of the
    /// puncture force without the encoder moving; a structure's rise and
    /// fall at 2 and 1.6 times the contact force (0.1 N and 80 mN for
    /// liver's 50 mN), since both must stand as far above the noise as a
    /// touch does — `needle fit --toml` sets the contact force from the
    /// recording's own noise. Baseline for 500 Hz.
    pub const fn for_tissue(p: &TissueParams) -> Self {
        let contact_force = MicroNewtons::from_n(p.contact_force_n);
        Self {
            contact_force,
            contact_offset: Stiffness::from_params(p).deformation_at(contact_force),
            puncture_min_peak: MicroNewtons::from_n(puncture_min_peak_n(p)),
            puncture_drop: MicroNewtons::from_n(puncture_drop_n(p)),
            // Vessel walls in liver give way at 0.15 N and more (paper §3,
            // Figs. 2–3); 10–20× the 5–10 mN noise this is tuned for.
            structure_rise: MicroNewtons::from_n(2.0 * p.contact_force_n),
            structure_drop: MicroNewtons::from_n(1.6 * p.contact_force_n),
            exit_drop: MicroNewtons::from_n(0.5 * p.cutting_force_n),
            stuck_rise: MicroNewtons::from_n(0.25 * p.puncture_force_n),
            baseline_shift: Self::baseline_shift_for(500),
            still_samples: Self::still_samples_for(500),
        }
    }

    /// The same thresholds for a recording at `sample_rate_hz`.
    pub const fn at_sample_rate(mut self, sample_rate_hz: u16) -> Self {
        self.baseline_shift = Self::baseline_shift_for(sample_rate_hz);
        self.still_samples = Self::still_samples_for(sample_rate_hz);
        self
    }

    /// Samples in 10 ms, two at least.
    const fn still_samples_for(sample_rate_hz: u16) -> u32 {
        let samples = sample_rate_hz as u32 / 100;
        if samples < 2 {
            2
        } else {
            samples
        }
    }

    /// The least shift whose time constant, 2^shift samples, reaches 2 s.
    const fn baseline_shift_for(sample_rate_hz: u16) -> u32 {
        let samples = 2 * sample_rate_hz as u32;
        let mut shift = 0;
        while shift < 16 && (1u32 << shift) < samples {
            shift += 1;
        }
        shift
    }
}

/// Detector state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct DetectState {
    /// Positions of the last two samples, newest first.
    previous_x: [Nanometres; 2],
    /// Consecutive samples inside the tissue with no advance.
    still: u32,
    contact: contact::ContactState,
    puncture: puncture::PunctureState,
    interior: interior::InteriorState,
}

/// One sample as the detectors see it.
#[derive(Clone, Copy, Debug)]
pub struct DetectInput {
    /// Sample index.
    pub index: u32,
    /// Phase before this sample.
    pub phase: Phase,
    /// Position.
    pub x: Nanometres,
    /// Velocity.
    pub v: NanometresPerSecond,
    /// Measured force.
    pub force: MicroNewtons,
    /// The tip is at or beyond the deepest point reached since puncture,
    /// so it is cutting new tissue.
    pub at_cutting_front: bool,
}

/// What the detectors made of one sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Detection {
    /// The event flagged at this sample.
    pub event: Option<Event>,
    /// Plausibility faults this sample raised.
    pub faults: Faults,
}

impl DetectConfig {
    /// Look at one sample.
    pub fn update(&self, state: &mut DetectState, s: DetectInput) -> Detection {
        // Moving inwards over the last two samples: the encoder, not the
        // windowed velocity, so there is no lag.
        let advancing = s.x > state.previous_x[1];
        state.previous_x = [s.x, state.previous_x[0]];
        let faults = puncture::stuck_encoder(self, &mut state.puncture, s);
        let (event, contact_faults) = match s.phase {
            Phase::Out => {
                state.puncture.restart();
                contact::update(self, &mut state.contact, s)
            }
            Phase::Loading => {
                let event = puncture::update(self, &mut state.puncture, s);
                if event.is_some() {
                    state.interior.after_puncture(s);
                }
                (event, Faults::NONE)
            }
            Phase::Inserted if advancing => {
                state.still = 0;
                (interior::update(self, &mut state.interior, s), Faults::NONE)
            }
            // Between two encoder steps: nothing new to look at.
            Phase::Inserted if state.still < self.still_samples => {
                state.still += 1;
                (None, Faults::NONE)
            }
            Phase::Inserted | Phase::Withdrawal => {
                state.interior.restart(s);
                (None, Faults::NONE)
            }
        };
        Detection {
            event,
            faults: faults.union(contact_faults),
        }
    }
}

/// An event at sample `s`.
fn event(
    s: &DetectInput,
    kind: EventKind,
    x: Nanometres,
    force: MicroNewtons,
    confidence_permille: u16,
) -> Event {
    Event {
        index: s.index,
        kind,
        x,
        force,
        confidence_permille,
    }
}

/// Confidence figure for `evidence` against `threshold`: 500 ‰ at the
/// threshold, 1000 ‰ at twice it and beyond.
pub fn confidence_permille(evidence: MicroNewtons, threshold: MicroNewtons) -> u16 {
    let t = i64::from(threshold.0.max(1));
    // max/min rather than clamp, which panics if `t` were negative.
    let over = (i64::from(evidence.0) - t).max(0).min(t);
    (500 + over * 500 / t) as u16
}
