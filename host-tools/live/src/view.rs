//! What the page shows, kept on the host: the device's configuration and
//! status, the last insertions (decimated for display, never the
//! recording), the events; and the updates that bring every open page
//! from one moment to the next.
//!
//! Bounded whatever runs for how long: [`INSERTIONS_KEPT`] insertions of
//! at most [`POINTS_PER_INSERTION`] points each, [`EVENTS_KEPT`] events,
//! [`NOTES_KEPT`] lines of the host's own.

use std::collections::VecDeque;

use needle_holder::assist::AssistModes;
use needle_holder::insertion::{Phase, Sample};
use needle_io::decode::{event_name, fault_names, halt_reason_name, phase_name, tissue_name};
use needle_io::frames::{Item, Message, StreamStats};
use serde::Serialize;

/// Insertions the page can overlay, the one in progress included.
pub const INSERTIONS_KEPT: usize = 5;
/// Points a second the page is given at most (the device may sample at
/// 2 kHz; a screen shows no more).
pub const DISPLAY_HZ: u32 = 100;
/// Points one insertion keeps (the oldest go first): 2 min at
/// [`DISPLAY_HZ`].
pub const POINTS_PER_INSERTION: usize = 12_000;
/// Events the page lists.
pub const EVENTS_KEPT: usize = 200;
/// Lines of the host's own (a recording's trials, say) the page lists.
pub const NOTES_KEPT: usize = 100;

/// One displayed sample: time (s), position (mm), measured force, the
/// device's model and the residual (N), and the phase (0 out, 1 loading,
/// 2 inserted, 3 withdrawal). An array on the wire: the page receives
/// many.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Point(pub f64, pub f64, pub f64, pub f64, pub f64, pub u8);

/// One insertion: from a contact to the next (what comes before the first
/// contact is insertion 0).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Insertion {
    /// Counted from 0 since the view began.
    pub number: u32,
    /// Its points, in time order.
    pub points: VecDeque<Point>,
}

/// An event as the page lists it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EventLine {
    pub kind: &'static str,
    pub t_s: f64,
    pub x_mm: f64,
    pub force_n: f64,
    pub confidence_percent: f64,
    /// The insertion it happened in.
    pub insertion: u32,
}

/// The device as the page shows it.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Device {
    /// The port (or `QEMU` and the replay).
    pub source: String,
    /// Still there: the port open and reading.
    pub connected: bool,
    /// Why the host stopped reading it, when it did for a reason other
    /// than the port closing (a stream of another protocol version, say).
    pub problem: Option<String>,
    pub sample_rate_hz: Option<u16>,
    pub tissue: Option<String>,
    pub assist: Option<String>,
    pub target_depth_mm: Option<f64>,
    /// The load cell's zero, counts (a tare moves it).
    pub tare_counts: Option<i32>,
    pub halt: bool,
    /// Why the halt line went up last, while it is up.
    pub halt_reason: Option<&'static str>,
    pub faults: String,
    /// Samples the host received a second, over the last second.
    pub samples_per_s: f64,
    /// Frames the device could not send (its status).
    pub frames_dropped: u32,
    /// Samples the host never received, and received but could not decode
    /// (out of step until a snapshot, or failing their check).
    pub samples_lost: u64,
    pub samples_withheld: u64,
    /// The phase now.
    pub phase: &'static str,
    /// The recording under way, in a line (where, trials written, the
    /// trial in hand); none when not recording.
    pub recording: Option<String>,
}

/// Everything a page needs to start: sent to each page as it opens.
#[derive(Debug, Serialize)]
pub struct Snapshot<'a> {
    /// The device's tissue library, by name, and its assist modes: what
    /// the page's controls offer.
    pub library: Vec<&'static str>,
    pub assist_modes: Vec<&'static str>,
    pub device: &'a Device,
    pub insertions: &'a VecDeque<Insertion>,
    pub events: &'a VecDeque<EventLine>,
    pub notes: &'a VecDeque<String>,
}

