//! Reading a run log back: the one reader of every command that takes a log (`summary`, `plot`,
//! `state`, `run --restart`, `sweep-report`, `accuracy`), and of the tests.

use mcap::records::Record;
use serde_json::Value;
use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("cannot read `{path}`: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("`{path}` is not an MCAP file: {why}")]
    NotMcap { path: PathBuf, why: String },
    #[error("`{path}` is damaged at byte {offset}: {message}")]
    Damaged { path: PathBuf, offset: usize, message: String },
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
    fn empty(path: &Path) -> Self {
        Self { path: path.into(), topics: BTreeMap::new(), schemas: BTreeMap::new(), attachments: Vec::new(), metadata: BTreeMap::new(), has_summary: false }
    }

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
        self.messages("/run").first().and_then(|m| m["scene_name"].as_str()).map(String::from).unwrap_or_else(|| self.path.file_stem().map_or_else(|| "run".into(), |s| s.to_string_lossy().into_owned()))
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
///
/// The file is walked record by record with every length checked against the bytes that are
/// there, and chunks are decompressed only as far as their data goes, so that damage (a flipped
/// bit, an edited length) is an error naming the offset, never an allocation the file asks for.
pub fn read_run_topics(path: &Path, keep: impl Fn(&str) -> bool) -> Result<RunRecord, ReadError> {
    let bytes = std::fs::read(path).map_err(|source| ReadError::Io { path: path.into(), source })?;
    let not_mcap = |why: &str| ReadError::NotMcap { path: path.into(), why: why.into() };
    if bytes.is_empty() {
        return Err(not_mcap("the file is empty"));
    }
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(not_mcap("it does not begin with the MCAP magic bytes"));
    }
    let mut reader = Reader { path, keep, record: RunRecord::empty(path), schemas: HashMap::new(), channels: HashMap::new() };
    // A file that ends in a footer says it is whole: a record running past its end is damage
    // there, and the expected end of a log whose writer was killed everywhere else.
    let whole = ends_with_footer(&bytes);
    let mut pos = mcap::MAGIC.len();
    while pos < bytes.len() {
        let (op, body, next) = match frame(&bytes, pos) {
            Some(frame) => frame,
            None if whole => return Err(reader.damaged(pos, "a record runs past the end of the file")),
            None => break,
        };
        let record = mcap::read::parse_record(op, body).map_err(|e| reader.damaged(pos, &e.to_string()))?;
        match record {
            Record::Footer(footer) => {
                reader.record.has_summary = footer.summary_start != 0;
                if &bytes[next..] != mcap::MAGIC {
                    return Err(reader.damaged(next, "the footer is not followed by the closing MCAP magic bytes"));
                }
                break;
            }
            Record::Chunk { header, data } => {
                let records = decompress(&header, &data).map_err(|e| reader.damaged(pos, &format!("chunk: {e}")))?;
                let mut inner = 0;
                while inner < records.len() {
                    let (op, body, next) = frame(&records, inner).ok_or_else(|| reader.damaged(pos, &format!("chunk: a record at {inner} runs past its end")))?;
                    let record = mcap::read::parse_record(op, body).map_err(|e| reader.damaged(pos, &format!("chunk: record at {inner}: {e}")))?;
                    reader.take(record, pos)?;
                    inner = next;
                }
            }
            record => reader.take(record, pos)?,
        }
        pos = next;
    }
    Ok(reader.record)
}

/// The opcode, body and end of the record at `pos`, or `None` when it runs past `bytes`.
fn frame(bytes: &[u8], pos: usize) -> Option<(u8, &[u8], usize)> {
    let header = bytes.get(pos..pos.checked_add(9)?)?;
    let len = usize::try_from(u64::from_le_bytes(header[1..9].try_into().ok()?)).ok()?;
    let end = (pos + 9).checked_add(len)?;
    Some((header[0], bytes.get(pos + 9..end)?, end))
}

