//! ROS 2 MCAP bags, as `ros2 bag record` (rosbag2's MCAP storage) writes them and Foxglove reads
//! them: `ros2msg` schemas with every dependent definition embedded, `cdr` payloads (the 4-byte
//! encapsulation header, then little-endian CDR from `cdr-encoding`, the serialiser ros2-client
//! uses), log and publish times in nanoseconds.
//!
//! [`read_bag`] reads what it can: a truncated or corrupt file yields the messages before the
//! damage and says where it stopped. Messages come back in log-time order. [`BagWriter`] writes
//! zstd-compressed chunks with the summary and indexes; [`BagWriter::finish`] must be called to
//! finish the file (the caller does it on every path, Ctrl-C included).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};

use byteorder::{BigEndian, LittleEndian};
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::msgs::definitions;

/// The encapsulation header of a little-endian CDR payload (CDR_LE, options 0).
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// What can go wrong with a bag.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// The file cannot be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The file is not an MCAP file at all.
    #[error("{path}: not an MCAP file ({reason})")]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// What the MCAP reader said.
        reason: String,
    },
    /// Writing MCAP records failed.
    #[error("{path}: cannot write MCAP: {reason}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What the MCAP writer said.
        reason: String,
    },
    /// A type has no known ROS 2 definition.
    #[error("no ROS 2 definition of `{0}` is known to ttball")]
    UnknownType(String),
    /// A message could not be encoded as CDR.
    #[error("cannot encode a `{type_name}` message as CDR: {reason}")]
    Encode {
        /// The message type.
        type_name: String,
        /// What the encoder said.
        reason: String,
    },
}

/// Why a payload could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// Shorter than the encapsulation header.
    #[error("payload of {0} bytes is too short for CDR")]
    TooShort(usize),
    /// Not plain CDR (e.g. XCDR2 or PL_CDR).
    #[error("unsupported CDR encapsulation {0:02x}{1:02x}")]
    Encapsulation(u8, u8),
    /// The bytes do not decode as the expected type.
    #[error("{0}")]
    Cdr(String),
}

/// Encodes a message as a ROS 2 CDR payload (little endian, with the encapsulation header).
pub fn encode<T: Serialize>(type_name: &str, msg: &T) -> Result<Vec<u8>, BagError> {
    let body = cdr_encoding::to_vec::<T, LittleEndian>(msg).map_err(|e| BagError::Encode {
        type_name: type_name.to_string(),
        reason: e.to_string(),
    })?;
    let mut out = Vec::with_capacity(body.len() + 4);
    out.extend_from_slice(&CDR_LE);
    out.extend_from_slice(&body);
    Ok(out)
}

/// Decodes a ROS 2 CDR payload (either byte order).
pub fn decode<T: DeserializeOwned>(payload: &[u8]) -> Result<T, DecodeError> {
    let Some((header, body)) = payload.split_first_chunk::<4>() else {
        return Err(DecodeError::TooShort(payload.len()));
    };
    let decoded = match (header[0], header[1]) {
        (0x00, 0x01) => cdr_encoding::from_bytes::<T, LittleEndian>(body),
        (0x00, 0x00) => cdr_encoding::from_bytes::<T, BigEndian>(body),
        (a, b) => return Err(DecodeError::Encapsulation(a, b)),
    };
    decoded
        .map(|(value, _)| value)
        .map_err(|e| DecodeError::Cdr(e.to_string()))
}

/// A channel of a bag: its topic, message type and encodings.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    /// Topic name.
    pub topic: String,
    /// Schema name, e.g. `ttball_msgs/msg/BallDetection` (empty without a schema).
    pub schema_name: String,
    /// Schema encoding, e.g. `ros2msg`.
    pub schema_encoding: String,
    /// Schema text.
    pub schema_data: Vec<u8>,
    /// Message encoding, e.g. `cdr`.
    pub message_encoding: String,
    /// Channel metadata (rosbag2 keeps the QoS profiles here).
    pub metadata: BTreeMap<String, String>,
}

/// One message of a bag.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BagMessage {
    /// Index of its channel in [`BagContents::channels`].
    pub channel: usize,
    /// Log time [ns].
    pub log_time: u64,
    /// Publish time [ns].
    pub publish_time: u64,
    /// The payload.
    pub data: Vec<u8>,
}

