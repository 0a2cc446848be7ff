//! Device configuration: everything fixed for a session, apart from state.

use crate::assist::{AssistConfig, AssistModes};
use crate::calibration::{Encoder, LoadCell};
use crate::detect::DetectConfig;
use crate::kinematics::VelocityConfig;
use crate::model::params::{ParamError, TissueParams, LIBRARY, LIVER1};
use crate::model::relax::Relaxation;
use crate::model::stiffness::Stiffness;
use crate::model::ModelConfig;
use crate::units::MicroNewtons;
use postcard::experimental::max_size::MaxSize;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Configuration of the whole per-sample pipeline.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub struct DeviceConfig {
    /// Load-cell calibration.
    pub load_cell: LoadCell,
    /// Encoder scale and plausibility limit.
    pub encoder: Encoder,
    /// Sample rate and velocity window.
    pub velocity: VelocityConfig,
    /// Force model.
    pub model: ModelConfig,
    /// Event detectors.
    pub detect: DetectConfig,
    /// Robot assist: what halts the robot besides faults.
    pub assist: AssistConfig,
    /// The tissue's relaxation at rest, applied to the model's force.
    /// Last on the wire: a protocol-3 configuration is this one without
    /// it (none).
    pub relaxation: Relaxation,
}

/// Assist modes of the firmware image, chosen by cargo features
/// (`stop-on-puncture`, `stop-on-structure`, `stop-on-exit`, `back-off`,
/// `speed-limit`); none by default, so the device records and only faults
/// halt the robot.
pub const FIRMWARE_ASSIST: AssistModes = {
    let mut m = AssistModes::NONE;
    if cfg!(feature = "stop-on-puncture") {
        m = m.union(AssistModes::STOP_ON_PUNCTURE);
    }
    if cfg!(feature = "stop-on-structure") {
        m = m.union(AssistModes::STOP_ON_STRUCTURE);
    }
    if cfg!(feature = "stop-on-exit") {
        m = m.union(AssistModes::STOP_ON_EXIT);
    }
    if cfg!(feature = "back-off") {
        m = m.union(AssistModes::BACK_OFF);
    }
    if cfg!(feature = "speed-limit") {
        m = m.union(AssistModes::SPEED_LIMIT);
    }
    m
};

/// The fastest the needle drive moves, nm/s (100 mm/s).
const MAX_DRIVE_NM_PER_S: i64 = 100_000_000;

/// A tissue as the device computes with it: the model, the detectors'
/// thresholds and the puncture force the speed limit scales with, all in
/// fixed point. Made from SI parameters by [`Self::from_params`] — at
/// compile time for the on-device library, on the host for an upload — so
/// the device itself never converts a float; an uploaded one is checked
/// on the device by [`Self::check`], in integers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, MaxSize, Schema)]
pub struct TissueModel {
    /// The force model.
    pub model: ModelConfig,
    /// Detector thresholds (their rate-dependent parts for 500 Hz; the
    /// device sets them for its rate).
    pub detect: DetectConfig,
    /// Puncture force the tissue's model expects.
    pub expected_peak: MicroNewtons,
    /// Relaxation of the model's force at rest.
    pub relaxation: Relaxation,
}

/// A fixed-point parameter that cannot be, named by the TOML key it comes
/// from.
const fn bad(ok: bool, field: &'static str, problem: &'static str) -> Result<(), ParamError> {
    if ok {
        Ok(())
    } else {
        Err(ParamError { field, problem })
    }
}

impl TissueModel {
    /// Convert and check SI parameters.
    pub const fn from_params(p: &TissueParams) -> Result<Self, ParamError> {
        let model = match ModelConfig::from_params(p) {
            Ok(model) => model,
            Err(e) => return Err(e),
        };
        Ok(Self {
            model,
            detect: DetectConfig::for_tissue(p),
            expected_peak: MicroNewtons::from_n(p.puncture_force_n),
            relaxation: Relaxation::from_params(p),
        })
    }

    /// The one check of a tissue, the same on the host and on the device:
    /// the parameters' own ([`TissueParams::validate`]), then the device's
    /// on their fixed point ([`Self::check`]) — a value the fixed point
    /// rounds to zero (a contact force of 1 nN, a band of 1 pm/s) was
    /// taken by the host and refused by the device.
    pub fn validated(p: &TissueParams) -> Result<Self, ParamError> {
        p.validate()?;
        let model = Self::from_params(p)?;
        model.check()?;
        Ok(model)
    }