/// Whether `bytes` end with a footer record and the closing magic.
fn ends_with_footer(bytes: &[u8]) -> bool {
    const FOOTER_RECORD: usize = 1 + 8 + 20;
    let tail = mcap::MAGIC.len() + FOOTER_RECORD;
    bytes.len() >= mcap::MAGIC.len() + tail && bytes.ends_with(mcap::MAGIC) && frame(bytes, bytes.len() - tail).is_some_and(|(op, body, _)| op == mcap::records::op::FOOTER && body.len() == 20)
}

/// A chunk's records: decompressed into a buffer that grows with the data actually decoded (at
/// most the size the header states), then held against the header's size and CRC.
fn decompress<'a>(header: &mcap::records::ChunkHeader, data: &'a [u8]) -> Result<Cow<'a, [u8]>, String> {
    let size = header.uncompressed_size;
    let records: Cow<'a, [u8]> = match header.compression.as_str() {
        "" => Cow::Borrowed(data),
        "zstd" => {
            let mut out = Vec::with_capacity(usize::try_from(size).unwrap_or(usize::MAX).min(data.len().saturating_mul(8)));
            let decoder = zstd::stream::read::Decoder::with_buffer(data).map_err(|e| e.to_string())?;
            decoder.take(size).read_to_end(&mut out).map_err(|e| format!("zstd: {e}"))?;
            Cow::Owned(out)
        }
        other => return Err(format!("compression `{other}` is not one bifirst reads")),
    };
    if records.len() as u64 != size {
        return Err(format!("{} bytes decompressed, the header says {size}", records.len()));
    }
    if header.uncompressed_crc != 0 && crc32fast::hash(&records) != header.uncompressed_crc {
        return Err("its CRC does not match its records".into());
    }
    Ok(records)
}

/// The walk's state: the schemas and channels seen so far and the record being filled.
struct Reader<'p, K> {
    path: &'p Path,
    keep: K,
    record: RunRecord,
    schemas: HashMap<u16, ChannelSchema>,
    channels: HashMap<u16, (String, u16, String)>,
}

impl<K: Fn(&str) -> bool> Reader<'_, K> {
    fn damaged(&self, offset: usize, message: &str) -> ReadError {
        ReadError::Damaged { path: self.path.into(), offset, message: message.into() }
    }

    /// Files one record (of the data section, a chunk, or the summary) found at `offset`.
    fn take(&mut self, record: Record<'_>, offset: usize) -> Result<(), ReadError> {
        match record {
            Record::Schema { header, data } => {
                let schema = ChannelSchema { name: header.name, encoding: header.encoding, message_encoding: String::new(), data: serde_json::from_slice(&data).unwrap_or(Value::Null) };
                self.schemas.insert(header.id, schema);
            }
            Record::Channel(channel) => {
                self.channels.insert(channel.id, (channel.topic, channel.schema_id, channel.message_encoding));
            }
            Record::Message { header, data } => {
                let Some((topic, schema_id, encoding)) = self.channels.get(&header.channel_id) else {
                    return Err(self.damaged(offset, &format!("a message on channel {}, which no channel record declares", header.channel_id)));
                };
                if !(self.keep)(topic) {
                    return Ok(());
                }
                if let (false, Some(schema)) = (self.record.schemas.contains_key(topic), self.schemas.get(schema_id)) {
                    self.record.schemas.insert(topic.clone(), ChannelSchema { message_encoding: encoding.clone(), ..schema.clone() });
                }
                let list = self.record.topics.entry(topic.clone()).or_default();
                let value = serde_json::from_slice(&data).map_err(|e| ReadError::Json { path: self.path.into(), topic: topic.clone(), index: list.len(), message: e.to_string() })?;
                list.push(value);
            }
            Record::Attachment { header, .. } => self.record.attachments.push(header.name),
            Record::Metadata(metadata) => {
                self.record.metadata.insert(metadata.name, metadata.metadata);
            }
            _ => {}
        }
        Ok(())
    }
}
