//! Reading recordings back (with the `mcap` crate), including files cut short by a crash.

use std::collections::BTreeMap;
use std::path::Path;

use crate::raw::{self, Chunk, PortInfo};

/// A recording read into memory.
#[derive(Debug)]
pub struct Recording {
    bytes: Vec<u8>,
}

/// A recording that cannot be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file cannot be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// Not an MCAP file at all.
    #[error("{0}: not an MCAP file ({1})")]
    NotMcap(String, String),
    /// No such raw channel.
    #[error("no raw serial channel {wanted} in the recording; it has: {have}{left_out}")]
    NoPort {
        /// What was asked for.
        wanted: String,
        /// What there is.
        have: String,
        /// `" (the recording left out: PATTERNS)"` when it was made with `--record-exclude`,
        /// else empty.
        left_out: String,
    },
}

/// One message of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Message {
    /// Topic.
    pub topic: String,
    /// Schema name (empty: none).
    pub schema: String,
    /// Log time, Unix nanoseconds.
    pub log_time: u64,
    /// The payload.
    pub data: Vec<u8>,
}

/// One raw serial channel's chunks.
#[derive(Debug, Clone, PartialEq)]
pub struct RawStream {
    /// The port.
    pub port: PortInfo,
    /// The topic.
    pub topic: String,
    /// `(log time, direction, bytes)`; a baud change is [`raw::Dir::Baud`] with the rate as
    /// 4 bytes little-endian.
    pub chunks: Vec<(u64, raw::Dir, Vec<u8>)>,
}

impl RawStream {
    /// All bytes the device sent, in order.
    pub fn rx_bytes(&self) -> Vec<u8> {
        self.chunks
            .iter()
            .filter(|c| c.1 == raw::Dir::Rx)
            .flat_map(|c| c.2.iter().copied())
            .collect()
    }
}

/// Where reading stopped early: a crash left the file cut short.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Truncation(pub Option<String>);

impl Recording {
    /// Read a file.
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let bytes = std::fs::read(path).map_err(|source| ReadError::Io {
            path: path.display().to_string(),
            source,
        })?;
        if !bytes.starts_with(mcap::MAGIC) {
            return Err(ReadError::NotMcap(
                path.display().to_string(),
                "no MCAP magic at the start".into(),
            ));
        }
        Ok(Self { bytes })
    }

    /// Every message in file order, and why reading stopped early (a crashed recorder's file
    /// ends in the middle of a chunk: the complete chunks before it are all returned).
    pub fn messages(&self) -> (Vec<Message>, Truncation) {
        let mut out = Vec::new();
        let stream = match mcap::MessageStream::new(&self.bytes) {
            Ok(s) => s,
            Err(e) => return (out, Truncation(Some(e.to_string()))),
        };
        for m in stream {
            match m {
                Ok(m) => out.push(Message {
                    topic: m.channel.topic.clone(),
                    schema: m
                        .channel
                        .schema
                        .as_ref()
                        .map(|s| s.name.clone())
                        .unwrap_or_default(),
                    log_time: m.log_time,
                    data: m.data.into_owned(),
                }),
                Err(e) => return (out, Truncation(Some(e.to_string()))),
            }
        }
        (out, Truncation(None))
    }

    /// Every channel: topic → (schema name, metadata).
    pub fn channels(&self) -> BTreeMap<String, (String, BTreeMap<String, String>)> {
        let mut out = BTreeMap::new();
        let Ok(stream) = mcap::MessageStream::new(&self.bytes) else {
            return out;
        };
        for m in stream.map_while(Result::ok) {
            out.entry(m.channel.topic.clone()).or_insert_with(|| {
                (
                    m.channel
                        .schema
                        .as_ref()
                        .map(|s| s.name.clone())
                        .unwrap_or_default(),
                    m.channel.metadata.clone(),
                )
            });
        }
        out
    }

    /// Every raw serial channel with its chunks.
    pub fn raw_streams(&self) -> Vec<RawStream> {
        let mut by_topic: BTreeMap<String, RawStream> = BTreeMap::new();
        let Ok(stream) = mcap::MessageStream::new(&self.bytes) else {
            return Vec::new();
        };
        for m in stream.map_while(Result::ok) {
            if m.channel.message_encoding != raw::ENCODING {
                continue;
            }
            let Some(port) = PortInfo::from_metadata(&m.channel.metadata) else {
                continue;
            };
            let entry = by_topic
                .entry(m.channel.topic.clone())
                .or_insert_with(|| RawStream {
                    port,
                    topic: m.channel.topic.clone(),
                    chunks: Vec::new(),
                });
            match raw::parse(&m.data) {
                Some(Chunk::Bytes(d, b)) => entry.chunks.push((m.log_time, d, b.to_vec())),
                Some(Chunk::Baud(b)) => {
                    entry
                        .chunks
                        .push((m.log_time, raw::Dir::Baud, b.to_le_bytes().to_vec()));
                }
                None => {}
            }
        }
        by_topic.into_values().collect()
    }

    /// The `ima` metadata record the recorder writes first (the session's `name`, the
    /// `version`, and under `exclude` the patterns of topics left out of the file), if the file
    /// has one. Found in files cut short by a crash too.
    pub fn ima_metadata(&self) -> Option<BTreeMap<String, String>> {
        mcap::read::LinearReader::new(&self.bytes)
            .ok()?
            .map_while(Result::ok)
            .find_map(|r| match r {
                mcap::records::Record::Metadata(m) if m.name == "ima" => Some(m.metadata),
                _ => None,
            })
    }

    /// The topic patterns the recorder was told to leave out (`--record-exclude`), as given,
    /// comma-separated; `None` when it left nothing out.
    pub fn left_out(&self) -> Option<String> {
        self.ima_metadata()?.remove("exclude")
    }

    /// The raw stream whose topic, device or port is `name`.
    pub fn raw_stream(&self, name: &str) -> Result<RawStream, ReadError> {
        let all = self.raw_streams();
        let have = all
            .iter()
            .map(|s| format!("{} ({})", s.topic, s.port.port))
            .collect::<Vec<_>>()
            .join(", ");
        all.into_iter()
            .find(|s| {
                s.topic == name
                    || s.topic.trim_start_matches('/') == name
                    || s.port.port == name
                    || format!("{}/{}", s.port.robot, s.port.device) == name
            })
            .ok_or_else(|| ReadError::NoPort {
                wanted: name.to_owned(),
                have: if have.is_empty() { "none".into() } else { have },
                left_out: self
                    .left_out()
                    .map(|p| format!(" (the recording left out: {p})"))
                    .unwrap_or_default(),
            })
    }
}