    /// The signs and ranges [`Self::from_params`] guarantees, checked in
    /// integers: what the device runs on a tissue it did not make.
    pub fn check(&self) -> Result<(), ParamError> {
        const NEG: &str = "must not be negative";
        const POS: &str = "must be positive";
        let m = &self.model;
        let f = &m.friction;
        let d = &self.detect;
        match m.stiffness {
            Stiffness::Polynomial { a1, a2 } => {
                bad(a1.0 >= 0, "a1_n_per_m", NEG)?;
                bad(a2.0 >= 0, "a2_n_per_m2", NEG)?;
                bad(
                    a1.0 > 0 || a2.0 > 0,
                    "a1_n_per_m",
                    "and a2 cannot both be zero",
                )?;
            }
            Stiffness::Rational { b_q32, .. } => bad(b_q32 > 0, "rational_b_m_per_n", POS)?,
        }
        bad(f.cp.0 >= 0, "cp_n_per_m", NEG)?;
        bad(f.cn.0 <= 0, "cn_n_per_m", "must not be positive")?;
        bad(f.bp.0 >= 0, "bp_ns_per_m2", NEG)?;
        bad(f.bn.0 >= 0, "bn_ns_per_m2", NEG)?;
        bad(f.dp.0 >= 0, "dp_n_per_m", NEG)?;
        bad(f.dn.0 <= 0, "dn_n_per_m", "must not be positive")?;
        bad(f.half_band.0 > 0, "half_band_mps", POS)?;
        bad(m.cutting.0 >= 0, "cutting_force_n", NEG)?;
        bad(
            m.phase.relaxation.0 <= 1 << 16,
            "relaxation",
            "must be within 0..=1",
        )?;
        bad(
            self.relaxation.total_gain() <= 1 << 16,
            "relax_gain_2",
            "and relax_gain_1 sum to more than 1",
        )?;
        for (k, b) in self.relaxation.branches.iter().enumerate() {
            let tau_key = ["relax_tau_1_s", "relax_tau_2_s"][k];
            bad(
                b.tau_ms <= crate::model::relax::MOST_TAU_MS,
                tau_key,
                "must be within the device's 1000 s",
            )?;
            bad(
                b.gain.0 == 0 || b.tau_ms >= 1,
                tau_key,
                "must be at least 1 ms where its gain is not zero",
            )?;
        }
        bad(m.phase.withdrawal_speed.0 > 0, "withdrawal_speed", POS)?;
        bad(m.phase.hold_force.0 > 0, "contact_force_n", POS)?;
        bad(d.contact_force.0 > 0, "contact_force_n", POS)?;
        bad(
            d.contact_offset.0 >= 0,
            "contact_force_n",
            "gives a negative contact offset",
        )?;
        bad(d.puncture_min_peak.0 > 0, "puncture_force_n", POS)?;
        bad(
            d.puncture_drop.0 > 0,
            "puncture_drop_to_n",
            "must be below puncture_force_n",
        )?;
        bad(
            d.structure_rise.0 > 0 && d.structure_drop.0 > 0,
            "contact_force_n",
            POS,
        )?;
        bad(d.exit_drop.0 >= 0, "cutting_force_n", NEG)?;
        bad(d.stuck_rise.0 > 0, "puncture_force_n", POS)?;
        bad(self.expected_peak.0 > 0, "puncture_force_n", POS)?;
        // Half a drop deeper than the force it falls from (a negative
        // fall-to force, or a negative spread of the fall), unless the
        // noise floor (twice the contact force) set it. A micronewton of
        // slack each: half a force and twice one are rounded apart.
        bad(
            d.puncture_drop.0 <= self.expected_peak.0 / 2 + 1
                || d.puncture_drop.0 <= d.contact_force.0.saturating_mul(2).saturating_add(1),
            "puncture_drop_to_n",
            "must not be negative (a fall deeper than puncture_force_n)",
        )?;
        bad(
            d.puncture_min_peak.0 <= self.expected_peak.0,
            "puncture_force_sd_n",
            "must not be negative (it arms the detector above puncture_force_n)",
        )?;
        // A touch must be told before the capsule gives way: a contact
        // threshold at or above the puncture force detects nothing.
        bad(
            d.contact_force.0 < self.expected_peak.0,
            "contact_force_n",
            "must be below puncture_force_n",
        )
    }
}

/// The on-device tissue library in fixed point, in [`LIBRARY`]'s order,
/// converted by the compiler.
pub const LIBRARY_MODELS: [TissueModel; LIBRARY.len()] = {
    let mut out = [match TissueModel::from_params(&LIVER1) {
        Ok(m) => m,
        Err(_) => panic!("liver1 is invalid"),
    }; LIBRARY.len()];
    let mut i = 0;
    while i < LIBRARY.len() {
        out[i] = match TissueModel::from_params(&LIBRARY[i].1) {
            Ok(m) => m,
            Err(_) => panic!("a tissue in the library is invalid"),
        };
        i += 1;
    }
    out
};

/// The library name of the firmware's default tissue.
pub const DEFAULT_TISSUE: &str = "liver1";

