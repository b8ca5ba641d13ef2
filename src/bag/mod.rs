//! The bag layer: ROS 2 MCAP bags, and what ttball does with recorded messages.
//!
//! - this module: the MCAP files themselves (below);
//! - [`replay`]: an MCAP bag through the node's code path ([`crate::ros::pipeline`]), into an
//!   output bag;
//! - [`record`]: simulated play written as a bag, with its truth;
//! - [`live_view`] (feature `live-view`): the same messages served to the Foxglove app over its
//!   WebSocket protocol.
//!
//! ROS 2 MCAP bags, as `ros2 bag record` (rosbag2's MCAP storage) writes them and Foxglove reads
//! them: `ros2msg` schemas with every dependent definition embedded, `cdr` payloads (the 4-byte
//! encapsulation header, then little-endian CDR from `cdr-encoding`, the serialiser ros2-client
//! uses), log and publish times in nanoseconds.
//!
//! [`BagReader`] (and [`read_bag_file`] on it) reads what it can: a corrupt chunk is
//! skipped, a truncated file yields its complete records, and the damage says where. Messages come back in log-time order. [`BagWriter`] writes
//! lz4-compressed chunks with the summary and indexes; [`BagWriter::finish`] must be called to
//! finish the file (the caller does it on every path, Ctrl-C included).

use std::cmp::{Ordering, Reverse};
use std::collections::{BTreeMap, BinaryHeap};
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use byteorder::{BigEndian, LittleEndian};
use mcap::records::op;
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::ros::msgs::definitions;

#[cfg(feature = "live-view")]
pub mod live_view;
pub mod record;
pub mod replay;
mod sqlite;

use sqlite::{Db3Stream, SQLITE_MAGIC};

/// The encapsulation header of a little-endian CDR payload (CDR_LE, options 0).
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// What can go wrong with a bag.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// The file cannot be read or written.
    #[error("{path}: {error}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the system said (in the message, not its source: said once in a chain).
        error: std::io::Error,
    },
    /// The file is not an MCAP file at all.
    #[error("{path}: not an MCAP file ({reason})")]
    NotMcap {
        /// The file.
        path: PathBuf,
        /// What the MCAP reader said.
        reason: String,
    },
    /// A rosbag2 sqlite3 file (`.db3`) cannot be read.
    #[error("{path}: {reason}")]
    Sqlite {
        /// The file.
        path: PathBuf,
        /// What is wrong, and what to do.
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
    // Straight after the header, into one buffer: CDR aligns relative to the start of the body,
    // which the serialiser counts from its own first byte.
    let mut out = Vec::with_capacity(CDR_LE.len() + 2 * std::mem::size_of_val(msg));
    out.extend_from_slice(&CDR_LE);
    cdr_encoding::to_writer::<T, LittleEndian, _>(&mut out, msg).map_err(|e| BagError::Encode {
        type_name: type_name.to_string(),
        reason: e.to_string(),
    })?;
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

impl ChannelInfo {
    /// The channel of `topic` carrying one of ttball's known types (`pkg/msg/Type`): its full
    /// `ros2msg` schema, `cdr` encoded, no metadata; None for a type without a definition.
    pub fn ros2(topic: &str, type_name: &str) -> Option<Self> {
        Some(Self {
            topic: topic.to_owned(),
            schema_name: type_name.to_owned(),
            schema_encoding: "ros2msg".to_owned(),
            schema_data: definitions::schema(type_name)?.into_bytes(),
            message_encoding: "cdr".to_owned(),
            metadata: BTreeMap::new(),
        })
    }
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
    /// What was skipped and why reading stopped early (a truncated or corrupt file); empty when
    /// the file was whole.
    pub damage: Vec<Damage>,
}

impl BagContents {
    /// The index of the channel of a topic.
    pub fn channel(&self, topic: &str) -> Option<usize> {
        channel_of(&self.channels, topic)
    }
}

/// The index of the channel of `topic` among `channels`.
pub fn channel_of(channels: &[ChannelInfo], topic: &str) -> Option<usize> {
    channels.iter().position(|c| c.topic == topic)
}

/// Reads a whole bag in memory (see [`BagReader`]): an MCAP file, or a rosbag2 directory (as
/// `ros2 bag record` writes it: `metadata.yaml` beside one or more `.mcap` files, read together).
/// Messages come back in log-time order (file order among equal times).
pub fn read_bag_file(path: &Path) -> Result<BagContents, BagError> {
    collect(BagReader::open(path)?)
}

/// Damage found while reading a bag: a chunk skipped, a chunk cut off by the end of the file, or
/// why reading stopped. Its `Display` is the sentence the summaries print.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Damage {
    /// A whole chunk that could not be read was skipped; reading went on after it.
    #[error("the chunk at byte {at} ({why}) was skipped")]
    ChunkSkipped {
        /// The chunk record's offset in the file.
        at: u64,
        /// What is wrong with it.
        why: ChunkDamage,
    },
    /// The file ends inside a chunk, of which the complete messages were read.
    #[error("the file ends inside the chunk at byte {at} ({found} messages of it read)")]
    CutChunk {
        /// The chunk record's offset in the file.
        at: u64,
        /// Messages read from it.
        found: usize,
    },
    /// Reading stopped: nothing after this point could be read.
    #[error("reading stopped after {messages} messages: {why}")]
    Stopped {
        /// Messages read before.
        messages: u64,
        /// Why.
        why: StopReason,
    },
    /// The next file of a split bag cannot be opened.
    #[error("{0}")]
    NextFile(String),
    /// Damage in one file of a split bag.
    #[error("{}: {damage}", .path.display())]
    InFile {
        /// The file.
        path: PathBuf,
        /// What was found in it.
        damage: Box<Damage>,
    },
}