/// What changed since the last update.
#[derive(Debug, Default, Serialize)]
pub struct Update {
    /// New points, each with the insertion it belongs to.
    pub points: Vec<(u32, Point)>,
    pub events: Vec<EventLine>,
    pub notes: Vec<String>,
    pub device: Option<Device>,
}

/// The view and the update in the making.
#[derive(Debug)]
pub struct View {
    device: Device,
    insertions: VecDeque<Insertion>,
    events: VecDeque<EventLine>,
    notes: VecDeque<String>,
    pending: Update,
    device_changed: bool,
    /// Samples since the last point kept.
    since_point: u32,
    last_phase: Phase,
}

impl View {
    /// Nothing seen yet from `source`.
    pub fn new(source: &str) -> Self {
        Self {
            device: Device {
                source: source.to_string(),
                connected: true,
                faults: "none".into(),
                phase: phase_name(Phase::Out),
                ..Device::default()
            },
            insertions: VecDeque::from([Insertion::default()]),
            events: VecDeque::new(),
            notes: VecDeque::new(),
            pending: Update::default(),
            device_changed: true,
            since_point: 0,
            last_phase: Phase::Out,
        }
    }

    /// The whole view, for a page that opens now.
    pub fn snapshot(&self) -> Snapshot<'_> {
        Snapshot {
            library: needle_holder::model::params::LIBRARY
                .iter()
                .map(|(name, _)| *name)
                .collect(),
            assist_modes: AssistModes::NAMES.iter().map(|(_, name)| *name).collect(),
            device: &self.device,
            insertions: &self.insertions,
            events: &self.events,
            notes: &self.notes,
        }
    }

    /// A line of the host's own for the page's log.
    pub fn note(&mut self, text: String) {
        if self.notes.len() == NOTES_KEPT {
            self.notes.pop_front();
        }
        self.notes.push_back(text.clone());
        self.pending.notes.push(text);
    }

    /// The recording under way, in a line, or none.
    pub fn set_recording(&mut self, recording: Option<String>) {
        if self.device.recording != recording {
            self.device.recording = recording;
            self.device_changed = true;
        }
    }

    /// Take one item of the stream in.
    pub fn apply(&mut self, item: &Item) {
        match item {
            Item::Sample(s) => self.sample(s),
            Item::Frame(message) => self.message(message),
            // The device started again: its sample indices (and times)
            // start again, in an insertion of their own.
            Item::Restart { .. } => {
                self.start_insertion();
                self.last_phase = Phase::Out;
            }
            Item::Gap { .. } | Item::Skipped { .. } => {}
        }
    }

    /// The device's port closed, or reading it failed (`problem`).
    pub fn disconnected(&mut self, problem: Option<String>) {
        self.device.connected = false;
        self.device.problem = problem;
        self.device.samples_per_s = 0.0;
        self.device_changed = true;
    }

    /// The points and events not yet sent: sent to the pages already open
    /// before a new page takes its snapshot, which holds them, so that no
    /// page is given them twice.
    pub fn take_pending(&mut self) -> Option<Update> {
        let pending = &self.pending;
        if pending.points.is_empty() && pending.events.is_empty() && pending.notes.is_empty() {
            return None;
        }
        Some(std::mem::take(&mut self.pending))
    }

    /// What changed since the last call, with the stream's counters and
    /// the samples a second measured over the last second.
    pub fn take_update(&mut self, stats: &StreamStats, samples_per_s: f64) -> Update {
        let samples_per_s = if self.device.connected {
            samples_per_s
        } else {
            0.0
        };
        let (lost, withheld) = (stats.lost_samples, stats.withheld_samples);
        if (lost, withheld, samples_per_s)
            != (
                self.device.samples_lost,
                self.device.samples_withheld,
                self.device.samples_per_s,
            )
        {
            self.device.samples_lost = lost;
            self.device.samples_withheld = withheld;
            self.device.samples_per_s = samples_per_s;
            self.device_changed = true;
        }
        let mut update = std::mem::take(&mut self.pending);
        if std::mem::take(&mut self.device_changed) {
            update.device = Some(self.device.clone());
        }
        update
    }

    /// The device's sample rate, once a frame has said it.
    pub fn sample_rate_hz(&self) -> Option<u16> {
        self.device.sample_rate_hz
    }

    fn rate_hz(&self) -> f64 {
        f64::from(self.device.sample_rate_hz.unwrap_or(500).max(1))
    }

    fn sample(&mut self, s: &Sample) {
        if s.phase == Phase::Loading && self.last_phase == Phase::Out {
            self.start_insertion();
        }
        let phase_changed = s.phase != self.last_phase;
        self.last_phase = s.phase;
        if phase_changed {
            self.device.phase = phase_name(s.phase);
            self.device_changed = true;
        }
        let every = (self.rate_hz() / f64::from(DISPLAY_HZ)).ceil().max(1.0) as u32;
        self.since_point += 1;
        if self.since_point < every && !phase_changed {
            return;
        }
        self.since_point = 0;
        // To the encoder's micrometre and a tenth of a millinewton: what
        // a screen can show, in a third of the characters.
        let point = Point(
            round(f64::from(s.index) / self.rate_hz(), 1e4),
            round(s.x.as_m() * 1e3, 1e3),
            round(s.force.as_n(), 1e4),
            round(s.model.as_n(), 1e4),
            round(s.residual.as_n(), 1e4),
            s.phase as u8,
        );
        let Some(insertion) = self.insertions.back_mut() else {
            return;
        };
        if insertion.points.len() == POINTS_PER_INSERTION {
            insertion.points.pop_front();
        }
        insertion.points.push_back(point);
        self.pending.points.push((insertion.number, point));
    }

    fn start_insertion(&mut self) {
        let number = self.insertions.back().map_or(0, |i| i.number + 1);
        if self.insertions.len() == INSERTIONS_KEPT {
            self.insertions.pop_front();
        }
        self.insertions.push_back(Insertion {
            number,
            points: VecDeque::new(),
        });
    }

    fn message(&mut self, message: &Message) {
        match message {
            Message::Header(h) => self.device.sample_rate_hz = Some(h.sample_rate_hz),
            Message::Config(c) => {
                self.device.sample_rate_hz = Some(c.config.velocity.sample_rate_hz);
                self.device.tissue = Some(tissue_name(c.tissue));
                self.device.assist = Some(assist_names(c.config.assist.modes));
                self.device.target_depth_mm = Some(c.config.assist.target_depth.as_m() * 1e3);
                self.device.tare_counts = Some(c.config.load_cell.tare_counts);
            }
            Message::Status(s) => {
                self.device.halt = s.halt;
                if !s.halt {
                    self.device.halt_reason = None;
                }
                self.device.faults = fault_names(s.faults.into());
                self.device.frames_dropped = s.frames_dropped;
            }
            Message::Halt(h) => {
                self.device.halt = true;
                self.device.halt_reason = Some(halt_reason_name(h.reason));
            }
            Message::Event(e) => {
                let line = EventLine {
                    kind: event_name(e.kind),
                    t_s: f64::from(e.index) / self.rate_hz(),
                    x_mm: e.x.as_m() * 1e3,
                    force_n: e.force.as_n(),
                    confidence_percent: f64::from(e.confidence_permille) / 10.0,
                    insertion: self.insertions.back().map_or(0, |i| i.number),
                };
                if self.events.len() == EVENTS_KEPT {
                    self.events.pop_front();
                }
                self.events.push_back(line.clone());
                self.pending.events.push(line);
            }
            Message::Snapshot(_) | Message::Reply(_) | Message::SelfTest(_) => return,
        }
        self.device_changed = true;
    }
}

