//! What the page asks — of the device: tare, a tissue, assist, re-arm, the
//! stream on or off; of the host: record or stop — what each does, and
//! the answer the page shows: done, or the device's reason, or what was
//! wrong with the asking.

use std::path::Path;

use anyhow::Result;
use needle_holder::protocol::Command;
use needle_io::device::{assist_command, upload_command};
use serde::{Deserialize, Serialize};

/// One request from the page, as JSON: `{"command": "tare"}`,
/// `{"command": "tissue", "name": "liver1"}`, `{"command": "upload",
/// "file_name": "fit.toml", "toml": "…", "entry": null}`,
/// `{"command": "assist", "modes": "puncture,back-off", "depth_mm": 20}`,
/// `{"command": "rearm"}`, `{"command": "stream", "on": true}`,
/// `{"command": "record", "on": true}`.
#[derive(Debug, Deserialize)]
#[serde(tag = "command", rename_all = "snake_case", deny_unknown_fields)]
pub enum Request {
    Tare,
    /// A tissue of the device's library, by name.
    Tissue {
        name: String,
    },
    /// A tissue file's text (what `needle fit --toml` writes), and which
    /// of its entries when it holds several.
    Upload {
        file_name: String,
        toml: String,
        entry: Option<String>,
    },
    Assist {
        modes: String,
        depth_mm: f64,
    },
    Rearm,
    Stream {
        on: bool,
    },
    /// Trial CSVs, as `needle record` writes them, into a new directory.
    Record {
        on: bool,
    },
}

/// What a request comes to: a command for the device, or a recording
/// started or stopped on the host.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Job {
    Device(Command),
    Record(bool),
}

impl Request {
    /// What the page's log says was asked.
    pub fn what(&self) -> String {
        match self {
            Request::Tare => "tare".into(),
            Request::Tissue { name } => format!("tissue {name}"),
            Request::Upload { file_name, .. } => format!("upload {file_name}"),
            Request::Assist { modes, depth_mm } => format!("assist {modes}, {depth_mm} mm"),
            Request::Rearm => "re-arm".into(),
            Request::Stream { on } => format!("stream {}", on_off(*on)),
            Request::Record { on } => format!("record {}", on_off(*on)),
        }
    }

    /// What to do, or why it cannot be done.
    pub fn job(&self) -> Result<Job> {
        Ok(match self {
            Request::Record { on } => Job::Record(*on),
            device => Job::Device(device.command()?),
        })
    }

    /// The device's command, or why there is none.
    fn command(&self) -> Result<Command> {
        Ok(match self {
            Request::Tare => Command::Tare,
            Request::Tissue { name } => {
                let library = needle_holder::model::params::LIBRARY;
                match library.iter().position(|(n, _)| *n == name.as_str()) {
                    Some(i) => Command::SelectTissue(i as u8),
                    None => {
                        let names: Vec<&str> = library.iter().map(|(n, _)| *n).collect();
                        anyhow::bail!(
                            "no tissue `{name}` in the device's library ({})",
                            names.join(", ")
                        )
                    }
                }
            }
            Request::Upload {
                file_name,
                toml,
                entry,
            } => {
                let tissues = needle_io::tissue::parse(toml, Path::new(file_name))?;
                upload_command(&tissues, entry.as_deref(), file_name)?
            }
            Request::Assist { modes, depth_mm } => {
                assist_command(modes, *depth_mm, "target depth (mm)")?
            }
            Request::Rearm => Command::Rearm,
            Request::Stream { on } => Command::Stream(*on),
            Request::Record { .. } => anyhow::bail!("a recording is the host's, not the device's"),
        })
    }
}

fn on_off(on: bool) -> &'static str {
    if on {
        "on"
    } else {
        "off"
    }
}

/// What the page shows of a request.
#[derive(Debug, Serialize)]
pub struct Answer {
    /// Done.
    pub ok: bool,
    /// In words: what was asked and what came of it.
    pub said: String,
}

impl Answer {
    pub fn done(what: &str) -> Self {
        Self {
            ok: true,
            said: format!("{what}: done"),
        }
    }

    /// Done, and what came of it.
    pub fn done_with(what: &str, detail: impl std::fmt::Display) -> Self {
        Self {
            ok: true,
            said: format!("{what}: {detail}"),
        }
    }

    pub fn not(what: &str, why: impl std::fmt::Display) -> Self {
        Self {
            ok: false,
            said: format!("{what}: {why}"),
        }
    }
}
