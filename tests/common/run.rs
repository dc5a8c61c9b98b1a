// Shared by the test files through `#[path]`: run a scene into a temporary MCAP and read it back.
#![allow(dead_code)]
use bifirst::run::{run_scene, Silent};
use bifirst::scene::load_scene;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub fn scene_path(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes").join(format!("{name}.toml"))
}

pub fn temp_path(file: &str) -> PathBuf {
    Path::new(env!("CARGO_TARGET_TMPDIR")).join(file)
}

/// Everything read back from a run log.
pub struct Log {
    /// Messages per topic, in order.
    pub topics: BTreeMap<String, Vec<Value>>,
    /// Schema (name, JSON) per topic.
    pub schemas: BTreeMap<String, (String, Value)>,
    pub attachments: Vec<String>,
    pub metadata: Vec<String>,
    pub record: bifirst::output::RunRecord,
}

impl Log {
    pub fn series(&self, topic: &str, field: &str) -> Vec<f64> {
        self.topics[topic].iter().map(|m| m[field].as_f64().unwrap_or_else(|| panic!("{topic}.{field} missing"))).collect()
    }
    pub fn vectors(&self, topic: &str, field: &str) -> Vec<Vec<f64>> {
        self.topics[topic].iter().map(|m| m[field].as_array().expect("array").iter().map(|x| x.as_f64().unwrap()).collect()).collect()
    }
}

pub fn read_log(path: &Path) -> Log {
    let record = bifirst::output::read_run(path).expect("the log reads back");
    assert!(record.has_summary, "the file has a summary");
    let mut schemas = BTreeMap::new();
    for (topic, schema) in &record.schemas {
        assert_eq!(schema.encoding, "jsonschema");
        assert_eq!(schema.message_encoding, "json");
        schemas.insert(topic.clone(), (schema.name.clone(), schema.data.clone()));
    }
    let metadata = record.metadata.keys().cloned().collect();
    Log { topics: record.topics.clone(), schemas, attachments: record.attachments.clone(), metadata, record }
}

/// Runs `scene` with overrides into `<tag>.mcap` and reads the log back.
pub fn run(scene: &str, sets: &[&str], tag: &str) -> Log {
    run_with(&scene_path(scene), sets, tag, &Default::default())
}

/// Runs the scene file at `path` with overrides and run options into `<tag>.mcap`.
pub fn run_with(path: &Path, sets: &[&str], tag: &str, options: &bifirst::run::RunOptions) -> Log {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let loaded = load_scene(path, &sets).expect("scene loads");
    let out = temp_path(&format!("{tag}.mcap"));
    run_scene(&loaded, &out, options, &mut Silent).expect("run succeeds");
    read_log(&out)
}
