//! iogate: an I/O gateway for industrial devices.
//!
//! Device profiles describe fields; links own the field buses; the cache keeps every
//! field's latest value; the APIs serve the cache and accept last-value-wins writes.
#![forbid(unsafe_code)]
// A test reads best whole; the length rule is the product's (`clippy.toml`).
#![cfg_attr(test, allow(clippy::too_many_lines))]

pub(crate) mod api;
pub mod app;
pub(crate) mod auth;
pub mod cache;
pub(crate) mod civil;
pub(crate) mod codec;
pub mod config;
pub(crate) mod declare;
pub(crate) mod demo;
pub mod drivers;
pub(crate) mod duration;
pub(crate) mod front_ends;
#[cfg(any(fuzzing, test))]
pub mod fuzz;
pub(crate) mod ha;
pub(crate) mod http_client;
#[cfg(test)]
pub(crate) mod killed;
pub mod link;
pub mod logging;
pub mod map;
pub mod metrics;
pub(crate) mod opcua_variant;
pub mod plan;
pub(crate) mod poller;
pub mod profile;
pub mod reload;
pub mod role;
pub(crate) mod runtime;
pub mod scan;
pub mod service;
pub(crate) mod setup;
pub(crate) mod sim;
pub(crate) mod text;
pub(crate) mod tls;
pub mod transaction;
pub(crate) mod write_log;
pub mod yaml;

/// Exit status of `iogate check` (and `serve`) when the configuration has problems.
pub const EXIT_CONFIG: i32 = 64;
