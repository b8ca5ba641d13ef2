//! The node's threads on chosen CPUs (`node.cpus`). Linux gives a new thread its creator's CPU
//! affinity (sched_setaffinity(2)), so the node is started from a short-lived thread allowed
//! only those CPUs: every thread it starts, RustDDS's event loop and discovery included, runs
//! there, and the caller's own affinity is left as it was.

use super::NodeError;

/// Runs `start` on a thread allowed to run only on `cpus`, so that the threads it starts inherit
/// that affinity; with no CPUs given, runs it here.
pub fn start_on<T: Send>(
    cpus: &[u32],
    start: impl FnOnce() -> Result<T, NodeError> + Send,
) -> Result<T, NodeError> {
    if cpus.is_empty() {
        return start();
    }
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .name("ttball-start".to_owned())
            .spawn_scoped(scope, || {
                pin_this_thread(cpus)?;
                start()
            })
            .map_err(|e| NodeError::Thread(e.to_string()))?
            .join()
            .map_err(|_| NodeError::Thread("starting the node panicked".to_owned()))?
    })
}

#[cfg(target_os = "linux")]
fn pin_this_thread(cpus: &[u32]) -> Result<(), NodeError> {
    use nix::sched::{CpuSet, sched_setaffinity};
    use nix::unistd::Pid;

    let mut set = CpuSet::new();
    for &cpu in cpus {
        let index = usize::try_from(cpu).unwrap_or(usize::MAX);
        set.set(index).map_err(|_| {
            NodeError::Cpus(format!(
                "node.cpus: CPU {cpu} is beyond the {} CPUs Linux can name",
                CpuSet::count()
            ))
        })?;
    }
    sched_setaffinity(Pid::from_raw(0), &set).map_err(|e| {
        let allowed = allowed_here().map_or_else(|| "unknown".to_owned(), |list| listed(&list));
        NodeError::Cpus(format!(
            "node.cpus: cannot run on CPUs {} ({e}); this process may use CPUs {allowed}: name some of them, or \"\" for any",
            listed(cpus)
        ))
    })
}

/// The CPUs the calling thread may run on, ascending; `None` when Linux does not say.
#[cfg(target_os = "linux")]
fn allowed_here() -> Option<Vec<u32>> {
    use nix::sched::{CpuSet, sched_getaffinity};
    use nix::unistd::Pid;

    let set = sched_getaffinity(Pid::from_raw(0)).ok()?;
    Some(
        (0..CpuSet::count())
            .filter(|&i| set.is_set(i).unwrap_or(false))
            .filter_map(|i| u32::try_from(i).ok())
            .collect(),
    )
}

/// CPU numbers as a message lists them: "0, 1".
#[cfg(target_os = "linux")]
fn listed(cpus: &[u32]) -> String {
    cpus.iter()
        .map(u32::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(not(target_os = "linux"))]
fn pin_this_thread(_cpus: &[u32]) -> Result<(), NodeError> {
    Err(NodeError::Cpus(
        "node.cpus works on Linux only: set it to \"\" (or pin the process with the system's tools)"
            .to_owned(),
    ))
}

#[cfg(test)]
#[cfg(target_os = "linux")]
mod tests {
    use super::*;

    fn allowed_here() -> Vec<u32> {
        super::allowed_here().expect("affinity")
    }

    #[test]
    fn threads_started_inherit_the_cpus_and_the_caller_keeps_its_own() {
        let before = allowed_here();
        let last = *before.last().expect("some cpu");
        let seen = start_on(&[last], || {
            let grandchild = std::thread::spawn(allowed_here)
                .join()
                .map_err(|_| NodeError::Thread("panicked".to_owned()))?;
            Ok((allowed_here(), grandchild))
        })
        .expect("started");
        assert_eq!(seen, (vec![last], vec![last]));
        assert_eq!(allowed_here(), before);
    }

    #[test]
    fn cpus_that_cannot_be_had_are_an_error_that_says_which_can() {
        let err = start_on(&[1023], || Ok(())).expect_err("no CPU 1023 here");
        let text = err.to_string();
        let first = allowed_here()[0];
        assert!(
            text.contains(&format!("this process may use CPUs {first}")),
            "{text}"
        );
        let err = start_on(&[5000], || Ok(())).expect_err("beyond cpu_set_t");
        assert!(err.to_string().contains("CPU 5000 is beyond"), "{err}");
    }

    #[test]
    fn no_cpus_runs_here() {
        let here = std::thread::current().id();
        assert_eq!(
            start_on(&[], || Ok(std::thread::current().id())).ok(),
            Some(here)
        );
    }
}
