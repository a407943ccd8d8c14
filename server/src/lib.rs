//! iogate: an I/O gateway for industrial devices.
//!
//! Device profiles describe fields; links own the field buses; the cache keeps every
//! field's latest value; the APIs serve the cache and accept last-value-wins writes.
#![forbid(unsafe_code)]

pub mod api;
pub mod app;
pub mod auth;
pub mod cache;
pub mod codec;
pub mod config;
pub mod declare;
pub mod demo;
pub mod duration;
pub mod link;
pub mod logging;
pub mod map;
pub mod metrics;
pub mod plan;
pub mod poller;
pub mod profile;
pub mod runtime;
pub mod service;
pub mod sim;
pub mod text;
pub mod tls;
pub mod transaction;
pub mod write_log;
pub mod yaml;

/// Exit status of `iogate check` (and `serve`) when the configuration has problems.
pub const EXIT_CONFIG: i32 = 64;
