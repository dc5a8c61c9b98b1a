//! Reading a run log back (for `bifirst plot` and `bifirst summary`, and the tests).

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("cannot read `{path}`: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("`{path}` is not a valid MCAP file: {message}")]
    Mcap { path: PathBuf, message: String },
    #[error("`{path}`: topic `{topic}` message {index} is not JSON: {message}")]
    Json { path: PathBuf, topic: String, index: usize, message: String },
    #[error("`{path}` has no `{topic}` channel; is it a bifirst run log?")]
    Missing { path: PathBuf, topic: String },
}

/// The schema of a channel as written.
#[derive(Debug, Clone)]
pub struct ChannelSchema {
    pub name: String,
    pub encoding: String,
    pub message_encoding: String,
    pub data: Value,
}

/// Everything in a run log.
#[derive(Debug, Clone)]
pub struct RunRecord {
    pub path: PathBuf,
    /// Messages per topic, in log order.
    pub topics: BTreeMap<String, Vec<Value>>,
    pub schemas: BTreeMap<String, ChannelSchema>,
    pub attachments: Vec<String>,
    /// Metadata records by name.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// Whether the file ends with its summary section (a finished log).
    pub has_summary: bool,
}

impl RunRecord {
    /// Messages of a topic (empty when the run has none).
    pub fn messages(&self, topic: &str) -> &[Value] {
        self.topics.get(topic).map_or(&[], Vec::as_slice)
    }

    /// Messages of a topic that must be there.
    pub fn require(&self, topic: &str) -> Result<&[Value], ReadError> {
        self.topics.get(topic).map(Vec::as_slice).ok_or_else(|| ReadError::Missing { path: self.path.clone(), topic: topic.into() })
    }

    /// A number field of every message of a topic (NaN where it is missing).
    pub fn series(&self, topic: &str, field: &str) -> Vec<f64> {
        self.messages(topic).iter().map(|m| m[field].as_f64().unwrap_or(f64::NAN)).collect()
    }

    /// Topics under a prefix such as `/probe/`, without the prefix.
    pub fn names_under(&self, prefix: &str) -> Vec<String> {
        self.topics.keys().filter_map(|k| k.strip_prefix(prefix)).map(String::from).collect()
    }

    /// The scene name from `/run`, else the file stem.
    pub fn name(&self) -> String {
        self.messages("/run").first().and_then(|m| m["scene_name"].as_str()).map(String::from).unwrap_or_else(|| {
            self.path.file_stem().map_or_else(|| "run".into(), |s| s.to_string_lossy().into_owned())
        })
    }
}

/// Reads every message of a run log. A log without its summary section (a killed process, a
/// crashed machine) is read as far as it goes: every message of its complete chunks, up to the
/// first record the cut left unfinished.
pub fn read_run(path: &Path) -> Result<RunRecord, ReadError> {
    read_run_topics(path, |_| true)
}

/// [`read_run`] keeping only the messages of the topics `keep` accepts (the others are not
/// decoded: a restart needs `/run` and `/state`, not every body's every step).
pub fn read_run_topics(path: &Path, keep: impl Fn(&str) -> bool) -> Result<RunRecord, ReadError> {
    let bytes = std::fs::read(path).map_err(|source| ReadError::Io { path: path.into(), source })?;
    let mcap_err = |e: mcap::McapError| ReadError::Mcap { path: path.into(), message: e.to_string() };
    // A finished log ends with its footer; only then is a broken record an error.
    let summary = mcap::Summary::read(&bytes).ok().flatten();
    let mut topics: BTreeMap<String, Vec<Value>> = BTreeMap::new();
    let mut schemas = BTreeMap::new();
    for message in mcap::MessageStream::new(&bytes).map_err(mcap_err)? {
        let message = match message {
            Ok(message) => message,
            Err(_) if summary.is_none() => break,
            Err(e) => return Err(mcap_err(e)),
        };
        let topic = message.channel.topic.clone();
        if !keep(&topic) {
            continue;
        }
        if let Some(schema) = &message.channel.schema {
            schemas.entry(topic.clone()).or_insert_with(|| ChannelSchema {
                name: schema.name.clone(),
                encoding: schema.encoding.clone(),
                message_encoding: message.channel.message_encoding.clone(),
                data: serde_json::from_slice(&schema.data).unwrap_or(Value::Null),
            });
        }
        let list = topics.entry(topic.clone()).or_default();
        let value = serde_json::from_slice(&message.data).map_err(|e| ReadError::Json { path: path.into(), topic, index: list.len(), message: e.to_string() })?;
        list.push(value);
    }
    let has_summary = summary.is_some();
    let (mut attachments, mut metadata) = (Vec::new(), BTreeMap::new());
    if let Some(summary) = summary {
        attachments = summary.attachment_indexes.iter().map(|a| a.name.clone()).collect();
        for index in &summary.metadata_indexes {
            let record = mcap::read::metadata(&bytes, index).map_err(mcap_err)?;
            metadata.insert(record.name, record.metadata);
        }
    }
    Ok(RunRecord { path: path.into(), topics, schemas, attachments, metadata, has_summary })
}
