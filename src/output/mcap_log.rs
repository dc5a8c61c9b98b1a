//! A chunked, zstd-compressed MCAP file of JSON messages with JSON-schema schemas.
//!
//! The file is finished (summary and indices written) by [`RunLog::finish`], or on drop if the
//! run ends early, so a failed run still leaves a valid file. A run killed outright leaves one
//! too: chunks reach the file whole, each followed by a provisional footer (see [`Sink`]).

use crate::precision::Real;
use serde_json::Value;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{Seek, SeekFrom, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

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
    writer: Option<mcap::Writer<Sink>>,
    sink: Sink,
    /// When the open chunk was last closed and put on disk.
    committed: Instant,
    channels: HashMap<String, u16>,
    sequence: u32,
}

/// The open chunk is closed and put on disk at least this often, so that a killed run loses at
/// most this much of its log (chunks also close when they reach their size).
const COMMIT_EVERY: Duration = Duration::from_secs(1);

/// The file under the MCAP writer. The writer's bytes are held until [`Sink::commit`], which
/// writes them and, after them, a footer without a summary, in one positioned write; the next
/// commit writes over that footer. So the file on disk always ends in a footer and a killed run
/// leaves a log that every MCAP reader reads to its last complete chunk (the Python reader's
/// default path needs the footer). `commit` is called between the writer's calls, when what it
/// wrote is whole records.
#[derive(Clone)]
struct Sink(Arc<Mutex<SinkState>>);

struct SinkState {
    file: File,
    pending: Vec<u8>,
    /// Bytes on disk before the provisional footer.
    written: u64,
}

/// A footer record with no summary section (summary_start = 0), then the closing magic.
fn provisional_footer() -> Vec<u8> {
    let mut tail = vec![mcap::records::op::FOOTER];
    tail.extend_from_slice(&20u64.to_le_bytes());
    tail.extend_from_slice(&[0; 20]);
    tail.extend_from_slice(mcap::MAGIC);
    tail
}

impl Sink {
    fn state(&self) -> MutexGuard<'_, SinkState> {
        self.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Puts the pending bytes on disk, followed by a provisional footer unless `last` (the
    /// writer has written its own footer).
    fn commit(&self, last: bool) -> std::io::Result<()> {
        let mut s = self.state();
        if s.pending.is_empty() && !last {
            return Ok(());
        }
        let mut bytes = std::mem::take(&mut s.pending);
        let end = s.written + bytes.len() as u64;
        if !last {
            bytes.extend_from_slice(&provisional_footer());
        }
        s.file.write_all_at(&bytes, s.written)?;
        s.written = end;
        bytes.clear();
        s.pending = bytes;
        if last && s.file.metadata()?.is_file() {
            s.file.set_len(end)?;
        }
        Ok(())
    }
}

impl Write for Sink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.state().pending.extend_from_slice(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The writer asks where it is (for its indexes) and never moves: it writes chunks whole.
impl Seek for Sink {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let s = self.state();
        let here = s.written + s.pending.len() as u64;
        match to {
            SeekFrom::Current(0) | SeekFrom::End(0) => Ok(here),
            SeekFrom::Start(p) if p == here => Ok(here),
            _ => Err(std::io::Error::new(std::io::ErrorKind::Unsupported, "the run log is written front to back")),
        }
    }
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
        let sink = Sink(Arc::new(Mutex::new(SinkState { file, pending: Vec::new(), written: 0 })));
        let write_err = |e: &dyn std::fmt::Display| OutputError::Write { path: path.into(), message: e.to_string() };
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .chunk_size(Some(1 << 20))
            // Chunks are built in memory and written whole (no length patched in afterwards).
            .disable_seeking(true)
            .profile("")
            .library(concat!("bifirst ", env!("CARGO_PKG_VERSION")))
            .create(sink.clone())
            .map_err(|e| write_err(&e))?;
        sink.commit(false).map_err(|e| write_err(&e))?;
        Ok(Self { path: path.into(), writer: Some(writer), sink, committed: Instant::now(), channels: HashMap::new(), sequence: 0 })
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

    fn writer(&mut self) -> Result<&mut mcap::Writer<Sink>, OutputError> {
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
        result.map_err(|e| self.err(e))?;
        self.commit()
    }

    /// Puts on disk what the writer has written whole; at least every [`COMMIT_EVERY`], the
    /// open chunk is closed first.
    fn commit(&mut self) -> Result<(), OutputError> {
        if self.committed.elapsed() >= COMMIT_EVERY {
            self.committed = Instant::now();
            let result = self.writer()?.flush();
            result.map_err(|e| self.err(e))?;
        }
        let result = self.sink.commit(false);
        result.map_err(|e| self.err(e))
    }

    pub fn attach(&mut self, name: &str, media_type: &str, data: &[u8]) -> Result<(), OutputError> {
        let attachment = mcap::Attachment { log_time: 0, create_time: 0, name: name.into(), media_type: media_type.into(), data: data.into() };
        let result = self.writer()?.attach(&attachment);
        result.map_err(|e| self.err(e))?;
        self.commit()
    }

    pub fn metadata(&mut self, name: &str, entries: BTreeMap<String, String>) -> Result<(), OutputError> {
        let result = self.writer()?.write_metadata(&mcap::records::Metadata { name: name.into(), metadata: entries });
        result.map_err(|e| self.err(e))?;
        self.commit()
    }

    /// Writes the summary and indices and closes the file.
    pub fn finish(&mut self) -> Result<(), OutputError> {
        let Some(mut w) = self.writer.take() else { return Ok(()) };
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| w.finish())) {
            Ok(Ok(_summary)) => {
                drop(w);
                self.sink.commit(true).map_err(|e| OutputError::Write { path: self.path.clone(), message: e.to_string() })
            }
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