/// What could be read of a bag.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct BagContents {
    /// Every channel seen.
    pub channels: Vec<ChannelInfo>,
    /// Every message read, in log-time order (file order among equal times).
    pub messages: Vec<BagMessage>,
    /// Why reading stopped early (a truncated or corrupt file), when it did.
    pub damage: Option<String>,
}

impl BagContents {
    /// The index of the channel of a topic.
    pub fn channel(&self, topic: &str) -> Option<usize> {
        self.channels.iter().position(|c| c.topic == topic)
    }
}

/// Reads a bag (see [`read_bag`]): an MCAP file, or a rosbag2 directory (as `ros2 bag record`
/// writes it: `metadata.yaml` beside one or more `.mcap` files, read together in log-time order).
pub fn read_bag_file(path: &Path) -> Result<BagContents, BagError> {
    if path.is_dir() {
        return read_bag_dir(path);
    }
    let bytes = std::fs::read(path).map_err(|source| BagError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    read_bag(&bytes).map_err(|reason| BagError::NotMcap {
        path: path.to_path_buf(),
        reason,
    })
}

fn read_bag_dir(dir: &Path) -> Result<BagContents, BagError> {
    let io = |source| BagError::Io {
        path: dir.to_path_buf(),
        source,
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(io)?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(BagError::NotMcap {
            path: dir.to_path_buf(),
            reason: "a directory without .mcap files".to_string(),
        });
    }
    let mut merged = BagContents::default();
    for file in &files {
        let part = read_bag_file(file)?;
        let map: Vec<usize> = part
            .channels
            .iter()
            .map(|c| {
                merged.channel(&c.topic).unwrap_or_else(|| {
                    merged.channels.push(c.clone());
                    merged.channels.len() - 1
                })
            })
            .collect();
        merged
            .messages
            .extend(part.messages.into_iter().map(|m| BagMessage {
                channel: map[m.channel],
                ..m
            }));
        if let Some(damage) = part.damage {
            merged.damage = Some(format!("{}: {damage}", file.display()));
        }
    }
    merged.messages.sort_by_key(|m| m.log_time);
    Ok(merged)
}

/// Reads every message of an MCAP file in memory, in log-time order. A file that does not start
/// as MCAP is an error; damage later on ends the reading with what was read and the reason.
pub fn read_bag(bytes: &[u8]) -> Result<BagContents, String> {
    if !bytes.starts_with(mcap::MAGIC) {
        return Err("it does not start with the MCAP magic bytes".to_string());
    }
    let options = mcap::read::Options::IgnoreEndMagic.into();
    let stream =
        mcap::MessageStream::new_with_options(bytes, options).map_err(|e| e.to_string())?;
    let mut contents = BagContents::default();
    let mut ids: BTreeMap<u16, usize> = BTreeMap::new();
    for item in stream {
        let message = match item {
            Ok(m) => m,
            Err(e) => {
                contents.damage = Some(format!(
                    "reading stopped after {} messages: {e}",
                    contents.messages.len()
                ));
                break;
            }
        };
        let channel = *ids.entry(message.channel.id).or_insert_with(|| {
            let c = &message.channel;
            let schema = c.schema.as_deref();
            contents.channels.push(ChannelInfo {
                topic: c.topic.clone(),
                schema_name: schema.map(|s| s.name.clone()).unwrap_or_default(),
                schema_encoding: schema.map(|s| s.encoding.clone()).unwrap_or_default(),
                schema_data: schema.map(|s| s.data.to_vec()).unwrap_or_default(),
                message_encoding: c.message_encoding.clone(),
                metadata: c.metadata.clone(),
            });
            contents.channels.len() - 1
        });
        contents.messages.push(BagMessage {
            channel,
            log_time: message.log_time,
            publish_time: message.publish_time,
            data: message.data.into_owned(),
        });
    }
    contents.messages.sort_by_key(|m| m.log_time);
    Ok(contents)
}

/// Writes a ROS 2 MCAP bag.
pub struct BagWriter<W: Write + Seek> {
    writer: mcap::Writer<W>,
    path: PathBuf,
    schemas: BTreeMap<(String, Vec<u8>), u16>,
    channels: BTreeMap<String, u16>,
    sequence: u32,
}

impl BagWriter<BufWriter<File>> {
    /// Creates (or replaces) a bag file.
    pub fn create(path: &Path) -> Result<Self, BagError> {
        let file = File::create(path).map_err(|source| BagError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::new(BufWriter::new(file), path)
    }
}

impl<W: Write + Seek> BagWriter<W> {
    /// A bag writer on any seekable output; `path` names it in errors.
    pub fn new(out: W, path: &Path) -> Result<Self, BagError> {
        let writer = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("ttball ", env!("CARGO_PKG_VERSION")))
            .create(out)
            .map_err(|e| BagError::Write {
                path: path.to_path_buf(),
                reason: e.to_string(),
            })?;
        Ok(Self {
            writer,
            path: path.to_path_buf(),
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            sequence: 0,
        })
    }

    fn write_error(&self, e: mcap::McapError) -> BagError {
        BagError::Write {
            path: self.path.clone(),
            reason: e.to_string(),
        }
    }

    /// The channel of a topic carrying one of ttball's known types (`pkg/msg/Type`), created on
    /// first use with the type's full `ros2msg` schema.
    pub fn channel(&mut self, topic: &str, type_name: &str) -> Result<u16, BagError> {
        if let Some(id) = self.channels.get(topic) {
            return Ok(*id);
        }
        let schema = definitions::schema(type_name)
            .ok_or_else(|| BagError::UnknownType(type_name.into()))?;
        self.add_channel(&ChannelInfo {
            topic: topic.to_string(),
            schema_name: type_name.to_string(),
            schema_encoding: "ros2msg".to_string(),
            schema_data: schema.into_bytes(),
            message_encoding: "cdr".to_string(),
            metadata: BTreeMap::new(),
        })
    }

    /// A channel copied from another bag (same topic, schema, encodings and metadata).
    pub fn add_channel(&mut self, info: &ChannelInfo) -> Result<u16, BagError> {
        if let Some(id) = self.channels.get(&info.topic) {
            return Ok(*id);
        }
        let schema_id = if info.schema_name.is_empty() {
            0
        } else {
            let key = (info.schema_name.clone(), info.schema_data.clone());
            match self.schemas.get(&key) {
                Some(id) => *id,
                None => {
                    let id = self
                        .writer
                        .add_schema(&info.schema_name, &info.schema_encoding, &info.schema_data)
                        .map_err(|e| self.write_error(e))?;
                    self.schemas.insert(key, id);
                    id
                }
            }
        };
        let id = self
            .writer
            .add_channel(
                schema_id,
                &info.topic,
                &info.message_encoding,
                &info.metadata,
            )
            .map_err(|e| self.write_error(e))?;
        self.channels.insert(info.topic.clone(), id);
        Ok(id)
    }

    /// Writes a payload on a channel.
    pub fn write_raw(
        &mut self,
        channel: u16,
        log_time: u64,
        publish_time: u64,
        data: &[u8],
    ) -> Result<(), BagError> {
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: self.sequence,
            log_time,
            publish_time,
        };
        self.writer
            .write_to_known_channel(&header, data)
            .map_err(|e| self.write_error(e))
    }

    /// Encodes a message as CDR and writes it; log and publish time are `log_time` [ns].
    pub fn write<T: Serialize>(
        &mut self,
        channel: u16,
        type_name: &str,
        log_time: u64,
        msg: &T,
    ) -> Result<(), BagError> {
        let payload = encode(type_name, msg)?;
        self.write_raw(channel, log_time, log_time, &payload)
    }

    /// Finishes the file: the last chunk, the summary and the footer.
    pub fn finish(mut self) -> Result<(), BagError> {
        self.writer.finish().map_err(|e| self.write_error(e))?;
        let mut out = self.writer.into_inner();
        out.flush().map_err(|source| BagError::Io {
            path: self.path.clone(),
            source,
        })
    }
}

/// A nanosecond stamp as an MCAP time (negative stamps become 0).
pub fn mcap_time(stamp: i64) -> u64 {
    u64::try_from(stamp).unwrap_or(0)
}
