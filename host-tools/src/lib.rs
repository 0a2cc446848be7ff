//! Host tools for the instrumented needle holder, as a library so the
//! `needle` command and the integration tests share them.

pub mod bench;
pub mod calibrate;
pub mod decode;
pub mod demo;
pub mod detect;
pub mod device;
pub mod diagnose;
pub mod evaluate;
pub mod firmware;
pub mod fit;
pub mod frames;
pub mod input;
pub mod link;
pub mod plot;
pub mod record;
pub mod selftest;
pub mod sim;
pub mod stdout;
pub mod tissue;
pub mod trial;
pub mod twin;
