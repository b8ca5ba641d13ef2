//! The shipped bags' replay summaries, committed in `tests/golden/`: how many tracks, what was
//! rejected and why, what was learned and, for the simulated bags, the accuracy against their
//! truth, to the summary's printed precision (the timing lines, which are the machine's, left
//! out). A change that moves any of it fails here with the difference, so that a change of
//! numbers is a reviewed decision: `TTBALL_BLESS=1 cargo test --test cli golden` writes the new
//! summaries, to be read in the diff and committed with the change.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use crate::common;

/// The replay summary of `bag` without its timing lines and with its output path named `OUT`.
fn summary(bag: &str) -> String {
    let dir = common::scratch("golden");
    let output = dir.join("out.mcap");
    let printed = common::ok(&["replay", bag, "-o", output.to_str().unwrap()]);
    let _ = std::fs::remove_dir_all(&dir);
    printed
        .lines()
        .filter(|l| !l.contains("processing per detection") && !l.contains("whole run"))
        .map(|l| l.replace(output.to_str().unwrap(), "OUT"))
        .collect::<Vec<_>>()
        .join("\n")
        + "\n"
}

/// The lines of `a` and `b` that differ, marked.
fn difference(a: &str, b: &str) -> String {
    let (a, b): (Vec<&str>, Vec<&str>) = (a.lines().collect(), b.lines().collect());
    (0..a.len().max(b.len()))
        .filter(|&i| a.get(i) != b.get(i))
        .map(|i| {
            format!(
                "- {}\n+ {}\n",
                a.get(i).copied().unwrap_or(""),
                b.get(i).copied().unwrap_or("")
            )
        })
        .collect()
}

#[test]
fn the_shipped_bags_replay_to_their_golden_summaries() {
    let bless = std::env::var_os("TTBALL_BLESS").is_some();
    let mut moved = Vec::new();
    for bag in ["real_launcher", "sim_rally_2cams", "sim_rally_wide"] {
        let golden = common::root().join(format!("tests/golden/{bag}.txt"));
        let now = summary(&format!("bags/{bag}.mcap"));
        if bless {
            std::fs::write(&golden, &now).unwrap();
            continue;
        }
        let committed = std::fs::read_to_string(&golden).unwrap_or_default();
        if committed != now {
            moved.push(format!(
                "{bag} (tests/golden/{bag}.txt):\n{}",
                difference(&committed, &now)
            ));
        }
    }
    assert!(
        moved.is_empty(),
        "the replay summaries moved; if that is meant, run `TTBALL_BLESS=1 cargo test --test \
         cli golden` and commit tests/golden/ with the change:\n{}",
        moved.join("\n")
    );
}
