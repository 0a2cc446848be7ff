//! The frame sink between the sample and the UART: the sample's side
//! writes whole frames into a byte queue, and whatever drains the link (a
//! transmit interrupt on the real board, the main loop between samples in
//! QEMU) takes bytes out, so a sample never waits on the UART. A frame
//! that does not fit is refused whole, and the device counts it as
//! dropped in its status frames.

use heapless::spsc::{Consumer, Producer};

/// Bytes of frames the link holds (4 KiB: every frame of a sample and a
/// snapshot besides, while the UART drains at 4–5 bytes a sample).
pub const QUEUE_BYTES: usize = 4096;

/// The sample's end of the link's byte queue. Of one size, not generic:
/// its bytes are copied on every sample, and a generic writer would be
/// built with whichever crate uses it (the firmware's images build theirs
/// for size), this one with the core (for speed).
pub struct QueueWriter<'a>(pub Producer<'a, u8, QUEUE_BYTES>);

/// The queue has no room for the whole frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueueFull;

impl embedded_io::Error for QueueFull {
    fn kind(&self) -> embedded_io::ErrorKind {
        embedded_io::ErrorKind::OutOfMemory
    }
}

impl embedded_io::ErrorType for QueueWriter<'_> {
    type Error = QueueFull;
}

impl embedded_io::Write for QueueWriter<'_> {
    /// All of `buf` or nothing: a frame cut short would be garbage on the
    /// wire (COBS resynchronises, but the bytes would be wasted).
    fn write(&mut self, buf: &[u8]) -> Result<usize, QueueFull> {
        let free = self.0.capacity() - self.0.len();
        if buf.len() > free {
            return Err(QueueFull);
        }
        for &byte in buf {
            // Room was checked above, and only this side enqueues.
            self.0.enqueue(byte).map_err(|_| QueueFull)?;
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), QueueFull> {
        Ok(())
    }
}

/// The drain's side: hand queued bytes to `send` (a transmitter taking one
/// byte if it has room now) until it refuses one; `true` when the queue is
/// empty. Every board's drain is this loop over its own transmitter.
pub fn drain<const N: usize>(
    queue: &mut Consumer<'_, u8, N>,
    mut send: impl FnMut(u8) -> bool,
) -> bool {
    while let Some(&byte) = queue.peek() {
        if !send(byte) {
            return false;
        }
        queue.dequeue();
    }
    true
}

/// Where the reader of a circular receive buffer, which a DMA channel
/// fills, has got to. The channel's remaining-transfers count (NDTR on an
/// STM32) says where it will write next: `len − remaining`, and it
/// reloads `len` at the wrap. The bytes between the reader and that point
/// are new. A burst as long as the buffer or longer between two reads
/// loses bytes; the board sizes the buffer for several of the longest
/// command.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RxRing {
    next: usize,
    len: usize,
}

impl RxRing {
    /// A reader at the start of a buffer of `len` bytes.
    pub const fn new(len: usize) -> Self {
        Self { next: 0, len }
    }

    /// The indices of the bytes that arrived since the last call, in
    /// order, given the channel's `remaining` count now; the reader moves
    /// past them.
    pub fn arrived(&mut self, remaining: usize) -> impl Iterator<Item = usize> {
        let len = self.len.max(1);
        // `remaining` is len at the start and after each wrap; 0 only for
        // the instant before the reload.
        let write_at = len.saturating_sub(remaining.min(len)) % len;
        let from = self.next % len;
        let count = (write_at + len - from) % len;
        self.next = write_at;
        (0..count).map(move |i| (from + i) % len)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_io::Write;
    use heapless::spsc::Queue;

    #[test]
    fn the_ring_yields_what_arrived_across_the_wrap_and_nothing_twice() {
        let mut ring = RxRing::new(8);
        // Nothing yet: remaining is the whole length.
        assert_eq!(ring.arrived(8).count(), 0);
        // Three bytes written (remaining 5).
        assert_eq!(ring.arrived(5).collect::<std::vec::Vec<_>>(), [0, 1, 2]);
        assert_eq!(ring.arrived(5).count(), 0, "nothing twice");
        // Seven more: to the end and round to index 1 (remaining 6).
        assert_eq!(
            ring.arrived(6).collect::<std::vec::Vec<_>>(),
            [3, 4, 5, 6, 7, 0, 1]
        );
        // The instant before the reload reads as the wrap point.
        let mut ring = RxRing::new(8);
        assert_eq!(ring.arrived(0).count(), 0);
        assert_eq!(ring.arrived(7).collect::<std::vec::Vec<_>>(), [0]);
    }

    #[test]
    fn a_frame_goes_in_whole_or_not_at_all() {
        let mut queue: Queue<u8, QUEUE_BYTES> = Queue::new();
        let (producer, mut consumer) = queue.split();
        let mut writer = QueueWriter(producer);
        let most = [1; QUEUE_BYTES - 3];
        assert_eq!(writer.write(&most), Ok(most.len()));
        assert_eq!(writer.write(&[6, 7, 8]), Err(QueueFull), "2 slots left");
        assert_eq!(consumer.len(), most.len());
        while consumer.dequeue().is_some() {}
        assert_eq!(writer.write(&[6, 7, 8]), Ok(3));
    }

    #[test]
    fn the_drain_stops_at_the_first_byte_refused_and_keeps_it() {
        let mut queue: Queue<u8, QUEUE_BYTES> = Queue::new();
        let (producer, mut consumer) = queue.split();
        QueueWriter(producer).write(&[1, 2, 3]).unwrap();
        let mut sent = std::vec::Vec::new();
        let mut room = 2;
        let empty = drain(&mut consumer, |byte| {
            room > 0 && {
                room -= 1;
                sent.push(byte);
                true
            }
        });
        assert!(!empty);
        assert_eq!(sent, [1, 2]);
        assert_eq!(consumer.peek(), Some(&3));
        assert!(drain(&mut consumer, |byte| {
            sent.push(byte);
            true
        }));
        assert_eq!(sent, [1, 2, 3]);
    }
}
