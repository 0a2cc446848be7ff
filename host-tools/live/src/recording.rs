//! Recording from the page: trial CSVs and the raw stream, exactly as
//! `needle record` writes them (its [`Recorder`]), each recording into a
//! new directory beneath the one `--record-into` names (`recording-001`,
//! `recording-002`, …, numbered on from the highest there).
//!
//! The recorder is fed every item the device thread reads, before the
//! view sees it: the page is decimated, the recording never.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use needle_io::frames::Item;
use needle_io::link::Link;
use needle_io::record::Recorder;

use crate::commands::Answer;
use crate::view::View;

/// Where recordings go, and the one under way.
pub struct Recording {
    into: PathBuf,
    recorder: Option<Recorder>,
}

impl Recording {
    pub fn new(into: &Path) -> Self {
        Self {
            into: into.to_path_buf(),
            recorder: None,
        }
    }

    /// Start recording what `link` reads from now on, from a device
    /// sampling at `rate_hz` if known.
    pub fn start(&mut self, link: &mut Link, rate_hz: Option<u16>, what: &str) -> Answer {
        if let Some(recorder) = &self.recorder {
            let dir = recorder.dir().display();
            return Answer::not(what, format!("already recording into {dir}"));
        }
        match self.open(link, rate_hz) {
            Ok(recorder) => {
                let answer = Answer::done_with(what, format!("into {}", recorder.dir().display()));
                self.recorder = Some(recorder);
                answer
            }
            Err(e) => Answer::not(what, format!("{e:#}")),
        }
    }

    fn open(&self, link: &mut Link, rate_hz: Option<u16>) -> Result<Recorder> {
        let dir = next_dir(&self.into)?;
        // The page lists events and replies itself.
        let recorder = Recorder::create(&dir, rate_hz, "needle live")?.without_frame_lines();
        let (file, path) = recorder.stream_file()?;
        link.capture_to(file, &path)?;
        Ok(recorder)
    }

    /// Stop, for `why`: the trial in hand written, the stream file closed.
    pub fn stop(&mut self, link: &mut Link, view: &mut View, why: &str, what: &str) -> Answer {
        let Some(mut recorder) = self.recorder.take() else {
            return Answer::not(what, "not recording");
        };
        if let Err(e) = link.stop_capture() {
            view.note(format!("{e:#}"));
        }
        let finished = recorder.finish(why);
        if finished.is_err() {
            recorder.abandon();
        }
        for line in recorder.take_lines() {
            view.note(line);
        }
        view.set_recording(None);
        let dir = recorder.dir().display();
        match finished {
            Ok(()) => Answer::done_with(what, format!("{} trials in {dir}", recorder.written())),
            Err(e) => Answer::not(what, format!("{dir}: {e:#}")),
        }
    }

    /// One item read from the device. A recording that cannot write (a
    /// full disk) stops, saying why; the view goes on.
    pub fn item(&mut self, link: &mut Link, view: &mut View, item: &Item) {
        let Some(recorder) = self.recorder.as_mut() else {
            return;
        };
        // The device's stream turned off from the page is the user's
        // choice: the recording waits for it.
        recorder.take_stream_off();
        if let Err(e) = recorder.item(item) {
            self.fail(link, view, &e);
        }
    }

    /// After a read: a stream file that could not be written stops the
    /// recording, as a trial that cannot be does.
    pub fn check_capture(&mut self, link: &mut Link, view: &mut View) {
        if let Some(e) = link.take_capture_error() {
            if self.recorder.is_some() {
                self.fail(link, view, &e);
            }
        }
    }

    fn fail(&mut self, link: &mut Link, view: &mut View, e: &anyhow::Error) {
        let Some(mut recorder) = self.recorder.take() else {
            return;
        };
        recorder.abandon();
        for line in recorder.take_lines() {
            view.note(line);
        }
        view.note(format!("recording stopped: {e:#}"));
        view.set_recording(None);
        // Failing already: what else fails is said above.
        let _ = link.stop_capture();
    }

    /// The recorder's lines to the page, and the recording in a line.
    pub fn show(&mut self, view: &mut View) {
        let Some(recorder) = self.recorder.as_mut() else {
            return;
        };
        for line in recorder.take_lines() {
            view.note(line);
        }
        let mut state = format!(
            "into {}: {} trials written",
            recorder.dir().display(),
            recorder.written()
        );
        if let Some(progress) = recorder.progress() {
            state = format!("{state}; {progress}");
        }
        view.set_recording(Some(state));
    }
}

/// `into/recording-NNN`, numbered one past the highest there.
fn next_dir(into: &Path) -> Result<PathBuf> {
    let highest = match std::fs::read_dir(into) {
        Ok(entries) => entries
            .filter_map(|e| e.ok())
            .filter_map(|e| {
                let name = e.file_name();
                name.to_str()?
                    .strip_prefix("recording-")?
                    .parse::<u32>()
                    .ok()
            })
            .max()
            .unwrap_or(0),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => 0,
        Err(e) => return Err(e).with_context(|| format!("{}: cannot read", into.display())),
    };
    Ok(into.join(format!("recording-{:03}", highest + 1)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_recording_gets_a_directory_one_past_the_highest() {
        let dir = tempfile::tempdir().unwrap();
        let into = dir.path().join("recordings");
        assert_eq!(next_dir(&into).unwrap(), into.join("recording-001"));
        for name in ["recording-001", "recording-007", "recording-x", "other-099"] {
            std::fs::create_dir_all(into.join(name)).unwrap();
        }
        assert_eq!(next_dir(&into).unwrap(), into.join("recording-008"));
    }
}
