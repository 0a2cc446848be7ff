//! `needle device calibrate --mass-g M`: a two-point calibration of the
//! load cell with a known mass. The zero is the device's tare (taken with
//! the holder unloaded); the gain scales what the device reads with the
//! mass hanging to the mass's weight, and goes to the device, which keeps
//! it in its settings and shows it in its config frames.
//!
//! Only the magnitude is scaled: the sign of the gain is the bridge's
//! wiring, which a mass hung either way does not tell.

use std::io::BufRead;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use needle_holder::protocol::command::{MIN_GAIN_Q16, NO_READING_YET};
use needle_holder::protocol::{Command, CommandError};

use crate::device::refused;
use crate::frames::{Item, Message};
use crate::link::Link;

/// Standard gravity, m/s². Local gravity differs by up to 0.3 %
/// (equator to pole): within what a hung mass calibrates.
const STANDARD_GRAVITY: f64 = 9.806_65;

/// Samples fewer than this over the measurement are too few to trust.
const MIN_SAMPLES: usize = 50;

#[derive(Debug, clap::Args)]
pub struct CalibrateArgs {
    /// The known mass, grams.
    #[arg(long)]
    pub mass_g: f64,
    /// How long to average the loaded reading, seconds.
    #[arg(long, default_value_t = 2.0)]
    pub seconds: f64,
    /// The mass hangs already and the zero is set: measure at once,
    /// asking nothing (for scripts).
    #[arg(long)]
    pub loaded: bool,
}

/// What the loaded reading gave.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Calibration {
    /// The gain before and after, µN a count (Q16.16).
    pub old_gain_q16: i32,
    pub new_gain_q16: i32,
    /// The mean force read with the mass hanging and its standard
    /// deviation, N, over `samples`.
    pub mean_n: f64,
    pub sd_n: f64,
    pub samples: usize,
}

/// The gain that makes `forces_n` (read at `old_gain_q16`) read the
/// weight of `mass_kg`, or why the reading cannot calibrate.
pub fn calibrated_gain(old_gain_q16: i32, forces_n: &[f64], mass_kg: f64) -> Result<Calibration> {
    if !(mass_kg.is_finite() && mass_kg > 0.0) {
        bail!("--mass-g: a mass above zero, in grams");
    }
    let samples = forces_n.len();
    if samples < MIN_SAMPLES {
        bail!("{samples} samples while the mass hung: at least {MIN_SAMPLES} are needed (is the device streaming?)");
    }
    let mean_n = forces_n.iter().sum::<f64>() / samples as f64;
    let sd_n =
        (forces_n.iter().map(|f| (f - mean_n).powi(2)).sum::<f64>() / (samples - 1) as f64).sqrt();
    // A load still swinging, or none at all, calibrates nothing.
    if mean_n.abs() < 3.0 * sd_n || mean_n.abs() < 1e-3 {
        bail!(
            "the load cell read {:.4} N ± {:.4} N: no steady load (is the mass hanging, and still?)",
            mean_n,
            sd_n
        );
    }
    let weight_n = mass_kg * STANDARD_GRAVITY;
    let new = f64::from(old_gain_q16) * weight_n / mean_n.abs();
    if !(new.abs() >= f64::from(MIN_GAIN_Q16) && new.abs() <= f64::from(i32::MAX)) {
        bail!(
            "a gain of {:.6} µN a count is beyond what the device takes",
            new / 65536.0
        );
    }
    Ok(Calibration {
        old_gain_q16,
        new_gain_q16: new.round() as i32,
        mean_n,
        sd_n,
        samples,
    })
}

/// Ask the person at the bench to do `what`, and wait for Enter.
fn ask(what: &str) -> Result<()> {
    crate::note!("{what}, then press Enter");
    let mut line = String::new();
    let read = std::io::stdin()
        .lock()
        .read_line(&mut line)
        .context("cannot read standard input")?;
    if read == 0 {
        bail!(
            "standard input ended before the answer: run with --loaded to measure without asking"
        );
    }
    Ok(())
}