/// Why a chunk was skipped.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ChunkDamage {
    /// It declares more uncompressed bytes than any record may have.
    #[error("{size} bytes uncompressed: too large")]
    TooLarge {
        /// The declared size.
        size: u64,
    },
    /// Its compression is neither zstd nor lz4.
    #[error("unknown compression `{0}`")]
    UnknownCompression(String),
    /// The decompressor failed (`codec: what it said`).
    #[error("{codec}: {reason}")]
    Decompression {
        /// `zstd` or `lz4`.
        codec: &'static str,
        /// What the decompressor said.
        reason: String,
    },
    /// It decompressed to another size than it declares.
    #[error("{got} bytes decompressed, {declared} declared")]
    SizeMismatch {
        /// Bytes it decompressed to.
        got: usize,
        /// Bytes it declares.
        declared: u64,
    },
    /// Its records do not match its CRC.
    #[error("its CRC does not match: corrupt")]
    CrcMismatch,
}

/// Why reading a file stopped.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StopReason {
    /// The file ends inside a record.
    #[error("the file ends inside a record at byte {at}")]
    EndsInsideRecord {
        /// The record's offset.
        at: u64,
    },
    /// The file ends inside a record's header.
    #[error("the file ends inside a record header at byte {at}")]
    EndsInsideHeader {
        /// The record's offset.
        at: u64,
    },
    /// A record claims a length no record may have.
    #[error("the record at byte {at} claims {len} bytes: corrupt")]
    RecordTooLong {
        /// The record's offset.
        at: u64,
        /// The length it claims.
        len: u64,
    },
    /// A record does not parse.
    #[error("the record at byte {at}: {reason}")]
    BadRecord {
        /// The record's offset.
        at: u64,
        /// What the parser said.
        reason: String,
    },
    /// A chunk's header does not parse.
    #[error("the chunk at byte {at} has a corrupt header")]
    ChunkHeader {
        /// The chunk's offset.
        at: u64,
    },
    /// A record inside a chunk does not parse.
    #[error("a record in the chunk at byte {at}: {reason}")]
    BadChunkRecord {
        /// The chunk's offset.
        at: u64,
        /// What the parser said.
        reason: String,
    },
    /// A chunk's records end inside a record.
    #[error("the chunk at byte {at} ends inside a record")]
    ChunkEndsInsideRecord {
        /// The chunk's offset.
        at: u64,
    },
    /// A message names a channel no record declared.
    #[error("a message on unknown channel {0}")]
    UnknownChannel(u16),
    /// Reading the file failed.
    #[error("{0}")]
    Io(String),
}

/// The damages as one sentence (`; ` between them), or `None` when there is none.
pub fn damage_text(damages: &[Damage]) -> Option<String> {
    (!damages.is_empty()).then(|| {
        damages
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join("; ")
    })
}

fn collect(mut reader: BagReader) -> Result<BagContents, BagError> {
    let mut messages = Vec::new();
    while let Some(m) = reader.next_message() {
        messages.push(m);
    }
    messages.sort_by_key(|m| m.log_time);
    Ok(BagContents {
        channels: reader.channels,
        messages,
        damage: reader.damage,
    })
}

/// How many messages the reader holds back to put them in log-time order: a message recorded
/// up to this many messages late still comes out in order. Bounds the reader's memory.
pub const REORDER_WINDOW: usize = 4096;

/// Streams the messages of a bag (an MCAP file, or a rosbag2 directory of them in name order)
/// without holding the file in memory: chunks are read and decompressed one at a time, and a
/// window of [`REORDER_WINDOW`] messages puts them in log-time order (file order among equal
/// times). The channels of a file's summary section are known at once; others are added as they
/// appear. A chunk whose CRC fails or that does not decompress is skipped; a file cut off yields
/// its complete records (those of a cut chunk included); [`Self::damage`] says what and where.
pub struct BagReader {
    files: std::vec::IntoIter<PathBuf>,
    file: Option<Stream>,
    channels: Vec<ChannelInfo>,
    damage: Vec<Damage>,
    window: ReorderWindow,
    sequence: u64,
    read: u64,
    messages: u64,
    size: u64,
    several_files: bool,
    /// A summary section was read: [`Self::channels`] lists every channel from the start.
    summarised: bool,
}

/// A message held in the reorder window, ordered by log time then arrival.
struct Held(u64, u64, BagMessage);

