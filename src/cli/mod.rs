//! The commands of the `bifirst` binary, one module per family; `main.rs` parses the command
//! line and hands each command to its module.

pub(crate) mod args;
pub(crate) mod bench;
pub(crate) mod logs;
pub(crate) mod progress;
pub(crate) mod run;
pub(crate) mod studies;
