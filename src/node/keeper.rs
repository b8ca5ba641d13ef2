//! Keeps what the node's estimator learned in a file as it runs (`ttball node --learned FILE`):
//! a thread of its own writes each lesson the estimator thread offers (at most one a diagnostics
//! period, when it changed) to a temporary file beside the target and renames it over the target,
//! so the file is always whole and a crash loses at most one period's learning. The estimator
//! thread only clones the lesson; the file's text ([`LearnedSummary::file_text`]) and the write
//! happen here. The last lesson, when the node stops, is written before the node's stop returns.

use std::path::PathBuf;
use std::thread::JoinHandle;

use crossbeam::channel::{self, Sender, TrySendError};
use tracing::{debug, warn};

use crate::config::Config;
use crate::online::estimator::LearnedSummary;

/// A lesson to write: the configuration the estimator ran with and what it learned.
type Lesson = (Config, LearnedSummary);

/// The writer thread and the last lesson offered to it.
pub(crate) struct LearnedKeeper {
    to_writer: Option<Sender<Lesson>>,
    writer: Option<JoinHandle<()>>,
    offered: Option<LearnedSummary>,
}

impl LearnedKeeper {
    /// Starts the writer of `path`; `base` is the configuration the node started with (the file
    /// holds the values that differ from it), `node_name` says who wrote it.
    pub(crate) fn start(path: PathBuf, base: Config, node_name: String) -> std::io::Result<Self> {
        // Room for one lesson: a newer one waits for the writer, or is offered again later.
        let (to_writer, lessons) = channel::bounded::<Lesson>(1);
        let writer = std::thread::Builder::new()
            .name("ttball-learned".to_owned())
            .spawn(move || {
                let by = format!("`ttball node --learned` ({node_name})");
                for (running, learned) in lessons {
                    match write(&path, &base, &running, &learned, &by) {
                        Ok(()) => debug!("what was learned written to {}", path.display()),
                        Err(e) => warn!("cannot keep what was learned in {}: {e}", path.display()),
                    }
                }
            })?;
        Ok(Self {
            to_writer: Some(to_writer),
            writer: Some(writer),
            offered: None,
        })
    }

    /// Offers the lesson as it stands, if it changed since the last one taken; never waits.
    pub(crate) fn offer(&mut self, running: &Config, learned: LearnedSummary) {
        if self.offered.as_ref() == Some(&learned) {
            return;
        }
        let Some(to_writer) = &self.to_writer else {
            return;
        };
        match to_writer.try_send((running.clone(), learned.clone())) {
            Ok(()) => self.offered = Some(learned),
            // The writer is busy with the previous one: offered again at the next period.
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {}
        }
    }

    /// Writes the last lesson and waits for the writer to end.
    pub(crate) fn finish(mut self, running: &Config, learned: LearnedSummary) {
        if let Some(to_writer) = self.to_writer.take() {
            if self.offered.as_ref() != Some(&learned) {
                let _ = to_writer.send((running.clone(), learned));
            }
            drop(to_writer);
        }
        if let Some(writer) = self.writer.take()
            && writer.join().is_err()
        {
            warn!("the thread keeping what was learned panicked");
        }
    }
}

/// The lesson's file, written whole: to `path` with `.tmp` appended, then renamed over `path`.
fn write(
    path: &std::path::Path,
    base: &Config,
    running: &Config,
    learned: &LearnedSummary,
    by: &str,
) -> Result<(), String> {
    let text = learned
        .file_text(base, running, by)
        .map_err(|e| format!("what was learned is not a valid configuration: {e}"))?;
    let mut temporary = path.as_os_str().to_owned();
    temporary.push(".tmp");
    let temporary = PathBuf::from(temporary);
    std::fs::write(&temporary, text).map_err(|e| e.to_string())?;
    std::fs::rename(&temporary, path).map_err(|e| e.to_string())
}