impl PartialEq for Held {
    fn eq(&self, other: &Self) -> bool {
        (self.0, self.1) == (other.0, other.1)
    }
}
impl Eq for Held {}
impl PartialOrd for Held {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Held {
    fn cmp(&self, other: &Self) -> Ordering {
        (self.0, self.1).cmp(&(other.0, other.1))
    }
}

/// The messages held back to be put in order: those that arrived in order (the usual case, a
/// bag written in log-time order) queue as they came, the others wait in a heap; the next out
/// is the earlier of the two fronts. The same order as one heap of them all, without a heap's
/// work for every message.
struct ReorderWindow {
    in_order: std::collections::VecDeque<Held>,
    late: BinaryHeap<Reverse<Held>>,
}

impl ReorderWindow {
    fn new() -> Self {
        Self {
            in_order: std::collections::VecDeque::with_capacity(REORDER_WINDOW + 1),
            late: BinaryHeap::new(),
        }
    }

    fn len(&self) -> usize {
        self.in_order.len() + self.late.len()
    }

    fn push(&mut self, held: Held) {
        if self.in_order.back().is_none_or(|last| *last < held) {
            self.in_order.push_back(held);
        } else {
            self.late.push(Reverse(held));
        }
    }

    /// The earliest message held.
    fn pop(&mut self) -> Option<BagMessage> {
        let late_first = match (self.in_order.front(), self.late.peek()) {
            (Some(queued), Some(Reverse(late))) => late < queued,
            (None, Some(_)) => true,
            (_, None) => false,
        };
        let held = if late_first {
            self.late.pop().map(|Reverse(h)| h)
        } else {
            self.in_order.pop_front()
        };
        held.map(|Held(_, _, m)| m)
    }
}

/// One MCAP file being read, a record at a time (its own framing: opcode, length, body), so
/// that a corrupt chunk can be skipped and a chunk cut off by the end of the file still yields
/// its complete records.
struct FileStream {
    path: PathBuf,
    source: Box<dyn Read>,
    /// Bytes of the file consumed so far (the offset of the next record).
    offset: u64,
    records: Records,
    /// The messages of the chunk being read, in file order.
    chunk: std::collections::VecDeque<BagMessage>,
    /// Chunks skipped as corrupt (CRC mismatch, undecompressible) or cut off, each with why.
    skipped: Vec<Damage>,
    /// The data section has ended (a data end or footer record).
    finished: bool,
}

/// One file of a bag being read: MCAP, or rosbag2's sqlite3 storage.
enum Stream {
    Mcap(FileStream),
    Db3(Db3Stream),
}

impl Stream {
    fn path(&self) -> &Path {
        match self {
            Self::Mcap(f) => &f.path,
            Self::Db3(f) => &f.path,
        }
    }

    /// The next message of the file, `None` at its end, or why it cannot be read further.
    fn next(
        &mut self,
        channels: &mut Vec<ChannelInfo>,
        read: &mut u64,
    ) -> Result<Option<BagMessage>, StopReason> {
        match self {
            Self::Mcap(f) => f.next(channels, read),
            Self::Db3(f) => f.next(read),
        }
    }

    /// The damage found since last asked (an MCAP file's skipped chunks).
    fn take_skipped(&mut self) -> Vec<Damage> {
        match self {
            Self::Mcap(f) => std::mem::take(&mut f.skipped),
            Self::Db3(_) => Vec::new(),
        }
    }
}

/// What a file is, by its first bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FileKind {
    Mcap,
    Sqlite,
}

/// Largest MCAP record accepted [bytes]: a corrupt length cannot make the reader buffer more.
const RECORD_LENGTH_LIMIT: u64 = 1 << 28;

/// The schema and channel records of one MCAP file.
#[derive(Default)]
struct Records {
    /// Schema id -> (name, encoding, data).
    schemas: BTreeMap<u16, (String, String, Vec<u8>)>,
    /// Channel id in the file -> index in [`BagReader::channels`].
    ids: BTreeMap<u16, usize>,
}

/// The files of a rosbag2 directory in recording order: `metadata.yaml`'s `relative_file_paths`
/// when it has one (as `ros2 bag play` reads them), else the `.mcap` and `.db3` files by their
/// split number (`name_2` before `name_10`), then by name.
pub fn rosbag2_files(dir: &Path) -> Result<Vec<PathBuf>, BagError> {
    let not_a_bag = |reason: String| BagError::NotMcap {
        path: dir.to_path_buf(),
        reason,
    };
    let metadata = dir.join("metadata.yaml");
    if let Ok(text) = std::fs::read_to_string(&metadata) {
        let listed = rosbag2_listed_files(&text).map_err(|e| {
            not_a_bag(format!(
                "its metadata.yaml is not rosbag2's ({e}); move it away to read the .mcap files by their split number"
            ))
        })?;
        let mut files = Vec::with_capacity(listed.len());
        for name in listed {
            // Before metadata version 4 the paths began with the bag directory's own name.
            let file = Some(dir.join(&name))
                .filter(|f| f.is_file())
                .or_else(|| dir.parent().map(|p| p.join(&name)))
                .unwrap_or_else(|| dir.join(&name));
            if !name.ends_with(".mcap") && !name.ends_with(".db3") {
                return Err(not_a_bag(format!(
                    "metadata.yaml lists `{name}`, neither an MCAP nor an sqlite3 file (a bag compressed per file: `ros2 bag decompress` it first)"
                )));
            }
            if !file.is_file() {
                return Err(not_a_bag(format!(
                    "metadata.yaml lists `{name}`, which is missing from the directory"
                )));
            }
            files.push(file);
        }
        if !files.is_empty() {
            return Ok(files);
        }
    }
    let entries = std::fs::read_dir(dir).map_err(|error| BagError::Io {
        path: dir.to_path_buf(),
        error,
    })?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "mcap" || e == "db3"))
        .collect();
    files.sort_by_cached_key(|p| {
        let stem = p.file_stem().map(|s| s.to_string_lossy().into_owned());
        let split = stem
            .as_deref()
            .and_then(|s| s.rsplit_once('_'))
            .and_then(|(_, n)| n.parse::<u64>().ok());
        (split, p.clone())
    });
    if files.is_empty() {
        return Err(not_a_bag(
            "a directory without .mcap or .db3 files".to_string(),
        ));
    }
    Ok(files)
}

