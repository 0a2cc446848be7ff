//! `needle device --port P ACTION`: one command to a device on a serial
//! port, its reply printed; exit non-zero when the device refuses it (with
//! its reason) or does not answer.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, Result};
use needle_holder::assist::AssistModes;
use needle_holder::model::params::LIBRARY;
use needle_holder::protocol::{Command, CommandError, TissueSource};
use needle_holder::units::Nanometres;

use crate::decode::{command_error, describe};
use crate::frames::{Item, Message};
use crate::link::Link;

#[derive(Debug, clap::Args)]
pub struct DeviceArgs {
    /// Serial port of the device (e.g. /dev/ttyACM0); every action but
    /// `tissues` needs it.
    #[arg(long)]
    pub port: Option<String>,
    /// Serial baud rate (the Nucleo-F411RE's is 921 600).
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    #[command(subcommand)]
    pub action: Action,
}

#[derive(Debug, clap::Subcommand)]
pub enum Action {
    /// Make the load cell's present reading its zero (needle out of tissue, unloaded).
    Tare,
    /// Use a tissue: a name from the on-device library, or a TOML file such as `needle fit --toml` writes.
    Tissue {
        /// Library name (see `needle device tissues`) or path to a .toml file.
        tissue: String,
        /// Which entry of the file (needed when it holds more than one).
        #[arg(long)]
        name: Option<String>,
    },
    /// List the on-device tissue library (no port needed).
    Tissues,
    /// Robot-assist modes (comma-separated: contact, puncture, structure, exit, depth, back-off, speed-limit; or none) and target depth.
    Assist {
        /// Modes.
        modes: String,
        /// Target depth past the surface for `depth`, mm (0.1–100).
        #[arg(long, default_value_t = 30.0)]
        depth_mm: f64,
    },
    /// Release the halt line (refused while its cause persists).
    Rearm,
    /// Start or stop the sample stream.
    Stream {
        #[arg(value_parser = ["on", "off"])]
        state: String,
    },
    /// Print the device's configuration.
    Config,
    /// Calibrate the load cell with a known mass: zero it unloaded, then
    /// set its gain from the mass hanging (kept in the device's settings).
    Calibrate(crate::calibrate::CalibrateArgs),
    /// Ask the board to test itself: converter registers, data-ready rate,
    /// encoder, halt line, link counters; exit 1 if a check fails.
    Selftest,
}

pub fn run(args: &DeviceArgs) -> Result<()> {
    if let Action::Tissues = args.action {
        for (i, (name, p)) in LIBRARY.iter().enumerate() {
            crate::out!(
                "{i:>2}  {name:<18} puncture {:.2} N at {:.1} mm, cutting {:.2} N",
                p.puncture_force_n,
                p.puncture_depth_m * 1e3,
                p.cutting_force_n
            )?;
        }
        return Ok(());
    }
    let Some(port) = &args.port else {
        bail!("--port: which serial port is the device on (e.g. --port /dev/ttyACM0)?");
    };
    if let Action::Calibrate(calibrate) = &args.action {
        let mut link = Link::open(port, args.baud)?;
        return crate::calibrate::run(&mut link, port, calibrate);
    }
    let command = command_of(&args.action)?;
    let mut link = Link::open(port, args.baud)?;
    refused(port, link.command(command)?)?;
    crate::out!("done")?;
    match args.action {
        Action::Config => print_config(&mut link, port)?,
        Action::Selftest => print_self_test(&mut link, port)?,
        _ => {}
    }
    Ok(())
}

/// Wait for the self-test that follows the reply and print its checks.
fn print_self_test(link: &mut Link, port: &str) -> Result<()> {
    let until = Instant::now() + Duration::from_secs(2);
    while Instant::now() < until && !link.closed() {
        for item in link.poll()? {
            if let Item::Frame(Message::SelfTest(t)) = item {
                let checks = crate::selftest::checks(&t);
                for c in &checks {
                    let verdict = match c.ok {
                        Some(true) => "ok  ",
                        Some(false) => "FAIL",
                        None => "    ",
                    };
                    crate::out!("{verdict} {}", c.line)?;
                }
                let failed = crate::selftest::failed(&checks);
                if failed > 0 {
                    bail!("{port}: {failed} self-test checks failed");
                }
                return Ok(());
            }
        }
    }
    bail!("{port}: the device acknowledged but sent no self-test")
}

/// A refused command as an error naming the port and the reason.
pub fn refused(port: &str, reply: Result<(), CommandError>) -> Result<()> {
    reply.map_err(|e| anyhow::anyhow!("{port}: the device refused: {}", command_error(&e)))
}

