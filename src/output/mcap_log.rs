//! A chunked, zstd-compressed MCAP file of JSON messages with JSON-schema schemas.
//!
//! The file is finished (summary and indices written) by [`RunLog::finish`], or on drop if the
//! run ends early, so a failed run still leaves a valid file.

use crate::precision::Real;
use serde_json::Value;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("cannot create `{path}`: {source}")]
    Create { path: PathBuf, source: std::io::Error },
    #[error("MCAP write to `{path}` failed: {message}")]
    Write { path: PathBuf, message: String },
    #[error("`{path}` is being written by another bifirst run; choose another --out")]
    Busy { path: PathBuf },
}

pub struct RunLog {
    path: PathBuf,
    writer: Option<mcap::Writer<BufWriter<File>>>,
    channels: HashMap<String, u16>,
    sequence: u32,
}

/// Simulated time in nanoseconds (MCAP log time), so Foxglove's timeline is simulated time.
fn log_time(t: Real) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

/// A message as the log stores it (JSON).
pub fn encode(message: &impl serde::Serialize) -> Vec<u8> {
    serde_json::to_vec(message).expect("message serializes")
}

impl RunLog {
    pub fn create(path: &Path) -> Result<Self, OutputError> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|source| OutputError::Create { path: path.into(), source })?;
        }
        let file = Self::open_exclusive(path)?;
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(1 << 20))
            .profile("")
            .library(concat!("bifirst ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(|e| OutputError::Write { path: path.into(), message: e.to_string() })?;
        Ok(Self { path: path.into(), writer: Some(writer), channels: HashMap::new(), sequence: 0 })
    }

    /// Opens `path` for writing under an exclusive lock, held until the log is closed, and only
    /// then empties it: a second run given the same `--out` fails and leaves the first run's
    /// file alone (two runs writing one file left it unreadable). Where the file system has no
    /// locks, the file is written without one.
    fn open_exclusive(path: &Path) -> Result<File, OutputError> {
        let create = |source| OutputError::Create { path: path.into(), source };
        let file = std::fs::OpenOptions::new().write(true).create(true).truncate(false).open(path).map_err(create)?;
        match file.try_lock() {
            Ok(()) | Err(std::fs::TryLockError::Error(_)) => {}
            Err(std::fs::TryLockError::WouldBlock) => return Err(OutputError::Busy { path: path.into() }),
        }
        // Devices (`/dev/null`, `/dev/full`) cannot be truncated, and need not be.
        if file.metadata().map_err(create)?.is_file() {
            file.set_len(0).map_err(create)?;
        }
        Ok(file)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The error of a failed write. The writer is abandoned: after an I/O error mcap's writer
    /// is left inconsistent and would panic when it finishes, in its own `Drop` too (caught by
    /// `--out /dev/full`, which aborted the process). A later call reports that the log is gone.
    fn err(&mut self, e: impl std::fmt::Display) -> OutputError {
        if let Some(w) = self.writer.take() {
            std::mem::forget(w);
        }
        OutputError::Write { path: self.path.clone(), message: e.to_string() }
    }

    fn writer(&mut self) -> Result<&mut mcap::Writer<BufWriter<File>>, OutputError> {
        let path = self.path.clone();
        self.writer.as_mut().ok_or(OutputError::Write { path, message: "the log is already finished".into() })
    }

    /// Registers a JSON channel with its JSON schema.
    pub fn add_channel(&mut self, topic: &str, schema_name: &str, schema: &Value) -> Result<(), OutputError> {
        let data = serde_json::to_vec(schema).expect("schema serializes");
        let w = self.writer()?;
        let result = w.add_schema(schema_name, "jsonschema", &data).and_then(|s| w.add_channel(s, topic, "json", &BTreeMap::new()));
        let id = result.map_err(|e| self.err(e))?;
        self.channels.insert(topic.to_string(), id);
        Ok(())
    }

    /// Writes one message on a registered channel at simulated time `t`.
    pub fn write(&mut self, topic: &str, t: Real, message: &impl serde::Serialize) -> Result<(), OutputError> {
        self.write_encoded(topic, t, &encode(message))
    }

    /// Writes one message already [`encode`]d (many are encoded in parallel, written in order).
    pub fn write_encoded(&mut self, topic: &str, t: Real, data: &[u8]) -> Result<(), OutputError> {
        let channel_id = *self.channels.get(topic).unwrap_or_else(|| panic!("channel {topic} not registered"));
        let sequence = self.sequence;
        self.sequence += 1;
        let header = mcap::records::MessageHeader { channel_id, sequence, log_time: log_time(t), publish_time: log_time(t) };
        let result = self.writer()?.write_to_known_channel(&header, data);
        result.map_err(|e| self.err(e))
    }

    pub fn attach(&mut self, name: &str, media_type: &str, data: &[u8]) -> Result<(), OutputError> {
        let attachment = mcap::Attachment { log_time: 0, create_time: 0, name: name.into(), media_type: media_type.into(), data: data.into() };
        let result = self.writer()?.attach(&attachment);
        result.map_err(|e| self.err(e))
    }

    pub fn metadata(&mut self, name: &str, entries: BTreeMap<String, String>) -> Result<(), OutputError> {
        let result = self.writer()?.write_metadata(&mcap::records::Metadata { name: name.into(), metadata: entries });
        result.map_err(|e| self.err(e))
    }

    /// Writes the summary and indices and closes the file.
    pub fn finish(&mut self) -> Result<(), OutputError> {
        let Some(mut w) = self.writer.take() else { return Ok(()) };
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| w.finish())) {
            Ok(Ok(_summary)) => Ok(()),
            Ok(Err(e)) => {
                std::mem::forget(w);
                Err(self.err(e))
            }
            Err(_) => {
                std::mem::forget(w);
                Err(self.err("the MCAP writer failed while closing the file"))
            }
        }
    }
}

impl Drop for RunLog {
    fn drop(&mut self) {
        let _ = self.finish();
    }
}
