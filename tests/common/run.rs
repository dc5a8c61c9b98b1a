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
    let bytes = std::fs::read(path).expect("log exists");
    let mut topics: BTreeMap<String, Vec<Value>> = BTreeMap::new();
    let mut schemas = BTreeMap::new();
    for message in mcap::MessageStream::new(&bytes).expect("valid mcap") {
        let message = message.expect("valid message");
        let topic = message.channel.topic.clone();
        let schema = message.channel.schema.as_ref().expect("every channel has a schema");
        assert_eq!(schema.encoding, "jsonschema");
        assert_eq!(message.channel.message_encoding, "json");
        schemas.entry(topic.clone()).or_insert_with(|| (schema.name.clone(), serde_json::from_slice(&schema.data).expect("schema is JSON")));
        topics.entry(topic).or_default().push(serde_json::from_slice(&message.data).expect("message is JSON"));
    }
    let summary = mcap::Summary::read(&bytes).expect("summary readable").expect("the file has a summary");
    let attachments = summary.attachment_indexes.iter().map(|a| a.name.clone()).collect();
    let metadata = summary.metadata_indexes.iter().map(|m| m.name.clone()).collect();
    Log { topics, schemas, attachments, metadata }
}

/// Runs `scene` with overrides into `<tag>.mcap` and reads the log back.
pub fn run(scene: &str, sets: &[&str], tag: &str) -> Log {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    let loaded = load_scene(&scene_path(scene), &sets).expect("scene loads");
    let out = temp_path(&format!("{tag}.mcap"));
    run_scene(&loaded, &out, &mut Silent).expect("run succeeds");
    read_log(&out)
}