/// The firmware's default: liver 1 of the paper, converted at compile time.
pub const DEFAULT: DeviceConfig = match DeviceConfig::for_tissue(&LIVER1) {
    Ok(config) => config,
    Err(_) => panic!("liver1 in the tissue library is invalid"),
};

impl Default for DeviceConfig {
    fn default() -> Self {
        DEFAULT
    }
}

impl DeviceConfig {
    /// The bench setup of the paper (10 N load cell, 1 µm encoder, 500 Hz,
    /// velocity over 10 samples) with the model and detectors of `tissue`.
    pub const fn for_tissue(tissue: &TissueParams) -> Result<Self, ParamError> {
        match TissueModel::from_params(tissue) {
            Ok(model) => Ok(Self::for_model(&model)),
            Err(e) => Err(e),
        }
    }

    /// [`Self::for_tissue`] from a tissue already in fixed point.
    pub const fn for_model(tissue: &TissueModel) -> Self {
        Self {
            load_cell: LoadCell::TEN_NEWTON_24_BIT,
            encoder: Encoder::ONE_MICRON,
            velocity: VelocityConfig {
                sample_rate_hz: 500,
                window: 10,
            },
            model: tissue.model,
            detect: tissue.detect,
            assist: AssistConfig::for_peak(tissue.expected_peak, FIRMWARE_ASSIST),
            relaxation: tissue.relaxation,
        }
    }

    /// This configuration (calibration, rate, velocity window, assist
    /// modes and target depth) with `tissue`'s model and detectors.
    /// Integers only: the device runs it on a command.
    pub fn with_tissue(&self, tissue: &TissueModel) -> Self {
        let mut next = Self {
            load_cell: self.load_cell,
            encoder: self.encoder,
            velocity: self.velocity,
            ..Self::for_model(tissue)
        }
        .with_sample_rate(self.velocity.sample_rate_hz);
        next.assist.modes = self.assist.modes;
        next.assist.target_depth = self.assist.target_depth;
        next
    }

    /// The tissue this configuration computes with, in fixed point.
    pub fn tissue_model(&self) -> TissueModel {
        TissueModel {
            model: self.model,
            detect: self.detect,
            expected_peak: self.assist.expected_peak,
            relaxation: self.relaxation,
        }
    }

    /// The same configuration with other assist modes.
    pub const fn with_assist(mut self, modes: AssistModes) -> Self {
        self.assist.modes = modes;
        self
    }

    /// The same configuration at another sample rate. Below 500 Hz the
    /// encoder's jump limit grows so that it still means the drive's
    /// 100 mm/s (a 100 Hz rig moves up to 1 mm between samples); it never
    /// shrinks.
    pub const fn with_sample_rate(mut self, sample_rate_hz: u16) -> Self {
        self.velocity.sample_rate_hz = sample_rate_hz;
        self.detect = self.detect.at_sample_rate(sample_rate_hz);
        let per_sample = MAX_DRIVE_NM_PER_S
            / (if sample_rate_hz == 0 {
                1
            } else {
                sample_rate_hz as i64
            })
            / (if self.encoder.nm_per_count <= 0 {
                1
            } else {
                self.encoder.nm_per_count as i64
            });
        if per_sample > self.encoder.max_counts_per_sample as i64 {
            self.encoder.max_counts_per_sample = if per_sample > 16_000 {
                16_000
            } else {
                per_sample as u16
            };
        }
        self
    }
}

/// Where the device's tissue model came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema, MaxSize)]
pub enum TissueSource {
    /// The on-device library, by position.
    Library(u8),
    /// Uploaded by the host.
    Uploaded,
}

#[cfg(test)]
mod tests {

    /// Values the host's floating point takes and the device's fixed point
    /// rounds to nothing, and fields that contradict each other, are refused
    /// by the one check both sides run, naming the field.
    #[test]
    fn one_check_refuses_what_the_device_would_and_contradictions() {
        type Spoil = fn(&mut TissueParams);
        let cases: [(Spoil, &str); 7] = [
            // 1 nN is 0 µN on the device.
            (|p| p.contact_force_n = 1e-9, "contact_force_n"),
            // 1 pm/s is 0 nm/s on the device.
            (|p| p.half_band_mps = 1e-12, "half_band_mps"),
            // A touch at 3 N is never told before a 2.3 N puncture.
            (|p| p.contact_force_n = 3.0, "contact_force_n"),
            // The fall cannot end above the peak.
            (|p| p.puncture_drop_to_n = 2.5, "puncture_drop_to_n"),
            // A drop deeper than the force it falls from.
            (|p| p.puncture_drop_to_n = -0.5, "puncture_drop_to_n"),
            (
                |p| p.puncture_force_sd_n = Some(-0.2),
                "puncture_force_sd_n",
            ),
            (|p| p.puncture_drop_sd_n = Some(-0.2), "puncture_drop_sd_n"),
        ];
        for (spoil, field) in cases {
            let mut p = LIVER1;
            spoil(&mut p);
            let got = TissueModel::validated(&p).map(|_| ()).map_err(|e| e.field);
            assert_eq!(got, Err(field), "{p:?}");
        }
        assert!(TissueModel::validated(&LIVER1).is_ok());
    }

