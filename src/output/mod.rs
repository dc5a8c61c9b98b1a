//! Outputs: the MCAP run log (see doc/mcap.md for the contract).

pub mod mcap_log;
pub mod schemas;

pub use mcap_log::{OutputError, RunLog};
