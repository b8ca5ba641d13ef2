//! The tables README.md and `docs/` quote are what the `ttball` command beside each prints, to
//! the digit: a block between `<!-- the table(s) below is/are printed by `ttball ARGS` -->` and
//! `<!-- end of `ttball ARGS` -->` must equal that command's output, so that a change that moves
//! a number fails here with both versions and the change of numbers is a reviewed decision.
//! `TTBALL_BLESS=1 cargo test --test cli doc_tables` writes the new tables into the files, to be
//! read in the diff and committed with the change.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    reason = "test code: fail loudly"
)]

use std::path::PathBuf;
use std::sync::Mutex;

use crate::common;

const STARTS: [&str; 2] = [
    "<!-- the table below is printed by `",
    "<!-- the tables below are printed by `",
];

/// The commands whose tables the tests below check.
const CHECKED: [&str; 6] = [
    "evaluate --readme",
    "evaluate --doc-table efficiency",
    "evaluate --doc-table sets",
    "evaluate --doc-table real-configurations",
    "evaluate --doc-table real-flights",
    "evaluate --doc-table rubbers",
];

/// One quoted table: the file, the `ttball` arguments, and the byte range between its markers.
struct Block {
    file: PathBuf,
    args: String,
    range: std::ops::Range<usize>,
}

/// README.md and every file of docs/.
fn files() -> Vec<PathBuf> {
    let mut files = vec![common::root().join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(common::root().join("docs"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    docs.sort();
    files.extend(docs);
    files
}

/// The blocks of `text` (the file `file`) that a `ttball` command prints.
fn blocks_of(file: &std::path::Path, text: &str) -> Vec<Block> {
    let mut blocks = Vec::new();
    for start in STARTS {
        for (at, _) in text.match_indices(start) {
            let command_start = at + start.len();
            let command_end = command_start + text[command_start..].find("` -->\n").unwrap();
            let command = &text[command_start..command_end];
            let Some(args) = command.strip_prefix("ttball ") else {
                continue;
            };
            let body = command_end + "` -->\n".len();
            let end = format!("<!-- end of `{command}` -->\n");
            let body_end = body
                + text[body..]
                    .find(&end)
                    .unwrap_or_else(|| panic!("{}: no `{end}`", file.display()));
            blocks.push(Block {
                file: file.to_path_buf(),
                args: args.to_string(),
                range: body..body_end,
            });
        }
    }
    blocks
}

fn all_blocks() -> Vec<Block> {
    files()
        .iter()
        .flat_map(|f| blocks_of(f, &std::fs::read_to_string(f).unwrap()))
        .collect()
}

/// Blessing rewrites files that two tests may both quote from.
static BLESSING: Mutex<()> = Mutex::new(());

/// Runs `ttball args` once and checks every block it prints (or writes them, blessing).
fn check(args: &str) {
    let printed = common::ok(&args.split_whitespace().collect::<Vec<_>>());
    let blocks: Vec<Block> = all_blocks()
        .into_iter()
        .filter(|b| b.args == args)
        .collect();
    assert!(!blocks.is_empty(), "no file quotes `ttball {args}`");
    if std::env::var_os("TTBALL_BLESS").is_some() {
        let _guard = BLESSING.lock().unwrap();
        for file in blocks.iter().map(|b| &b.file) {
            let text = std::fs::read_to_string(file).unwrap();
            // Ranges move as earlier blocks change: find this command's blocks afresh, last first.
            let mut blessed = text.clone();
            for b in blocks_of(file, &text)
                .iter()
                .rev()
                .filter(|b| b.args == args)
            {
                blessed.replace_range(b.range.clone(), &printed);
            }
            std::fs::write(file, blessed).unwrap();
        }
        return;
    }
    for b in &blocks {
        let text = std::fs::read_to_string(&b.file).unwrap();
        let quoted = &text[b.range.clone()];
        assert!(
            quoted == printed,
            "{} quotes other tables than `ttball {args}` prints; if the change is meant, run \
             `TTBALL_BLESS=1 cargo test --test cli doc_tables` and commit the file:\nquoted:\n\
             {quoted}\nprinted:\n{printed}",
            b.file.display()
        );
    }
}

#[test]
fn the_readme_holds_the_accuracy_tables_evaluate_prints() {
    check(CHECKED[0]);
}

/// The slowest: 200 shots of each camera setup, each fitted as a whole at every lead.
#[test]
fn the_accuracy_doc_holds_the_efficiency_table_evaluate_prints() {
    check(CHECKED[1]);
}

#[test]
fn the_accuracy_doc_holds_the_sets_table_evaluate_prints() {
    check(CHECKED[2]);
}

#[test]
fn the_real_flights_doc_holds_the_configurations_table_evaluate_prints() {
    check(CHECKED[3]);
}

#[test]
fn the_real_flights_doc_holds_the_flights_table_evaluate_prints() {
    check(CHECKED[4]);
}

#[test]
fn the_racket_doc_holds_the_rubbers_table_evaluate_prints() {
    check(CHECKED[5]);
}

/// A table quoted from a `ttball` command that no test checks would go stale unseen.
#[test]
fn every_table_a_ttball_command_prints_is_checked() {
    for b in all_blocks() {
        assert!(
            CHECKED.contains(&b.args.as_str()),
            "{} quotes `ttball {}`, which no test checks",
            b.file.display(),
            b.args
        );
    }
}

/// The marker parser itself: a block, its command, and a command of another program skipped.
#[test]
fn blocks_are_found_between_their_markers() {
    let text = "a\n<!-- the table below is printed by `ttball evaluate --x` -->\n| t |\n\
                <!-- end of `ttball evaluate --x` -->\n<!-- the table below is printed by \
                `cargo bench` -->\n| b |\n<!-- end of `cargo bench` -->\n";
    let blocks = blocks_of(std::path::Path::new("f.md"), text);
    assert_eq!(blocks.len(), 1);
    assert_eq!(blocks[0].args, "evaluate --x");
    assert_eq!(&text[blocks[0].range.clone()], "| t |\n");
}