/// `rosbag2_bagfile_information.relative_file_paths` of a rosbag2 `metadata.yaml`.
fn rosbag2_listed_files(text: &str) -> Result<Vec<String>, String> {
    let document: serde_norway::Value = serde_norway::from_str(text).map_err(|e| e.to_string())?;
    let info = document
        .get("rosbag2_bagfile_information")
        .ok_or("no rosbag2_bagfile_information")?;
    let Some(paths) = info.get("relative_file_paths") else {
        return Ok(Vec::new());
    };
    paths
        .as_sequence()
        .ok_or("relative_file_paths is not a list")?
        .iter()
        .map(|p| {
            p.as_str()
                .map(str::to_owned)
                .ok_or_else(|| "relative_file_paths holds a non-string".to_owned())
        })
        .collect()
}

impl BagReader {
    /// Opens a bag file or rosbag2 directory (MCAP or sqlite3 storage); the channels of its
    /// MCAP summary sections and sqlite3 topic tables are read.
    pub fn open(path: &Path) -> Result<Self, BagError> {
        let files = if path.is_dir() {
            rosbag2_files(path)?
        } else {
            vec![path.to_path_buf()]
        };
        let mut size = 0;
        let mut reader = Self::empty();
        for file in &files {
            let mut f = File::open(file).map_err(|error| BagError::Io {
                path: file.clone(),
                error,
            })?;
            size += f.metadata().map(|m| m.len()).unwrap_or(0);
            match kind_of_file(&mut f, file)? {
                FileKind::Mcap => {
                    if let Some(summary) = read_summary(&mut f) {
                        reader.register_summary(&summary);
                    }
                }
                FileKind::Sqlite => {
                    Db3Stream::open(file, &mut reader.channels)?;
                    reader.summarised = true;
                }
            }
        }
        reader.size = size;
        reader.several_files = files.len() > 1;
        reader.files = files.into_iter();
        reader.open_next()?;
        Ok(reader)
    }

    /// A reader of MCAP bytes already in memory; `path` names them in messages.
    pub fn from_bytes(bytes: Vec<u8>, path: &Path) -> Result<Self, BagError> {
        if file_kind(&bytes, path)? != FileKind::Mcap {
            return Err(BagError::NotMcap {
                path: path.to_path_buf(),
                reason: "an sqlite3 bag is read from its file, not from memory".to_string(),
            });
        }
        let mut reader = Self::empty();
        reader.size = bytes.len() as u64;
        reader.file = Some(Stream::Mcap(FileStream::new(
            path.to_path_buf(),
            Box::new(std::io::Cursor::new(bytes)),
        )));
        Ok(reader)
    }

    fn empty() -> Self {
        Self {
            files: Vec::new().into_iter(),
            file: None,
            channels: Vec::new(),
            damage: Vec::new(),
            window: ReorderWindow::new(),
            sequence: 0,
            read: 0,
            messages: 0,
            size: 0,
            several_files: false,
            summarised: false,
        }
    }

    /// True when the bag's summary section was read: [`Self::channels`] is then complete
    /// before the first message.
    pub fn has_summary(&self) -> bool {
        self.summarised
    }

    /// Every channel seen so far (all of them once the summaries are read).
    pub fn channels(&self) -> &[ChannelInfo] {
        &self.channels
    }

    /// The index of the channel of a topic.
    pub fn channel(&self, topic: &str) -> Option<usize> {
        channel_of(&self.channels, topic)
    }

    /// What was damaged, when anything was: corrupt chunks skipped, and why reading stopped
    /// early (a truncated or corrupt file).
    pub fn damage(&self) -> &[Damage] {
        &self.damage
    }

    /// Bytes read so far and the bag's size in bytes (for progress).
    pub fn progress(&self) -> (u64, u64) {
        (self.read, self.size)
    }

    /// The next message in log-time order, or `None` at the end (or at damage).
    pub fn next_message(&mut self) -> Option<BagMessage> {
        while self.window.len() <= REORDER_WINDOW {
            let Some(message) = self.read_message() else {
                break;
            };
            self.sequence += 1;
            self.window
                .push(Held(message.log_time, self.sequence, message));
        }
        self.window.pop()
    }

