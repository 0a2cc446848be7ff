//! The frame sink between the sample and the UART: the sample's side
//! writes whole frames into a byte queue, and whatever drains the link (a
//! transmit interrupt on the real board, the main loop between samples in
//! QEMU) takes bytes out, so a sample never waits on the UART. A frame
//! that does not fit is refused whole, and the device counts it as
//! dropped in its status frames.

use heapless::spsc::{Consumer, Producer};

/// The sample's end of a byte queue of `N` bytes.
pub struct QueueWriter<'a, const N: usize>(pub Producer<'a, u8, N>);

/// The queue has no room for the whole frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueueFull;

impl embedded_io::Error for QueueFull {
    fn kind(&self) -> embedded_io::ErrorKind {
        embedded_io::ErrorKind::OutOfMemory
    }
}

impl<const N: usize> embedded_io::ErrorType for QueueWriter<'_, N> {
    type Error = QueueFull;
}

impl<const N: usize> embedded_io::Write for QueueWriter<'_, N> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use embedded_io::Write;
    use heapless::spsc::Queue;

    #[test]
    fn a_frame_goes_in_whole_or_not_at_all() {
        let mut queue: Queue<u8, 8> = Queue::new();
        let (producer, mut consumer) = queue.split();
        let mut writer = QueueWriter(producer);
        assert_eq!(writer.write(&[1, 2, 3, 4, 5]), Ok(5));
        assert_eq!(writer.write(&[6, 7, 8]), Err(QueueFull), "7 slots, 5 used");
        assert_eq!(consumer.len(), 5);
        while consumer.dequeue().is_some() {}
        assert_eq!(writer.write(&[6, 7, 8]), Ok(3));
    }

    #[test]
    fn the_drain_stops_at_the_first_byte_refused_and_keeps_it() {
        let mut queue: Queue<u8, 8> = Queue::new();
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
