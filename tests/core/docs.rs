//! The documentation's rules, checked on the files: `docs/` is reference a reader can hold (under
//! [`DOCS_WORD_LIMIT`] words, counted as `wc -w` counts them), and the README, `docs/`,
//! `config/` and the code carry no dates (a date is history, and history lives in git log).

#![allow(clippy::unwrap_used, clippy::panic, reason = "test code: fail loudly")]

use std::path::{Path, PathBuf};

/// The most words `docs/` may hold.
const DOCS_WORD_LIMIT: usize = 20_000;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The files below `dir` whose names end in one of `extensions`, sorted (the layer rule reads
/// `src/` through it too).
pub(crate) fn source_files(dir: &Path, extensions: &[&str], out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            source_files(&path, extensions, out);
        } else if path
            .extension()
            .is_some_and(|e| extensions.iter().any(|x| e == *x))
        {
            out.push(path);
        }
    }
}

/// The dates in `text` (year-month, year-month-day: `2026-12`, `2026-12-05`) with their line
/// numbers. A year alone (a citation's, `Nakashima et al. 2010`) is not one.
fn dates(text: &str) -> Vec<(usize, String)> {
    let mut found = Vec::new();
    for (number, line) in text.lines().enumerate() {
        let bytes = line.as_bytes();
        for start in 0..bytes.len() {
            let digit = |i: usize| bytes.get(start + i).is_some_and(u8::is_ascii_digit);
            let starts_a_word = start == 0 || !bytes[start - 1].is_ascii_alphanumeric();
            let century = bytes[start..].starts_with(b"19") || bytes[start..].starts_with(b"20");
            if !(starts_a_word && century && digit(2) && digit(3)) {
                continue;
            }
            if bytes.get(start + 4) != Some(&b'-') || !(digit(5) && digit(6)) || digit(7) {
                continue;
            }
            let month = (bytes[start + 5] - b'0') * 10 + (bytes[start + 6] - b'0');
            if (1..=12).contains(&month) {
                found.push((number + 1, line[start..(start + 7)].to_owned()));
            }
        }
    }
    found
}

#[test]
fn docs_hold_under_twenty_thousand_words() {
    let mut docs = Vec::new();
    source_files(&root().join("docs"), &["md"], &mut docs);
    assert!(!docs.is_empty());
    let words: usize = docs
        .iter()
        .map(|path| {
            std::fs::read_to_string(path)
                .unwrap()
                .split_whitespace()
                .count()
        })
        .sum();
    assert!(
        words < DOCS_WORD_LIMIT,
        "docs/ holds {words} words, the limit is {DOCS_WORD_LIMIT}: say it in fewer words, or \
         cut what is history rather than reference"
    );
}

#[test]
fn the_readme_docs_configuration_and_code_carry_no_dates() {
    let mut checked = vec![root().join("README.md")];
    source_files(&root().join("docs"), &["md"], &mut checked);
    source_files(&root().join("config"), &["yaml", "md"], &mut checked);
    source_files(&root().join("src"), &["rs"], &mut checked);
    source_files(&root().join("msgs"), &["msg", "srv", "md"], &mut checked);
    let mut problems = Vec::new();
    for path in &checked {
        let text = std::fs::read_to_string(path).unwrap();
        for (line, date) in dates(&text) {
            let name = path.strip_prefix(root()).unwrap().display();
            problems.push(format!("{name}:{line}: {date}"));
        }
    }
    assert!(
        problems.is_empty(),
        "dates are history, which git log keeps:\n{}",
        problems.join("\n")
    );
}

#[test]
fn the_date_finder_sees_a_date_and_not_a_year_or_a_number() {
    let text = "measured 2026-12-05\nsince 2026-11, Isomura et al. 2014\nid 12026-11 and 2014-13\n";
    let found: Vec<String> = dates(text).into_iter().map(|(_, d)| d).collect();
    assert_eq!(found, ["2026-12", "2026-11"]);
}