    fn open_next(&mut self) -> Result<bool, BagError> {
        let Some(path) = self.files.next() else {
            self.file = None;
            return Ok(false);
        };
        let mut f = File::open(&path).map_err(|error| BagError::Io {
            path: path.clone(),
            error,
        })?;
        self.file = Some(match kind_of_file(&mut f, &path)? {
            FileKind::Sqlite => Stream::Db3(Db3Stream::open(&path, &mut self.channels)?),
            FileKind::Mcap => {
                f.seek(SeekFrom::Start(0)).map_err(|error| BagError::Io {
                    path: path.clone(),
                    error,
                })?;
                Stream::Mcap(FileStream::new(
                    path,
                    Box::new(BufReader::with_capacity(1 << 16, f)),
                ))
            }
        });
        Ok(true)
    }

    /// The next message in file order, across the files.
    fn read_message(&mut self) -> Option<BagMessage> {
        loop {
            let stream = self.file.as_mut()?;
            let result = stream.next(&mut self.channels, &mut self.read);
            let path = self.several_files.then(|| stream.path().to_path_buf());
            let in_file = |damage: Damage| match &path {
                Some(path) => Damage::InFile {
                    path: path.clone(),
                    damage: Box::new(damage),
                },
                None => damage,
            };
            let skipped = stream.take_skipped();
            self.damage.extend(skipped.into_iter().map(&in_file));
            match result {
                Ok(Some(message)) => {
                    self.messages += 1;
                    return Some(message);
                }
                Ok(None) => {}
                Err(why) => {
                    self.damage.push(in_file(Damage::Stopped {
                        messages: self.messages,
                        why,
                    }));
                    self.file = None;
                    return None;
                }
            }
            match self.open_next() {
                Ok(true) => {}
                Ok(false) => return None,
                Err(e) => {
                    self.damage.push(Damage::NextFile(e.to_string()));
                    return None;
                }
            }
        }
    }

    /// Registers the channels of a file's summary section (the file's ids are read again with
    /// its data section).
    fn register_summary(&mut self, summary: &[u8]) {
        self.summarised = true;
        let mut records = Records::default();
        for (opcode, record) in (RecordSlices { rest: summary }) {
            if let Ok(record) = mcap::parse_record(opcode, record) {
                records.take(record, &mut self.channels);
            }
        }
    }
}

impl FileStream {
    /// A stream over `source`, positioned after the 8 magic bytes (already checked).
    fn new(path: PathBuf, mut source: Box<dyn Read>) -> Self {
        let mut magic = [0u8; 8];
        let skipped_magic = read_up_to(&mut source, &mut magic).unwrap_or(0);
        Self {
            path,
            source,
            offset: skipped_magic as u64,
            records: Records::default(),
            chunk: std::collections::VecDeque::new(),
            skipped: Vec::new(),
            finished: false,
        }
    }

    /// The next message of the file, `None` at its end, or why it cannot be read further.
    fn next(
        &mut self,
        channels: &mut Vec<ChannelInfo>,
        read: &mut u64,
    ) -> Result<Option<BagMessage>, StopReason> {
        loop {
            if let Some(message) = self.chunk.pop_front() {
                return Ok(Some(message));
            }
            if self.finished {
                return Ok(None);
            }
            let at = self.offset;
            let Some((opcode, body, complete)) = self.next_record()? else {
                return Ok(None);
            };
            *read += self.offset - at;
            if !complete {
                if opcode == op::CHUNK {
                    // What the cut-off chunk holds up to the end of the file is still read.
                    let _ = self.take_chunk(&body, at, false, channels);
                    let found = self.chunk.len();
                    self.finished = true;
                    if found > 0 {
                        self.skipped.push(Damage::CutChunk { at, found });
                        continue;
                    }
                }
                return Err(StopReason::EndsInsideRecord { at });
            }
            match opcode {
                op::CHUNK => self.take_chunk(&body, at, true, channels)?,
                op::DATA_END | op::FOOTER => self.finished = true,
                _ => {
                    let record =
                        mcap::parse_record(opcode, &body).map_err(|e| StopReason::BadRecord {
                            at,
                            reason: e.to_string(),
                        })?;
                    if let mcap::records::Record::Message { header, data } = record {
                        let data = data.into_owned();
                        return self.message(&header, data).map(Some);
                    }
                    self.records.take(record, channels);
                }
            }
        }
    }

    /// The next record: opcode, body, and whether the body is whole (false when the file ends
    /// inside it); `None` at the end of the file.
    fn next_record(&mut self) -> Result<Option<(u8, Vec<u8>, bool)>, StopReason> {
        let at = self.offset;
        let mut head = [0u8; 9];
        let got =
            read_up_to(&mut self.source, &mut head).map_err(|e| StopReason::Io(e.to_string()))?;
        self.offset += got as u64;
        match got {
            0 => return Ok(None),
            9 => {}
            _ => return Err(StopReason::EndsInsideHeader { at }),
        }
        let opcode = head[0];
        let mut len_bytes = [0u8; 8];
        len_bytes.copy_from_slice(&head[1..]);
        let len = u64::from_le_bytes(len_bytes);
        if len > RECORD_LENGTH_LIMIT {
            return Err(StopReason::RecordTooLong { at, len });
        }
        let mut body = Vec::new();
        Read::by_ref(&mut self.source)
            .take(len)
            .read_to_end(&mut body)
            .map_err(|e| StopReason::Io(e.to_string()))?;
        self.offset += body.len() as u64;
        let complete = body.len() as u64 == len;
        Ok(Some((opcode, body, complete)))
    }

