//! Outputs: the MCAP run log (see doc/mcap.md for the contract) with its Foxglove view, VTU
//! files for ParaView, and what reads a run log back: plots and the summary table.

pub mod contacts;
pub mod foxglove;
pub mod mcap_log;
pub mod messages;
pub mod plot;
pub mod read;
pub mod run_summary;
pub mod schemas;
pub mod summary;
pub mod vtu;

pub use mcap_log::{encode, OutputError, RunLog};
pub use read::{read_run, read_run_topics, ReadError, RunRecord};
pub use vtu::VtuSeries;

/// `n` and the noun in the number it calls for: "1 body", "3 bodies".
pub fn counted(n: usize, one: &str, many: &str) -> String {
    format!("{n} {}", if n == 1 { one } else { many })
}