    /// A fall to zero (a one-trial fit clamps a fall level a hair below
    /// zero to 0.0) is a valid tissue, whatever rounding does to half an
    /// odd number of micronewtons.
    #[test]
    fn a_fall_to_zero_is_no_drop_deeper_than_the_force() {
        for force_n in [2.304001, 2.304, 1.000003, 0.7] {
            let p = TissueParams {
                puncture_force_n: force_n,
                puncture_drop_to_n: 0.0,
                puncture_force_sd_n: None,
                puncture_drop_sd_n: None,
                ..LIVER1
            };
            assert_eq!(TissueModel::validated(&p).map(|_| ()), Ok(()), "{force_n}");
        }
    }

    /// What a host that skipped the parameters' check would upload: the
    /// device's own check names the key all the same.
    #[test]
    fn the_device_refuses_a_relaxation_it_cannot_run_by_key() {
        use crate::model::fixed::FractionQ16;
        use crate::model::relax::{Branch, MOST_TAU_MS};
        let ok = TissueModel::from_params(&LIVER1).unwrap();
        let with = |branches: [Branch; 2]| {
            let mut m = ok;
            m.relaxation.branches = branches;
            m.check().map_err(|e| e.field)
        };
        let b = |gain: u32, tau_ms: u32| Branch {
            gain: FractionQ16(gain),
            tau_ms,
        };
        assert_eq!(with([b(30_000, 1500), b(0, 0)]), Ok(()));
        // An instant relaxation: a gain with no time constant.
        assert_eq!(with([b(30_000, 0), b(0, 0)]), Err("relax_tau_1_s"));
        assert_eq!(with([b(0, 0), b(1, MOST_TAU_MS + 1)]), Err("relax_tau_2_s"));
        // More than the whole force.
        assert_eq!(with([b(40_000, 10), b(30_000, 10)]), Err("relax_gain_2"));
    }

    #[test]
    fn the_device_refuses_contradicting_detector_figures_by_key() {
        type Spoil = fn(&mut TissueParams);
        let cases: [(Spoil, &str); 3] = [
            (|p| p.puncture_drop_to_n = -1.0, "puncture_drop_to_n"),
            (
                |p| p.puncture_force_sd_n = Some(-0.2),
                "puncture_force_sd_n",
            ),
            // The device holds the fall that confirms, not its parts: a
            // negative spread it can tell once it puts that fall past half
            // the peak.
            (|p| p.puncture_drop_sd_n = Some(-0.6), "puncture_drop_to_n"),
        ];
        for (spoil, field) in cases {
            let mut p = LIVER1;
            spoil(&mut p);
            let mut model = LIBRARY_MODELS[0];
            model.detect = DetectConfig::for_tissue(&p);
            assert_eq!(model.check().map_err(|e| e.field), Err(field), "{p:?}");
        }
    }

    use super::*;
    use crate::units::NanometresPerSecond;

    #[test]
    fn the_library_passes_the_devices_check_and_spoilt_models_do_not() {
        for (tissue, (name, _)) in LIBRARY_MODELS.iter().zip(LIBRARY) {
            assert_eq!(tissue.check(), Ok(()), "{name}");
        }
        type Spoil = fn(&mut TissueModel);
        let cases: [(Spoil, &str); 8] = [
            (|t| t.model.friction.cn.0 = 1, "cn_n_per_m"),
            (
                |t| t.detect.puncture_min_peak = t.expected_peak.add(MicroNewtons(1)),
                "puncture_force_sd_n",
            ),
            (
                |t| t.detect.puncture_drop = t.expected_peak,
                "puncture_drop_to_n",
            ),
            (
                |t| t.model.friction.half_band = NanometresPerSecond(0),
                "half_band_mps",
            ),
            (|t| t.model.cutting = MicroNewtons(-1), "cutting_force_n"),
            (|t| t.model.phase.relaxation.0 = (1 << 16) + 1, "relaxation"),
            (
                |t| t.detect.puncture_drop = MicroNewtons(0),
                "puncture_drop_to_n",
            ),
            (|t| t.expected_peak = MicroNewtons(-5), "puncture_force_n"),
        ];
        for (spoil, field) in cases {
            let mut t = LIBRARY_MODELS[0];
            spoil(&mut t);
            assert_eq!(t.check().map_err(|e| e.field), Err(field));
        }
    }
}