    /// Reads a chunk record's records: its messages are queued, its schemas and channels
    /// registered. A whole chunk whose CRC does not match, or that does not decompress, is
    /// skipped (noted in `skipped`) and reading goes on with the next record; of a chunk cut off
    /// by the end of the file (`complete` false), the complete records are read.
    fn take_chunk(
        &mut self,
        body: &[u8],
        at: u64,
        complete: bool,
        channels: &mut Vec<ChannelInfo>,
    ) -> Result<(), StopReason> {
        let Some(chunk) = ChunkParts::parse(body) else {
            return Err(StopReason::ChunkHeader { at });
        };
        let data = match decompress(&chunk, complete) {
            Ok(data) => data,
            Err(why) => {
                self.skipped.push(Damage::ChunkSkipped { at, why });
                return Ok(());
            }
        };
        if complete && chunk.crc != 0 && crc32fast::hash(&data) != chunk.crc {
            self.skipped.push(Damage::ChunkSkipped {
                at,
                why: ChunkDamage::CrcMismatch,
            });
            return Ok(());
        }
        let mut records = RecordSlices { rest: &data };
        for (opcode, record) in records.by_ref() {
            match mcap::parse_record(opcode, record) {
                Ok(mcap::records::Record::Message { header, data }) => {
                    let message = self.message(&header, data.into_owned())?;
                    self.chunk.push_back(message);
                }
                Ok(other) => self.records.take(other, channels),
                Err(e) => {
                    return Err(StopReason::BadChunkRecord {
                        at,
                        reason: e.to_string(),
                    });
                }
            }
        }
        if complete && !records.rest.is_empty() {
            return Err(StopReason::ChunkEndsInsideRecord { at });
        }
        Ok(())
    }

    /// A message record of this file as a [`BagMessage`].
    fn message(
        &self,
        header: &mcap::records::MessageHeader,
        data: Vec<u8>,
    ) -> Result<BagMessage, StopReason> {
        let Some(&channel) = self.records.ids.get(&header.channel_id) else {
            return Err(StopReason::UnknownChannel(header.channel_id));
        };
        Ok(BagMessage {
            channel,
            log_time: header.log_time,
            publish_time: header.publish_time,
            data,
        })
    }
}

/// The parts of a chunk record body: uncompressed size and CRC, compression, compressed records
/// (as many bytes of them as there are).
struct ChunkParts<'a> {
    uncompressed_size: u64,
    crc: u32,
    compression: &'a str,
    records: &'a [u8],
}

impl<'a> ChunkParts<'a> {
    fn parse(body: &'a [u8]) -> Option<Self> {
        // message_start_time u64, message_end_time u64, uncompressed_size u64,
        // uncompressed_crc u32, compression (u32 length + UTF-8), records length u64, records.
        let (_times, rest) = body.split_at_checked(16)?;
        let (size, rest) = rest.split_first_chunk::<8>()?;
        let (crc, rest) = rest.split_first_chunk::<4>()?;
        let (name_len, rest) = rest.split_first_chunk::<4>()?;
        let (name, rest) = rest.split_at_checked(u32::from_le_bytes(*name_len) as usize)?;
        let (records_len, rest) = rest.split_first_chunk::<8>()?;
        let records_len = usize::try_from(u64::from_le_bytes(*records_len)).ok()?;
        Some(Self {
            uncompressed_size: u64::from_le_bytes(*size),
            crc: u32::from_le_bytes(*crc),
            compression: std::str::from_utf8(name).ok()?,
            records: rest.get(..records_len).unwrap_or(rest),
        })
    }
}

/// The records `(opcode, body)` laid end to end in `rest` (a chunk's or a summary section's);
/// iteration stops at one cut short, which stays in `rest`.
struct RecordSlices<'a> {
    rest: &'a [u8],
}

impl<'a> Iterator for RecordSlices<'a> {
    type Item = (u8, &'a [u8]);

    fn next(&mut self) -> Option<Self::Item> {
        let (&opcode, after) = self.rest.split_first()?;
        let (len, body) = after.split_first_chunk::<8>()?;
        let len = usize::try_from(u64::from_le_bytes(*len)).ok()?;
        let (record, tail) = body.split_at_checked(len)?;
        self.rest = tail;
        Some((opcode, record))
    }
}

/// Reads into `buf` until it is full or the source ends; the number of bytes read.
fn read_up_to(source: &mut dyn Read, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut got = 0;
    while got < buf.len() {
        match source.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

impl Records {
    /// Registers a schema or channel record (channels merge by topic across files).
    fn take(&mut self, record: mcap::records::Record<'_>, channels: &mut Vec<ChannelInfo>) {
        match record {
            mcap::records::Record::Schema { header, data } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding, data.into_owned()));
            }
            mcap::records::Record::Channel(c) => {
                let schema = self.schemas.get(&c.schema_id);
                let known = channels.iter().position(|known| known.topic == c.topic);
                // A summary may repeat its channels without their schemas (the data section has
                // them): the channel then learns its schema when the data section names it.
                if let (Some(i), Some((name, encoding, data))) = (known, schema)
                    && channels[i].schema_name.is_empty()
                {
                    channels[i].schema_name.clone_from(name);
                    channels[i].schema_encoding.clone_from(encoding);
                    channels[i].schema_data.clone_from(data);
                }
                let index = known.unwrap_or_else(|| {
                    channels.push(ChannelInfo {
                        topic: c.topic.clone(),
                        schema_name: schema.map(|s| s.0.clone()).unwrap_or_default(),
                        schema_encoding: schema.map(|s| s.1.clone()).unwrap_or_default(),
                        schema_data: schema.map(|s| s.2.clone()).unwrap_or_default(),
                        message_encoding: c.message_encoding.clone(),
                        metadata: c.metadata.clone(),
                    });
                    channels.len() - 1
                });
                self.ids.insert(c.id, index);
            }
            _ => {}
        }
    }
}

