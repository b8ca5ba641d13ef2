//! rosbag2's sqlite3 storage: the `.db3` files `ros2 bag record` writes by default on ROS 2
//! Humble and earlier (and with `-s sqlite3` on later distributions), read as one more kind of
//! file of a [`BagReader`](super::BagReader).
//!
//! A `.db3` file is an SQLite database with rosbag2's tables (`rosbag2_storage_default_plugins`,
//! `sqlite_storage.cpp`):
//!
//! ```text
//! topics(id, name, type, serialization_format, offered_qos_profiles [, type_description_hash])
//! messages(id, topic_id, timestamp, data)
//! message_definitions(id, topic_type, encoding, encoded_message_definition, ...)   (Iron on)
//! schema(schema_version, ros_distro), metadata(...)                                 (Humble on)
//! ```
//!
//! `offered_qos_profiles` is absent in the oldest files (Eloquent), `message_definitions` before
//! Iron; both are read when present. Messages are read in pages by their row id (the order they
//! were recorded in; the reader's window puts them in log-time order), `timestamp` being the
//! receive time in nanoseconds and `data` the serialised (CDR) message. The database is opened
//! read-only; a database another process holds locked is waited for [`BUSY_TIMEOUT`], then
//! refused with what to do. A damaged or cut file yields the messages read before the damage.

use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::{Connection, ErrorCode, OpenFlags};

use super::{BagError, BagMessage, ChannelInfo, StopReason};

/// The first bytes of every SQLite database file.
pub const SQLITE_MAGIC: &[u8] = b"SQLite format 3\0";

/// Messages read from the database at once.
const PAGE: i64 = 1024;

/// How long opening waits for a database another process holds locked.
pub const BUSY_TIMEOUT: Duration = Duration::from_secs(2);

/// The messages of one `.db3` file, read a page at a time.
pub(super) struct Db3Stream {
    /// The file.
    pub path: PathBuf,
    connection: Connection,
    /// Topic id in the file -> index in the reader's channels.
    ids: BTreeMap<i64, usize>,
    /// The row id of the last message read.
    after: i64,
    page: VecDeque<BagMessage>,
    /// The last page was short: nothing after it.
    finished: bool,
}

/// What SQLite said, as a sentence that says what to do where there is something to do.
fn explain(error: &rusqlite::Error) -> String {
    match error.sqlite_error_code() {
        Some(ErrorCode::DatabaseBusy | ErrorCode::DatabaseLocked) => format!(
            "the database is locked by another process ({error}): a recording still running? \
             read it once `ros2 bag record` has stopped"
        ),
        Some(ErrorCode::DatabaseCorrupt) => {
            format!("the database is damaged ({error}): the messages before the damage are read")
        }
        Some(ErrorCode::NotADatabase) => format!("not an SQLite database ({error})"),
        Some(ErrorCode::CannotOpen | ErrorCode::PermissionDenied | ErrorCode::ReadOnly) => {
            format!("the database cannot be opened for reading ({error})")
        }
        _ if matches!(
            error,
            rusqlite::Error::InvalidColumnType(..)
                | rusqlite::Error::FromSqlConversionFailure(..)
                | rusqlite::Error::IntegralValueOutOfRange(..)
        ) =>
        {
            // A row whose values are not of rosbag2's types: overwritten pages.
            format!("the database is damaged ({error}): the messages before the damage are read")
        }
        _ => error.to_string(),
    }
}

