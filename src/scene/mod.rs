//! Scene files (TOML): the types, loading with `--set` overrides, and validation.
//!
//! Every bad input becomes a [`SceneError`] that names the file, the line (when the key is in
//! the file) and the dotted key.

mod error;
mod load;
mod packing;
mod types;
mod validate;

pub use error::{SceneError, SceneErrorKind};
pub use load::{load_scene, parse_scene, LoadedScene};
pub use packing::grain_name;
pub use types::*;
pub use validate::LARGEST_INPUT;
