//! The device's side of the host tools: the frames it sends and how they
//! are decoded ([`frames`], [`decode`]), the serial link both ways
//! ([`link`]), the commands to a device ([`device`], [`calibrate`],
//! [`selftest`]), recording trials ([`record`]), the files the tools read
//! and write ([`input`], [`trial`], [`tissue`]), the host twin of the
//! device loop ([`twin`]), and how every command writes ([`stdout`]).
//! No analysis here: that is `needle-analysis`, which builds on this.

pub mod calibrate;
pub mod decode;
pub mod device;
pub mod frames;
pub mod input;
pub mod link;
pub mod record;
pub mod selftest;
pub mod stdout;
pub mod tissue;
pub mod trial;
pub mod twin;
