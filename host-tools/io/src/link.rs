//! A device on a serial port, both ways: frames in (through the same
//! [`StreamDecoder`] as `needle decode`), commands out, each matched to
//! its reply.
//!
//! The first command's sequence number comes from the device's status
//! frames (`next_command_seq`, every half second at 500 Hz); a device that
//! sends none yet (one waiting for its first command) gets a fresh random
//! number, and a device that has taken a higher one says so in a stale
//! reply, after which the command goes again with the number it gave.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use needle_holder::protocol::command::MAX_ENCODED_COMMAND;
use needle_holder::protocol::wire::Encoder;
use needle_holder::protocol::{Command, CommandError, CommandFrame};

use crate::frames::{Item, Message, StreamDecoder};

/// The bytes a link keeps: in memory until it has a file, then in the
/// file (unbuffered: each read from the port is one write).
#[derive(Default)]
struct Capture {
    held: Vec<u8>,
    file: Option<(std::fs::File, std::path::PathBuf)>,
    /// Bytes in the file, and those of them after its last delimiter
    /// (the frame being read).
    written: u64,
    since_delimiter: u64,
}

impl Capture {
    fn write(&mut self, bytes: &[u8]) -> Result<()> {
        match &mut self.file {
            Some((file, path)) => file
                .write_all(bytes)
                .with_context(|| format!("{}: cannot write", path.display()))?,
            None => self.held.extend_from_slice(bytes),
        }
        self.written += bytes.len() as u64;
        self.since_delimiter = match bytes.iter().rposition(|&b| b == 0) {
            Some(i) => (bytes.len() - i - 1) as u64,
            None => self.since_delimiter + bytes.len() as u64,
        };
        Ok(())
    }

    /// Close the file after its last whole frame: the frame being read is
    /// in no trial either.
    fn end(self) -> Result<()> {
        if let Some((file, path)) = self.file {
            file.set_len(self.written - self.since_delimiter)
                .with_context(|| format!("{}: cannot write", path.display()))?;
        }
        Ok(())
    }
}

/// How long to wait for a reply before sending the command again.
const REPLY_TIMEOUT: Duration = Duration::from_millis(1500);
/// Sends of one command before giving up.
const ATTEMPTS: u32 = 3;
/// How long to listen for a status frame before the first command.
const STATUS_WAIT: Duration = Duration::from_millis(1200);

/// An open port to a device.
pub struct Link {
    port: Box<dyn serialport::SerialPort>,
    name: String,
    decoder: StreamDecoder,
    next_seq: Option<u32>,
    /// Items read while waiting for a reply, for the caller.
    backlog: Vec<Item>,
    /// Where the raw bytes read go, as they arrive, when the caller keeps
    /// them (`needle record`'s `stream.bin`).
    capture: Option<Capture>,
    /// Why writing the capture failed (a full disk), until the caller
    /// asks; capturing stopped there.
    capture_failed: Option<anyhow::Error>,
    closed: bool,
}

impl Link {
    /// Open `port` at `baud`.
    pub fn open(port: &str, baud: u32) -> Result<Self> {
        check_baud(baud)?;
        let serial = serialport::new(port, baud)
            .timeout(Duration::from_millis(50))
            .open()
            .with_context(|| format!("{port}: cannot open serial port"))?;
        Ok(Self {
            port: serial,
            name: port.to_string(),
            decoder: StreamDecoder::new(),
            next_seq: None,
            backlog: Vec::new(),
            capture: None,
            capture_failed: None,
            closed: false,
        })
    }

    /// Keep every byte read from now on, in memory until
    /// [`Self::capture_to`] gives a file.
    pub fn keep_capture(&mut self) {
        self.capture.get_or_insert_with(Capture::default);
    }

    /// Write the bytes kept so far (or, if none were kept, the frame being
    /// read), and every byte read from now on, to `file` at `path`, as they
    /// arrive: a recording stopped by any means keeps what came before.
    pub fn capture_to(&mut self, file: std::fs::File, path: &std::path::Path) -> Result<()> {
        let capture = self.capture.get_or_insert_with(|| Capture {
            // Begun mid-stream: from the start of the frame being read, so
            // that the file begins with a whole one.
            held: self.decoder.partial_frame().unwrap_or_default().to_vec(),
            ..Capture::default()
        });
        capture.file = Some((file, path.to_path_buf()));
        let held = std::mem::take(&mut capture.held);
        (capture.written, capture.since_delimiter) = (0, 0);
        capture.write(&held)
    }

    /// Why writing the capture failed, once: the bytes read since are not
    /// in it (they were decoded all the same).
    pub fn take_capture_error(&mut self) -> Option<anyhow::Error> {
        self.capture_failed.take()
    }

    /// Keep no more of the bytes read: the file closed after its last
    /// whole frame.
    pub fn stop_capture(&mut self) -> Result<()> {
        self.capture.take().map_or(Ok(()), Capture::end)
    }

    /// The port closed (the device went away, or QEMU exited).
    pub fn closed(&self) -> bool {
        self.closed
    }

    /// The stream decoder, for its counters and the device's configuration.
    pub fn decoder(&self) -> &StreamDecoder {
        &self.decoder
    }