/// What the open file at `path` is ([`file_kind`] of its first bytes, read from where it stands).
fn kind_of_file(f: &mut File, path: &Path) -> Result<FileKind, BagError> {
    let mut start = Vec::with_capacity(SQLITE_MAGIC.len());
    let _ = Read::by_ref(f)
        .take(SQLITE_MAGIC.len() as u64)
        .read_to_end(&mut start);
    file_kind(&start, path)
}

/// What a file is by its first bytes (at least 16 of them when the file has them): MCAP or
/// SQLite, else an error that says what it is not.
fn file_kind(start: &[u8], path: &Path) -> Result<FileKind, BagError> {
    if start.is_empty() {
        return Err(BagError::NotMcap {
            path: path.to_path_buf(),
            reason: "the file is empty (0 bytes)".to_string(),
        });
    }
    if start.starts_with(mcap::MAGIC) {
        return Ok(FileKind::Mcap);
    }
    if start.starts_with(SQLITE_MAGIC) {
        return Ok(FileKind::Sqlite);
    }
    Err(BagError::NotMcap {
        path: path.to_path_buf(),
        reason: "it starts with neither the MCAP magic bytes nor SQLite's (rosbag2's sqlite3 \
                 storage)"
            .to_string(),
    })
}

/// The records of a chunk, decompressed; of a chunk cut short (`complete` false), as much as
/// decompresses.
fn decompress(chunk: &ChunkParts<'_>, complete: bool) -> Result<Vec<u8>, ChunkDamage> {
    let size = chunk.uncompressed_size;
    if size > RECORD_LENGTH_LIMIT {
        return Err(ChunkDamage::TooLarge { size });
    }
    let mut out = Vec::new();
    let result = match chunk.compression {
        "" => {
            out.extend_from_slice(chunk.records);
            Ok(0)
        }
        "zstd" => zstd::stream::read::Decoder::new(chunk.records)
            .and_then(|d| d.take(size).read_to_end(&mut out))
            .map_err(|e| ChunkDamage::Decompression {
                codec: "zstd",
                reason: e.to_string(),
            }),
        "lz4" => lz4::Decoder::new(chunk.records)
            .and_then(|d| d.take(size).read_to_end(&mut out))
            .map_err(|e| ChunkDamage::Decompression {
                codec: "lz4",
                reason: e.to_string(),
            }),
        other => return Err(ChunkDamage::UnknownCompression(other.to_owned())),
    };
    if complete {
        result?;
        if out.len() as u64 != size {
            return Err(ChunkDamage::SizeMismatch {
                got: out.len(),
                declared: size,
            });
        }
    }
    Ok(out)
}

/// The summary section of a finished MCAP file (from its footer), if it has one.
fn read_summary(f: &mut File) -> Option<Vec<u8>> {
    // Footer record: opcode, length (20), summary start, summary offset start, CRC; then magic.
    const TAIL: u64 = 1 + 8 + 8 + 8 + 4 + 8;
    let len = f.metadata().ok()?.len();
    let footer_at = len.checked_sub(TAIL)?;
    f.seek(SeekFrom::Start(footer_at)).ok()?;
    let mut tail = [0u8; TAIL as usize];
    f.read_exact(&mut tail).ok()?;
    if tail[0] != mcap::records::op::FOOTER || tail[29..] != *mcap::MAGIC {
        return None;
    }
    let start = u64::from_le_bytes(tail[9..17].try_into().ok()?);
    if start == 0 || start >= footer_at {
        return None;
    }
    let mut summary = vec![0u8; usize::try_from(footer_at - start).ok()?];
    f.seek(SeekFrom::Start(start)).ok()?;
    f.read_exact(&mut summary).ok()?;
    Some(summary)
}

/// An error's message followed by its causes' (the `mcap` crate's I/O error names what failed,
/// its cause why: "No space left on device").
fn with_causes(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        let next = c.to_string();
        if !text.ends_with(&next) {
            text = format!("{text}: {next}");
        }
        cause = c.source();
    }
    text
}

/// Writes a ROS 2 MCAP bag.
pub struct BagWriter<W: Write + Seek> {
    writer: mcap::Writer<W>,
    path: PathBuf,
    schemas: BTreeMap<(String, Vec<u8>), u16>,
    channels: BTreeMap<String, u16>,
    /// Each channel's description, by id (for the observer).
    infos: BTreeMap<u16, ChannelInfo>,
    sequence: u32,
    observer: Option<Observer>,
}

