//! Scene errors that point at the file, line and key.

use std::fmt;
use std::path::PathBuf;

/// What is wrong, in broad classes (tests and scripts match on these).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneErrorKind {
    /// Not readable or not valid TOML.
    Syntax,
    /// A key the scene format does not have.
    UnknownKey,
    /// A value of the wrong type, a missing required key.
    Type,
    /// A value out of range or inconsistent with the rest of the scene.
    Invalid,
    /// A reference to something that does not exist (material, body, node set, file).
    Reference,
    /// A mesh that cannot be read or has bad elements.
    Mesh,
}

/// An error in a scene, located as precisely as the input allows.
#[derive(Debug, Clone)]
pub struct SceneError {
    pub kind: SceneErrorKind,
    pub file: PathBuf,
    /// 1-based line in `file`, when the key is written there.
    pub line: Option<usize>,
    /// Dotted key, e.g. `material.rubber.G`; empty for the whole file.
    pub key: String,
    /// The `--set KEY=VALUE` that supplied the value, if any.
    pub from_set: Option<String>,
    pub message: String,
}

impl fmt::Display for SceneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "scene `{}`", self.file.display())?;
        if let Some(line) = self.line {
            write!(f, ", line {line}")?;
        }
        if !self.key.is_empty() {
            write!(f, ", key `{}`", self.key)?;
        }
        if let Some(set) = &self.from_set {
            write!(f, " (from --set {set})")?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for SceneError {}