    /// Items that arrived since the last call (reading what waits on the
    /// port for up to its 50 ms timeout).
    pub fn poll(&mut self) -> Result<Vec<Item>> {
        self.read_once()?;
        Ok(std::mem::take(&mut self.backlog))
    }

    /// The sequence number the next command takes, once known.
    pub fn next_seq(&self) -> Option<u32> {
        self.next_seq
    }

    /// Send bytes as they are (tests of what the device makes of them).
    pub fn send_raw(&mut self, bytes: &[u8]) -> Result<()> {
        self.port
            .write_all(bytes)
            .and_then(|()| self.port.flush())
            .with_context(|| format!("{}: cannot write", self.name))
    }

    /// Finish the stream: any incomplete frame at its end.
    pub fn finish(&mut self) -> Vec<Item> {
        let mut items = std::mem::take(&mut self.backlog);
        self.decoder.finish(|item| items.push(item));
        items
    }

    fn read_once(&mut self) -> Result<()> {
        if self.closed {
            return Ok(());
        }
        let mut buf = [0u8; 4096];
        match self.port.read(&mut buf) {
            // A pseudo-terminal whose other end closed reads as an error
            // (EIO) or end of file: the device is gone, not a failure.
            Ok(0) => self.closed = true,
            Ok(n) => {
                if let Some(capture) = self.capture.as_mut() {
                    if let Err(e) = capture.write(&buf[..n]) {
                        // What failed is the file, not the device: the
                        // stream goes on being read, and the caller is told.
                        self.capture = None;
                        self.capture_failed = Some(e);
                    }
                }
                let backlog = &mut self.backlog;
                let mut seq = None;
                self.decoder.feed(&buf[..n], |item| {
                    if let Item::Frame(Message::Status(s)) = &item {
                        seq = Some(s.next_command_seq);
                    }
                    backlog.push(item);
                })?;
                if let Some(s) = seq.filter(|&s| s > 0) {
                    self.next_seq = Some(self.next_seq.map_or(s, |n| n.max(s)));
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(_) => self.closed = true,
        }
        Ok(())
    }

    /// Send `command` and wait for the device's answer: `Ok(Ok(()))` when
    /// done, `Ok(Err(why))` when refused.
    pub fn command(&mut self, command: Command) -> Result<Result<(), CommandError>> {
        if self.next_seq.is_none() {
            let until = Instant::now() + STATUS_WAIT;
            while self.next_seq.is_none() && Instant::now() < until && !self.closed {
                self.read_once()?;
            }
        }
        let mut seq = self.next_seq.unwrap_or_else(fresh_seq);
        let mut restarted = false;
        loop {
            let reply = self.exchange(CommandFrame { seq, command })?;
            match reply {
                Err(CommandError::Stale { next_seq }) if !restarted => {
                    restarted = true;
                    seq = next_seq;
                }
                reply => {
                    self.next_seq = Some(seq.wrapping_add(1));
                    return Ok(reply);
                }
            }
        }
    }

    /// One command frame out, its reply back (sent again after a timeout:
    /// the device answers a repeat without acting twice).
    fn exchange(&mut self, frame: CommandFrame) -> Result<Result<(), CommandError>> {
        let mut encoder = Encoder::<MAX_ENCODED_COMMAND>::default();
        let bytes = encoder.encode(&frame);
        if bytes.is_empty() {
            bail!("the command does not fit a frame (a bug in its size bound)");
        }
        // A leading zero ends whatever partial frame the device holds.
        let mut out = vec![0u8];
        out.extend_from_slice(bytes);
        for _ in 0..ATTEMPTS {
            self.port
                .write_all(&out)
                .and_then(|()| self.port.flush())
                .with_context(|| format!("{}: cannot send the command", self.name))?;
            let until = Instant::now() + REPLY_TIMEOUT;
            while Instant::now() < until {
                if self.closed {
                    bail!("{}: the device went away before answering", self.name);
                }
                let start = self.backlog.len();
                self.read_once()?;
                // Only the reply that names this command answers it: a
                // stray byte on the line draws a `Corrupted` reply with
                // sequence 0 just before the command is read and done.
                let found = self.backlog[start..].iter().position(
                    |item| matches!(item, Item::Frame(Message::Reply(r)) if r.seq == frame.seq),
                );
                if let Some(at) = found {
                    if let Item::Frame(Message::Reply(r)) = self.backlog.remove(start + at) {
                        return Ok(r.result);
                    }
                }
            }
        }
        bail!(
            "{}: no reply to command {} after {ATTEMPTS} tries: is a needle-holder on this port, at this baud rate?",
            self.name,
            frame.seq
        )
    }
}

/// A sequence number for a device whose last one is unknown: random, in
/// the lower quarter of the range, so it is most likely above what the
/// device took and far from wrapping.
fn fresh_seq() -> u32 {
    use rand::Rng;
    rand::thread_rng().gen_range(1..1 << 30)
}

/// A baud rate a port can be set to: 0 means "hang up" to a tty, and no
/// UART runs above 12 Mbd.
pub fn check_baud(baud: u32) -> Result<()> {
    if !(50..=12_000_000).contains(&baud) {
        anyhow::bail!(
            "--baud {baud}: must be within 50..=12000000 (the Nucleo-F411RE's is 921600)"
        );
    }
    Ok(())
}