/// The command an action sends.
pub fn command_of(action: &Action) -> Result<Command> {
    Ok(match action {
        Action::Tare => Command::Tare,
        Action::Tissue { tissue, name } => tissue_command(tissue, name.as_deref())?,
        Action::Tissues => bail!("`tissues` sends nothing"),
        Action::Calibrate(_) => bail!("`calibrate` is a dialogue, not one command"),
        Action::Assist { modes, depth_mm } => assist_command(modes, *depth_mm, "--depth-mm")?,
        Action::Rearm => Command::Rearm,
        Action::Stream { state } => Command::Stream(state == "on"),
        Action::Config => Command::ReadConfig,
        Action::Selftest => Command::SelfTest,
    })
}

/// The assist modes named in `modes` (comma-separated) with a target
/// depth of `depth_mm` past the surface (`depth_name` names it in an
/// error: the flag, or the page's field).
pub fn assist_command(modes: &str, depth_mm: f64, depth_name: &str) -> Result<Command> {
    let target_depth = Nanometres::from_m(depth_mm / 1e3);
    if !(depth_mm.is_finite() && needle_holder::assist::target_depth_is_valid(target_depth)) {
        bail!("{depth_name} {depth_mm:?}: must be between 0.1 and 100 mm");
    }
    let modes = parse_assist(modes)?;
    Ok(needle_holder::protocol::command::set_assist(
        modes,
        target_depth,
    ))
}

/// A library name selects on the device; a file's entry is uploaded.
fn tissue_command(tissue: &str, name: Option<&str>) -> Result<Command> {
    let path = PathBuf::from(tissue);
    if let Some(i) = LIBRARY.iter().position(|(n, _)| *n == tissue) {
        if path.exists() {
            crate::note!(
                "needle device: {tissue} is the device's library entry; the file of that name here is not read (name it ./{tissue} to upload it)"
            );
        }
        return Ok(Command::SelectTissue(i as u8));
    }
    if !path.exists() {
        let names: Vec<&str> = LIBRARY.iter().map(|(n, _)| *n).collect();
        bail!(
            "{tissue}: neither a tissue in the device's library ({}) nor a file",
            names.join(", ")
        );
    }
    let library = crate::tissue::load(&path)?;
    upload_command(&library, name, &path.display().to_string())
}

/// The upload of the tissue named `name` in `library` (read from
/// `from`), or of its one tissue when `name` is `None`.
pub fn upload_command(
    library: &[crate::tissue::Tissue],
    name: Option<&str>,
    from: &str,
) -> Result<Command> {
    let entry = match (name, library) {
        (Some(n), _) => crate::tissue::named(library, n, from)?,
        (None, [one]) => one.clone(),
        (None, _) => bail!(
            "{from}: holds {} tissues ({}): say which with --name",
            library.len(),
            crate::tissue::names(library)
        ),
    };
    // The device takes tissues in fixed point: the conversion (and its
    // check) runs here, with the core's own code.
    let model = needle_holder::config::TissueModel::from_params(&entry.params)
        .map_err(|e| anyhow::anyhow!("{from}: [{}] {e}", entry.name))?;
    Ok(Command::UploadTissue(model))
}

/// Wait for the configuration frame that answers a read and print it.
fn print_config(link: &mut Link, port: &str) -> Result<()> {
    let until = Instant::now() + Duration::from_secs(2);
    while Instant::now() < until && !link.closed() {
        for item in link.poll()? {
            if let Item::Frame(Message::Config(c)) = item {
                let rate = c.config.velocity.sample_rate_hz;
                crate::out!("{}", describe(&Message::Config(c.clone()), Some(rate)))?;
                let modes: Vec<&str> = AssistModes::NAMES
                    .iter()
                    .filter(|(m, _)| c.config.assist.modes.contains(*m))
                    .map(|(_, n)| *n)
                    .collect();
                let tissue = match c.tissue {
                    TissueSource::Library(_) => "from the library",
                    TissueSource::Uploaded => "uploaded",
                };
                crate::out!(
                    "rate {rate} Hz, tissue {} ({tissue}), assist {}",
                    crate::decode::tissue_name(c.tissue),
                    if modes.is_empty() {
                        "none".into()
                    } else {
                        modes.join(",")
                    }
                )?;
                return Ok(());
            }
        }
    }
    bail!("{port}: the device acknowledged but sent no configuration frame")
}

/// Parse `--assist`.
pub fn parse_assist(list: &str) -> Result<AssistModes> {
    // An empty list is no choice: `none` says "no assist" in words.
    if list.split(',').all(|m| m.trim().is_empty()) {
        anyhow::bail!("assist: name the modes, or `none` to turn them all off");
    }
    list.split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty() && *s != "none")
        .try_fold(AssistModes::NONE, |modes, name| {
            let known = AssistModes::NAMES.iter().find(|(_, n)| *n == name);
            match known {
                Some((mode, _)) => Ok(modes.union(*mode)),
                None => {
                    let names: Vec<&str> = AssistModes::NAMES.iter().map(|(_, n)| *n).collect();
                    anyhow::bail!("unknown assist mode `{name}` (known: {})", names.join(", "))
                }
            }
        })
}