impl Db3Stream {
    /// Opens `path` read-only and registers its topics among `channels` (merged by topic
    /// across files), each with its message definition when the file has one.
    pub fn open(path: &Path, channels: &mut Vec<ChannelInfo>) -> Result<Self, BagError> {
        let refused = |error: rusqlite::Error| BagError::Sqlite {
            path: path.to_path_buf(),
            reason: explain(&error),
        };
        let connection = Connection::open_with_flags(
            path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(refused)?;
        connection.busy_timeout(BUSY_TIMEOUT).map_err(refused)?;
        let definitions = read_definitions(&connection).map_err(refused)?;
        let topics = read_topics(&connection).map_err(|error| match error {
            rusqlite::Error::SqliteFailure(_, Some(ref message))
                if message.contains("no such table") =>
            {
                BagError::Sqlite {
                    path: path.to_path_buf(),
                    reason: format!("an SQLite database without rosbag2's tables ({message})"),
                }
            }
            other => refused(other),
        })?;
        let mut ids = BTreeMap::new();
        for (id, mut info) in topics {
            // The file's own definition, else ttball's for its own types (files before Iron
            // hold none), so that a copy of the channel into MCAP can be decoded.
            if let Some((encoding, text)) = definitions.get(&info.schema_name) {
                info.schema_encoding.clone_from(encoding);
                info.schema_data = text.clone().into_bytes();
            } else if let Some(text) = crate::ros::msgs::definitions::schema(&info.schema_name) {
                info.schema_encoding = "ros2msg".to_owned();
                info.schema_data = text.into_bytes();
            }
            let index = match channels.iter().position(|c| c.topic == info.topic) {
                Some(index) => index,
                None => {
                    channels.push(info);
                    channels.len() - 1
                }
            };
            ids.insert(id, index);
        }
        Ok(Self {
            path: path.to_path_buf(),
            connection,
            ids,
            after: i64::MIN,
            page: VecDeque::with_capacity(PAGE as usize),
            finished: false,
        })
    }

    /// The next message in recording order, `None` at the end, or why reading stopped.
    pub fn next(&mut self, read: &mut u64) -> Result<Option<BagMessage>, StopReason> {
        if self.page.is_empty() && !self.finished {
            self.read_page(read)
                .map_err(|error| StopReason::Io(explain(&error)))?;
        }
        Ok(self.page.pop_front())
    }

    /// Reads the next page of messages after the last one read.
    fn read_page(&mut self, read: &mut u64) -> Result<(), rusqlite::Error> {
        let mut statement = self.connection.prepare_cached(
            "SELECT id, topic_id, timestamp, data FROM messages WHERE id > ?1 ORDER BY id LIMIT ?2",
        )?;
        let mut rows = statement.query((self.after, PAGE))?;
        let mut count = 0;
        while let Some(row) = rows.next()? {
            count += 1;
            let (id, topic, stamp, data): (i64, i64, i64, Vec<u8>) =
                (row.get(0)?, row.get(1)?, row.get(2)?, row.get(3)?);
            self.after = id;
            *read += data.len() as u64;
            // A message of a topic the file does not declare has no channel: left out.
            let Some(&channel) = self.ids.get(&topic) else {
                continue;
            };
            let log_time = u64::try_from(stamp).unwrap_or(0);
            self.page.push_back(BagMessage {
                channel,
                log_time,
                publish_time: log_time,
                data,
            });
        }
        self.finished = count < PAGE;
        Ok(())
    }
}

/// Each topic of the file by its id: its channel, QoS profiles in the metadata as rosbag2's MCAP
/// storage keeps them.
fn read_topics(connection: &Connection) -> Result<Vec<(i64, ChannelInfo)>, rusqlite::Error> {
    let with_qos = connection
        .prepare("SELECT id, name, type, serialization_format, offered_qos_profiles FROM topics")
        .is_ok();
    let sql = if with_qos {
        "SELECT id, name, type, serialization_format, offered_qos_profiles FROM topics ORDER BY id"
    } else {
        "SELECT id, name, type, serialization_format, '' FROM topics ORDER BY id"
    };
    let mut statement = connection.prepare(sql)?;
    let rows = statement.query_map((), |row| {
        let qos: String = row.get(4)?;
        let metadata = if qos.is_empty() {
            BTreeMap::new()
        } else {
            BTreeMap::from([("offered_qos_profiles".to_owned(), qos)])
        };
        Ok((
            row.get::<_, i64>(0)?,
            ChannelInfo {
                topic: row.get(1)?,
                schema_name: row.get(2)?,
                schema_encoding: String::new(),
                schema_data: Vec::new(),
                message_encoding: row.get(3)?,
                metadata,
            },
        ))
    })?;
    rows.collect()
}

/// The message definitions a file holds (Iron on), by type: encoding (`ros2msg`, `ros2idl`) and
/// text; none in older files, or where rosbag2 did not find a type's definition (`unknown`).
fn read_definitions(
    connection: &Connection,
) -> Result<BTreeMap<String, (String, String)>, rusqlite::Error> {
    let has_table: bool = connection.query_row(
        "SELECT count(*) > 0 FROM sqlite_master WHERE type = 'table' AND name = 'message_definitions'",
        (),
        |row| row.get(0),
    )?;
    if !has_table {
        return Ok(BTreeMap::new());
    }
    let mut statement = connection.prepare(
        "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions",
    )?;
    let rows = statement.query_map((), |row| {
        Ok((
            row.get::<_, String>(0)?,
            (row.get::<_, String>(1)?, row.get::<_, String>(2)?),
        ))
    })?;
    let mut definitions = BTreeMap::new();
    for row in rows {
        let (name, (encoding, text)) = row?;
        if matches!(encoding.as_str(), "ros2msg" | "ros2idl") && !text.is_empty() {
            definitions.insert(name, (encoding, text));
        }
    }
    Ok(definitions)
}
