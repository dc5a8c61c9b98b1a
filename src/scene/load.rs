//! Reading a scene: TOML text -> `--set` overrides -> typed [`Scene`] -> validation.

use super::error::{SceneError, SceneErrorKind};
use super::packing;
use super::types::Scene;
use super::validate::validate;
use std::path::{Path, PathBuf};

/// Sections whose entries are named by the user; `--set` may not invent new entries there.
const NAMED_SECTIONS: [&str; 5] = ["material", "body", "boundary", "probe", "obstacle"];

/// A validated scene together with what is needed to point errors back at the input.
#[derive(Debug, Clone)]
pub struct LoadedScene {
    pub scene: Scene,
    /// Scene name (the `name` key, else the file stem).
    pub name: String,
    pub path: PathBuf,
    /// The resolved scene after `--set`, with defaults filled in, as TOML text.
    pub resolved_toml: String,
    source: String,
    overrides: Vec<(String, String)>,
}

impl LoadedScene {
    /// Directory that relative paths in the scene (mesh files) are resolved against.
    pub fn base_dir(&self) -> &Path {
        self.path.parent().unwrap_or(Path::new("."))
    }

    /// An error about `key`, located in the file or attributed to the `--set` that wrote it.
    pub fn error(&self, kind: SceneErrorKind, key: &str, message: impl Into<String>) -> SceneError {
        locate(&self.path, &self.source, &self.overrides, kind, key, message.into())
    }
}

/// Reads and validates a scene file, applying `--set KEY=VALUE` overrides first.
pub fn load_scene(path: &Path, sets: &[String]) -> Result<LoadedScene, SceneError> {
    let source = std::fs::read_to_string(path).map_err(|e| SceneError { kind: SceneErrorKind::Reference, file: path.to_path_buf(), line: None, key: String::new(), from_set: None, message: format!("cannot read the scene file: {e}.") })?;
    parse_scene(path, source, sets)
}

/// Like [`load_scene`] with the file's text already in hand (`path` is used for messages and
/// for resolving relative mesh paths).
pub fn parse_scene(path: &Path, source: String, sets: &[String]) -> Result<LoadedScene, SceneError> {
    let mut table: toml::Table = toml::from_str(&source).map_err(|e| {
        let line = e.span().map(|s| line_of(&source, s.start));
        SceneError { kind: SceneErrorKind::Syntax, file: path.to_path_buf(), line, key: String::new(), from_set: None, message: format!("not valid TOML: {}", toml_message(e.message().trim_end())) }
    })?;
    let mut overrides = Vec::new();
    for set in sets {
        let key = apply_set(&mut table, set).map_err(|(key, message)| SceneError {
            kind: if message.starts_with("there is no") { SceneErrorKind::UnknownKey } else { SceneErrorKind::Type },
            file: path.to_path_buf(),
            line: None,
            key,
            from_set: Some(set.clone()),
            message,
        })?;
        overrides.push((key, set.clone()));
    }
    let err = |kind, key: String, message: String| locate(path, &source, &overrides, kind, &key, message);
    let mut scene: Scene = serde_path_to_error::deserialize(toml::Value::Table(table.clone())).map_err(|e| {
        // For an unknown field the path already ends with that field's name.
        let key = dotted(e.path());
        let inner = e.into_inner().to_string();
        let mut message = inner.lines().next().unwrap_or_default().trim().to_string();
        // A name given as another type: serde says only "unit variant"; the names come from
        // the error a string that is no name gets.
        if message.contains("unit variant") {
            message = match variant_names(&table, &key) {
                Some(names) => format!("expected a name in quotes, {names}"),
                None => "expected a name in quotes".into(),
            };
        }
        let kind = if message.starts_with("unknown field") { SceneErrorKind::UnknownKey } else { SceneErrorKind::Type };
        err(kind, key, format!("{message}."))
    })?;
    // The packing stays a `[packing]` section in the resolved scene: the seed reproduces it.
    let resolved_toml = toml::to_string(&scene).expect("a deserialized scene serializes");
    packing::expand(&mut scene).map_err(|(kind, key, message)| err(kind, key, message))?;
    validate(&scene).map_err(|(kind, key, message)| err(kind, key, message))?;
    let name = scene.name.clone().unwrap_or_else(|| path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "scene".into()));
    Ok(LoadedScene { scene, name, path: path.to_path_buf(), resolved_toml, source, overrides })
}