/// Run the calibration against the device on `link` (its port `port`).
pub fn run(link: &mut Link, port: &str, args: &CalibrateArgs) -> Result<()> {
    if !(args.seconds.is_finite() && args.seconds > 0.0 && args.seconds <= 600.0) {
        bail!("--seconds {}: between 0 and 600", args.seconds);
    }
    if !args.loaded {
        ask("Take every load off the needle holder and hold it still")?;
        tare(link, port)?;
        ask(&format!(
            "Hang the {} g mass from the needle holder and let it settle",
            args.mass_g
        ))?;
    }
    // The stream on (it may be off), then the configuration read: the
    // config frame that answers the read marks where fresh samples start
    // (all before it may be from before the mass hung).
    refused(port, link.command(Command::Stream(true))?)?;
    refused(port, link.command(Command::ReadConfig)?)?;
    let (gain_q16, forces_n) = measure(link, port, Duration::from_secs_f64(args.seconds))?;
    let found = calibrated_gain(gain_q16, &forces_n, args.mass_g / 1e3)?;
    refused(
        port,
        link.command(Command::SetLoadCellGain(found.new_gain_q16))?,
    )?;
    crate::out!(
        "the {} g mass read {:.4} N ± {:.4} N over {} samples; gain {:.6} → {:.6} µN a count: it reads {:.4} N now, kept in the device's settings",
        args.mass_g,
        found.mean_n,
        found.sd_n,
        found.samples,
        f64::from(found.old_gain_q16) / 65536.0,
        f64::from(found.new_gain_q16) / 65536.0,
        args.mass_g / 1e3 * STANDARD_GRAVITY
    )?;
    Ok(())
}

/// Zero the load cell; a device that has no reading yet to zero (just
/// started, or its stream only now on) is asked again for a second.
fn tare(link: &mut Link, port: &str) -> Result<()> {
    let mut until = None;
    loop {
        let reply = link.command(Command::Tare)?;
        let no_reading_yet = matches!(
            &reply,
            Err(CommandError::OutOfRange { field }) if field.as_str() == NO_READING_YET
        );
        let until = *until.get_or_insert_with(|| Instant::now() + Duration::from_secs(1));
        if !no_reading_yet || Instant::now() >= until {
            return refused(port, reply);
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The gain in force and the forces of the samples over `window`, from
/// the last config frame among what arrived up to the reply to a config
/// read (the one that answered it, or a later one) on.
fn measure(link: &mut Link, port: &str, window: Duration) -> Result<(i32, Vec<f64>)> {
    let arrived = link.poll()?;
    let last_config = arrived
        .iter()
        .enumerate()
        .rev()
        .find_map(|(at, item)| match item {
            Item::Frame(Message::Config(c)) => Some((at, c.config.load_cell.gain_q16)),
            _ => None,
        });
    let Some((at, gain)) = last_config else {
        bail!("{port}: the device answered the configuration read but sent no configuration frame");
    };
    let mut forces: Vec<f64> = arrived[at..].iter().filter_map(force_of).collect();
    let until = Instant::now() + window;
    while Instant::now() < until && !link.closed() {
        forces.extend(link.poll()?.iter().filter_map(force_of));
    }
    Ok((gain, forces))
}

fn force_of(item: &Item) -> Option<f64> {
    match item {
        Item::Sample(s) => Some(s.force.as_n()),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_gain_scales_the_reading_to_the_weight_and_keeps_its_sign() {
        // 100 g read as 0.5 N at 1 µN a count: the gain grows by 0.98/0.5.
        let forces: Vec<f64> = (0..200).map(|i| 0.5 + 1e-4 * f64::from(i % 3)).collect();
        let c = calibrated_gain(65_536, &forces, 0.1).unwrap();
        let mean = 0.5 + 1e-4;
        let want = 65_536.0 * 0.1 * STANDARD_GRAVITY / mean;
        assert_eq!(c.new_gain_q16, want.round() as i32);
        let negative: Vec<f64> = forces.iter().map(|f| -f).collect();
        let c = calibrated_gain(-65_536, &negative, 0.1).unwrap();
        assert_eq!(c.new_gain_q16, -(want.round() as i32));
    }

    #[test]
    fn no_load_a_swinging_load_or_too_few_samples_calibrate_nothing() {
        let none = vec![0.0; 200];
        assert!(calibrated_gain(65_536, &none, 0.1).is_err());
        let swinging: Vec<f64> = (0..200)
            .map(|i| if i % 2 == 0 { 1.0 } else { -0.8 })
            .collect();
        assert!(calibrated_gain(65_536, &swinging, 0.1).is_err());
        assert!(calibrated_gain(65_536, &[0.5; 10], 0.1).is_err());
        assert!(calibrated_gain(65_536, &[0.5; 200], 0.0).is_err());
    }
}
