//! The host tools' analyses, on trials as `needle-io` reads them:
//! simulated insertions with known truth ([`sim`]), the model's parameters
//! fitted from trials ([`fit`]), the core's detectors run on them and
//! scored ([`detect`], [`evaluate`]), the sim-to-real diagnosis
//! ([`diagnose`]) and the plots ([`plot`]). No serial port here.

pub mod detect;
pub mod diagnose;
pub mod evaluate;
pub mod fit;
pub mod page;
pub mod plot;
pub mod sim;