/// The names an enum-valued `key` takes ("one of `a`, `b`"), from the error of the scene with
/// an empty string there.
fn variant_names(table: &toml::Table, key: &str) -> Option<String> {
    let mut probe = table.clone();
    let parts: Vec<&str> = key.split('.').collect();
    let (last, path) = parts.split_last()?;
    let mut node = &mut probe;
    for part in path {
        node = node.get_mut(*part)?.as_table_mut()?;
    }
    node.insert(last.to_string(), toml::Value::String(String::new()));
    let error = serde_path_to_error::deserialize::<_, Scene>(toml::Value::Table(probe)).err()?;
    let message = error.into_inner().to_string();
    message.lines().next()?.split_once("expected ").map(|(_, names)| names.trim().to_string()).filter(|n| n.starts_with("one of"))
}

/// The TOML parser's message, with integers beyond its range said so.
fn toml_message(message: &str) -> String {
    if message.contains("as i128") {
        format!("{message} (TOML integers are 64-bit: at most {})", i64::MAX)
    } else {
        message.to_string()
    }
}

fn dotted(path: &serde_path_to_error::Path) -> String {
    use serde_path_to_error::Segment;
    let parts: Vec<String> = path
        .iter()
        .filter_map(|s| match s {
            Segment::Map { key } => Some(key.clone()),
            Segment::Seq { index } => Some(index.to_string()),
            _ => None,
        })
        .collect();
    parts.join(".")
}

/// Applies one `KEY=VALUE`; returns the key, or (key, message) on failure.
fn apply_set(table: &mut toml::Table, set: &str) -> Result<String, (String, String)> {
    let Some((key, value)) = set.split_once('=') else {
        return Err((String::new(), "expected KEY=VALUE.".into()));
    };
    let key = key.trim().to_string();
    let value: toml::Value = toml::from_str::<toml::Table>(&format!("v = {}", value.trim())).ok().and_then(|mut t| t.remove("v")).ok_or_else(|| {
        let value = value.trim();
        let digits = value.strip_prefix(['+', '-']).unwrap_or(value);
        if !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit() || b == b'_') {
            (key.clone(), format!("`{value}` is beyond TOML's integers (64-bit: at most {}).", i64::MAX))
        } else {
            (key.clone(), format!("`{value}` is not a TOML literal (strings need quotes, e.g. \"lvf\")."))
        }
    })?;
    let parts: Vec<&str> = key.split('.').collect();
    if parts.iter().any(|p| p.is_empty()) {
        return Err((key.clone(), "the key has an empty part.".into()));
    }
    let mut node = table;
    for (depth, part) in parts[..parts.len() - 1].iter().enumerate() {
        let in_named = depth == 1 && NAMED_SECTIONS.contains(&parts[0]);
        if in_named && !node.contains_key(*part) {
            let section = parts[0];
            return Err((key.clone(), format!("there is no {section} named `{part}` in the scene.")));
        }
        let entry = node.entry(part.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
        node = match entry {
            toml::Value::Table(t) => t,
            _ => return Err((key.clone(), format!("there is no key below `{}`: it is not a table.", parts[..=depth].join(".")))),
        };
    }
    node.insert(parts[parts.len() - 1].to_string(), value);
    Ok(key)
}

fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].bytes().filter(|&b| b == b'\n').count() + 1
}

/// Finds the line of the deepest part of `key` written in `source`, or the `--set` behind it.
fn locate(path: &Path, source: &str, overrides: &[(String, String)], kind: SceneErrorKind, key: &str, message: String) -> SceneError {
    let from_set = overrides.iter().rev().find(|(k, _)| key == k || key.starts_with(&format!("{k}."))).map(|(_, set)| set.clone());
    let line = if from_set.is_some() { None } else { key_line(source, key) };
    SceneError { kind, file: path.to_path_buf(), line, key: key.to_string(), from_set, message }
}

fn key_line(source: &str, key: &str) -> Option<usize> {
    use toml::de::{DeTable, DeValue};
    let doc = DeTable::parse(source).ok()?;
    let mut value: &DeValue = &DeValue::Table(doc.into_inner());
    let mut found = None;
    for part in key.split('.').filter(|p| !p.is_empty()) {
        let next = match value {
            DeValue::Table(t) => t.iter().find(|(k, _)| k.get_ref().as_ref() == part).map(|(k, v)| (k.span().start, v)),
            DeValue::Array(a) => part.parse::<usize>().ok().and_then(|i| a.get(i)).map(|v| (v.span().start, v)),
            _ => None,
        };
        let Some((start, v)) = next else { break };
        found = Some(start);
        value = v.get_ref();
    }
    found.map(|s| line_of(source, s))
}
