//! Frames out on USART2 without ever blocking the sample task: the sample
//! task writes whole frames into a queue ([`QueueWriter`], the core's
//! frame sink), the USART2 interrupt at the lowest priority drains it a
//! byte per transmit-empty ([`drain`]). A frame that does not fit in the
//! queue is dropped whole, and the core counts it in its status frames.

use heapless::spsc::Consumer;

use super::serial::Usart2;

/// Bytes the queue holds: about 40 ms of a 2 kHz stream, so a stall of
/// the drain that long loses nothing.
pub use needle_holder::link::QUEUE_BYTES;

/// The sample task's end of the queue (the core's queue sink, see
/// [`needle_holder::link`]).
pub type QueueWriter = needle_holder::link::QueueWriter<'static>;

/// Send what the transmitter takes now, without waiting.
pub fn send_waiting(serial: &mut Usart2, queue: &mut Consumer<'static, u8, QUEUE_BYTES>) {
    needle_holder::link::drain(queue, |byte| serial.write(byte));
}

/// [`send_waiting`], then listen for transmit-empty while bytes wait and
/// stop listening once the queue is empty.
#[cfg(not(feature = "f411-replay"))]
pub fn drain(serial: &mut Usart2, queue: &mut Consumer<'static, u8, QUEUE_BYTES>) {
    send_waiting(serial, queue);
    serial.listen_tx(queue.ready());
}