/// Sees every message a [`BagWriter`] writes, after it is written: its channel, log time and
/// payload (e.g. the live view, [`crate::bag::live_view`]).
pub type Observer = Box<dyn FnMut(&ChannelInfo, u64, &[u8]) + Send>;

impl BagWriter<BufWriter<File>> {
    /// Creates (or replaces) a bag file.
    pub fn create(path: &Path) -> Result<Self, BagError> {
        let file = File::create(path).map_err(|error| BagError::Io {
            path: path.to_path_buf(),
            error,
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
            // lz4: the whole replay of real play about 12 % faster than with zstd's fastest
            // level, the file about 10 % larger (docs/performance.md).
            .compression(Some(mcap::Compression::Lz4))
            .create(out)
            .map_err(|e| BagError::Write {
                path: path.to_path_buf(),
                reason: with_causes(&e),
            })?;
        Ok(Self {
            writer,
            path: path.to_path_buf(),
            schemas: BTreeMap::new(),
            channels: BTreeMap::new(),
            infos: BTreeMap::new(),
            sequence: 0,
            observer: None,
        })
    }

    /// Shows every message written from now on to `observer` as well.
    pub fn observe(&mut self, observer: Observer) {
        self.observer = Some(observer);
    }

    /// Whether an observer sees what it writes ([`Self::observe`]).
    pub fn is_observed(&self) -> bool {
        self.observer.is_some()
    }

    /// The file it writes (as named in its errors).
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn write_error(&self, e: mcap::McapError) -> BagError {
        BagError::Write {
            path: self.path.clone(),
            reason: with_causes(&e),
        }
    }

    /// The channel of a topic carrying one of ttball's known types (`pkg/msg/Type`), created on
    /// first use with the type's full `ros2msg` schema, offered reliable and volatile (ttball's
    /// outputs; see [`Self::channel_with_qos`]).
    pub fn channel(&mut self, topic: &str, type_name: &str) -> Result<u16, BagError> {
        self.channel_with_qos(topic, type_name, OfferedQos::Reliable)
    }

    /// [`Self::channel`] with the QoS its publisher offers, recorded as rosbag2 records it
    /// (the channel's `offered_qos_profiles`), so that `ros2 bag play` republishes it so.
    pub fn channel_with_qos(
        &mut self,
        topic: &str,
        type_name: &str,
        qos: OfferedQos,
    ) -> Result<u16, BagError> {
        if let Some(id) = self.channels.get(topic) {
            return Ok(*id);
        }
        let mut info = ChannelInfo::ros2(topic, type_name)
            .ok_or_else(|| BagError::UnknownType(type_name.into()))?;
        info.metadata
            .insert(OFFERED_QOS_PROFILES.to_owned(), qos.profiles_yaml());
        self.add_channel(&info)
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
        self.infos.insert(id, info.clone());
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
            .map_err(|e| self.write_error(e))?;
        if let (Some(observe), Some(info)) = (&mut self.observer, self.infos.get(&channel)) {
            observe(info, log_time, data);
        }
        Ok(())
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
        out.flush().map_err(|error| BagError::Io {
            path: self.path.clone(),
            error,
        })
    }
}

/// The channel metadata key under which rosbag2 records the QoS a topic's publishers offered
/// (required by MCAP's `ros2` profile).
pub const OFFERED_QOS_PROFILES: &str = "offered_qos_profiles";

/// The QoS a channel's publisher offers, as far as `ros2 bag play` uses it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OfferedQos {
    /// Sensor data (REP 2003): best effort, volatile. The detections.
    SensorData,
    /// Reliable, volatile: ttball's outputs and the simulator's truth.
    Reliable,
    /// Reliable, transient local (latched): `/tf_static`.
    TransientLocal,
}

impl OfferedQos {
    /// The profile list as rosbag2 writes it (a YAML list of one profile, with the numeric
    /// `rmw_qos_*_policy` values every ROS 2 distribution reads): history and depth unknown
    /// (discovery does not carry them; rosbag2 records 3 / 0 too), durations infinite,
    /// liveliness automatic.
    pub fn profiles_yaml(self) -> String {
        // rmw_qos_reliability_policy_e: 1 reliable, 2 best effort; rmw_qos_durability_policy_e:
        // 1 transient local, 2 volatile.
        let (reliability, durability) = match self {
            Self::SensorData => (2, 2),
            Self::Reliable => (1, 2),
            Self::TransientLocal => (1, 1),
        };
        let infinite = "\n    sec: 2147483647\n    nsec: 4294967295";
        format!(
            "- history: 3\n  depth: 0\n  reliability: {reliability}\n  durability: {durability}\n  deadline:{infinite}\n  lifespan:{infinite}\n  liveliness: 1\n  liveliness_lease_duration:{infinite}\n  avoid_ros_namespace_conventions: false"
        )
    }
}

/// A nanosecond stamp as an MCAP time (negative stamps become 0).
pub fn mcap_time(stamp: i64) -> u64 {
    u64::try_from(stamp).unwrap_or(0)
}