/// `value` to the nearest `1 / per`.
fn round(value: f64, per: f64) -> f64 {
    (value * per).round() / per
}

/// The modes' names, comma-separated, or `none`.
fn assist_names(modes: AssistModes) -> String {
    let names: Vec<&str> = AssistModes::NAMES
        .iter()
        .filter(|(mode, _)| modes.0 & mode.0 != 0)
        .map(|(_, name)| *name)
        .collect();
    if names.is_empty() {
        "none".into()
    } else {
        names.join(",")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use needle_holder::insertion::{Event, EventKind};
    use needle_holder::units::{MicroNewtons, Nanometres, NanometresPerSecond};

    fn sample(index: u32, phase: Phase) -> Item {
        let i = (index % 100_000) as i32;
        Item::Sample(Sample {
            index,
            x: Nanometres(1000 * i),
            v: NanometresPerSecond(0),
            force: MicroNewtons(10 * i),
            model: MicroNewtons(9 * i),
            residual: MicroNewtons(i),
            phase,
        })
    }

    fn header(rate_hz: u16) -> Item {
        Item::Frame(Message::Header(needle_holder::protocol::header(rate_hz)))
    }

    #[test]
    fn a_2_khz_stream_is_shown_at_100_points_a_second_and_every_phase_change() {
        let mut view = View::new("test");
        view.apply(&header(2000));
        for i in 0..2000 {
            let phase = if i < 1000 { Phase::Out } else { Phase::Loading };
            view.apply(&sample(i, phase));
        }
        let update = view.take_update(&StreamStats::default(), 2000.0);
        // 20 samples a point; the change of phase at 1000 starts an
        // insertion and is shown at once.
        assert!(
            (100..=102).contains(&update.points.len()),
            "{}",
            update.points.len()
        );
        let first_loading = update.points.iter().find(|(_, p)| p.5 == 1).unwrap();
        assert_eq!(first_loading.0, 1, "a contact starts insertion 1");
        assert_eq!(first_loading.1 .0, 0.5, "at the sample it came");
        assert_eq!(
            view.take_update(&StreamStats::default(), 2000.0)
                .points
                .len(),
            0
        );
    }

    #[test]
    fn an_hour_of_insertions_and_events_keeps_the_view_bounded() {
        let mut view = View::new("test");
        view.apply(&header(500));
        let mut index = 0;
        for _ in 0..3 * INSERTIONS_KEPT {
            for phase in [
                Phase::Out,
                Phase::Loading,
                Phase::Inserted,
                Phase::Withdrawal,
            ] {
                for _ in 0..60_000 {
                    view.apply(&sample(index, phase));
                    index += 1;
                }
            }
            let event = Event {
                index,
                kind: EventKind::Puncture,
                x: Nanometres(1),
                force: MicroNewtons(1),
                confidence_permille: 900,
            };
            for _ in 0..EVENTS_KEPT {
                view.apply(&Item::Frame(Message::Event(event)));
                view.note("trial written".into());
            }
            view.take_update(&StreamStats::default(), 500.0);
        }
        let snapshot = view.snapshot();
        assert_eq!(snapshot.insertions.len(), INSERTIONS_KEPT);
        assert_eq!(
            snapshot.insertions.back().unwrap().number,
            3 * INSERTIONS_KEPT as u32
        );
        assert!(snapshot
            .insertions
            .iter()
            .all(|i| i.points.len() == POINTS_PER_INSERTION));
        assert_eq!(snapshot.events.len(), EVENTS_KEPT);
        assert_eq!(snapshot.notes.len(), NOTES_KEPT);
    }

    #[test]
    fn the_device_goes_out_with_an_update_only_when_it_changed() {
        let mut view = View::new("test");
        let stats = StreamStats::default();
        assert!(view.take_update(&stats, 0.0).device.is_some(), "the first");
        assert!(view.take_update(&stats, 0.0).device.is_none());
        view.apply(&header(500));
        let device = view.take_update(&stats, 0.0).device.unwrap();
        assert_eq!(device.sample_rate_hz, Some(500));
        view.disconnected(None);
        assert!(!view.take_update(&stats, 0.0).device.unwrap().connected);
    }
}
