//! The node's own log records on `/rosout` (`rcl_interfaces/msg/Log`), as well as on standard
//! error: the command line's log layer hands each event of ttball at or above the logger's
//! level (`--log-level`, INFO by default; rcl forwards the same) to [`forward`], which publishes
//! it while a node runs (the node installs its writer when it
//! starts and takes it away when it stops). Other crates' events (RustDDS's) stay on standard
//! error only.

use std::cell::Cell;
use std::sync::Mutex;

use ros2_client::Publisher;
use ros2_client::log::Log;

/// rcl_interfaces/msg/Log levels.
pub const DEBUG: u8 = 10;
/// rcl_interfaces/msg/Log levels.
pub const INFO: u8 = 20;
/// rcl_interfaces/msg/Log levels.
pub const WARN: u8 = 30;
/// rcl_interfaces/msg/Log levels.
pub const ERROR: u8 = 40;

struct Sink {
    publisher: Publisher<Log>,
    /// The node's logger name (`robot1.ttball` for `/robot1/ttball`, as rcl names it).
    name: String,
}

static SINK: Mutex<Option<Sink>> = Mutex::new(None);

thread_local! {
    /// Set while a record is published, so that a warning on the way is not forwarded again.
    static FORWARDING: Cell<bool> = const { Cell::new(false) };
}

/// The logger name rcl gives the node of fully qualified name `fqn`.
pub fn logger_name(fqn: &str) -> String {
    fqn.trim_start_matches('/').replace('/', ".")
}

/// Publishes the node's log records on `publisher` from now on.
pub(super) fn install(publisher: Publisher<Log>, node_fqn: &str) {
    if let Ok(mut sink) = SINK.lock() {
        *sink = Some(Sink {
            publisher,
            name: logger_name(node_fqn),
        });
    }
}

/// Stops publishing (the node stops; its writer goes before its participant).
pub(super) fn uninstall() {
    if let Ok(mut sink) = SINK.lock() {
        *sink = None;
    }
}

/// Publishes a log record of rcl level `level` on `/rosout`, if a node runs.
pub fn forward(level: u8, message: &str, file: &str, function: &str, line: u32) {
    if FORWARDING.with(Cell::get) {
        return;
    }
    FORWARDING.with(|f| f.set(true));
    if let Ok(sink) = SINK.lock()
        && let Some(sink) = sink.as_ref()
    {
        let _ = sink.publisher.publish(Log {
            stamp: ros2_client::builtin_interfaces::Time::now(),
            level,
            name: sink.name.clone(),
            msg: message.to_owned(),
            file: file.to_owned(),
            function: function.to_owned(),
            line,
        });
    }
    FORWARDING.with(|f| f.set(false));
}

#[cfg(test)]
mod tests {
    #[test]
    fn logger_names_follow_rcl() {
        assert_eq!(super::logger_name("/ttball"), "ttball");
        assert_eq!(super::logger_name("/robot1/ttball"), "robot1.ttball");
    }
}
