//! The layer rule of `src/lib.rs`, checked on the source: a module uses only its own layer and
//! the layers listed before it (below it), never one listed after it (above it). Every `crate::`
//! path outside comments is read, in library code and in its unit tests alike. And no function
//! of `src/` is longer than [`LONGEST_FUNCTION`] lines.

#![allow(clippy::unwrap_used, clippy::panic, reason = "test code: fail loudly")]

use std::path::{Path, PathBuf};

use crate::docs::source_files;

/// The layers, lowest first, as `src/lib.rs` lists them.
const LAYERS: [&str; 10] = [
    "model", "config", "physics", "online", "offline", "eval", "plot", "ros", "bag", "node",
];

fn rank(layer: &str) -> Option<usize> {
    LAYERS.iter().position(|l| *l == layer)
}

/// Every layer named after `crate::` on a line of code (comments left out).
fn used_layers(text: &str) -> Vec<(usize, String)> {
    let mut used = Vec::new();
    for (number, line) in text.lines().enumerate() {
        let code = line.split("//").next().unwrap_or("");
        let mut rest = code;
        while let Some(at) = rest.find("crate::") {
            let after = &rest[at + "crate::".len()..];
            let name: String = after
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            used.push((number + 1, name));
            rest = after;
        }
    }
    used
}

#[test]
fn every_module_uses_only_its_layer_and_the_layers_below_it() {
    let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    source_files(&src, &["rs"], &mut files);
    let mut broken = Vec::new();
    let mut checked = 0;
    for file in &files {
        let relative = file.strip_prefix(&src).unwrap();
        let top = relative
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let top = top.trim_end_matches(".rs");
        if matches!(top, "lib" | "main" | "cli") {
            continue;
        }
        let own = rank(top).unwrap_or_else(|| {
            panic!("src/{top} is in no layer: add it to src/lib.rs's list and to LAYERS here")
        });
        checked += 1;
        let text = std::fs::read_to_string(file).unwrap();
        for (line, name) in used_layers(&text) {
            match rank(&name) {
                Some(used) if used > own => broken.push(format!(
                    "src/{}:{line}: layer {top} uses crate::{name}, a layer above it",
                    relative.display()
                )),
                Some(_) => {}
                None => broken.push(format!(
                    "src/{}:{line}: crate::{name} is in no layer",
                    relative.display()
                )),
            }
        }
    }
    assert!(
        checked > 50,
        "only {checked} source files found under {}",
        src.display()
    );
    assert!(broken.is_empty(), "{}", broken.join("\n"));
}

#[test]
fn the_layer_list_here_is_the_one_in_lib_rs() {
    let lib = std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src/lib.rs"))
        .unwrap();
    let declared: Vec<&str> = lib
        .lines()
        .filter_map(|l| l.trim().strip_prefix("pub mod "))
        .map(|l| l.trim_end_matches(';'))
        .collect();
    assert_eq!(
        declared, LAYERS,
        "src/lib.rs declares its layers in this order"
    );
    for (i, layer) in LAYERS.iter().enumerate() {
        let entry = format!("//! {}. ", i + 1);
        let line = lib
            .lines()
            .find(|l| l.starts_with(&entry))
            .unwrap_or_else(|| panic!("src/lib.rs's docs list no layer {}", i + 1));
        assert!(
            line.contains(layer),
            "layer {} of src/lib.rs's docs is not {layer}: {line}",
            i + 1
        );
    }
}

#[test]
fn the_checker_sees_a_path_into_a_lower_layer() {
    let used = used_layers("use crate::bag::replay; // crate::node in a comment\n");
    assert_eq!(used, vec![(1, "bag".to_string())]);
}

/// The longest a function of `src/` may be [lines], its signature and closing brace included: one
/// a reader holds at once.
const LONGEST_FUNCTION: usize = 120;

/// Each function of `text` (a `fn` at the start of a line, with a body) as (its first line,
/// its name, its length in lines): from its signature to the closing brace at its indentation.
fn function_lengths(text: &str) -> Vec<(usize, String, usize)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut found = Vec::new();
    for (start, line) in lines.iter().enumerate() {
        let code = line.trim_start();
        let indent = line.len() - code.len();
        let Some(at) = code.find("fn ") else {
            continue;
        };
        let prefix = &code[..at];
        let qualifiers = [
            "pub",
            "pub(crate)",
            "pub(super)",
            "const",
            "async",
            "unsafe",
        ];
        if !prefix.split_whitespace().all(|w| qualifiers.contains(&w)) {
            continue;
        }
        let name: String = code[at + 3..]
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        // A declaration without a body (in a trait) ends with `;` before any `{`.
        let Some(open) = (start..lines.len())
            .find(|&k| lines[k].contains('{') || lines[k].trim_end().ends_with(';'))
        else {
            continue;
        };
        if !lines[open].contains('{') {
            continue;
        }
        // A body on one line (`fn f() {}`), else the closing brace alone at the indentation.
        let balanced = lines[open].matches('{').count() == lines[open].matches('}').count();
        let closing = " ".repeat(indent) + "}";
        let end = if balanced {
            open
        } else {
            (open + 1..lines.len())
                .find(|&k| lines[k].trim_end() == closing)
                .unwrap_or(lines.len() - 1)
        };
        found.push((start + 1, name, end - start + 1));
    }
    found
}

#[test]
fn no_function_in_src_is_longer_than_a_reader_holds() {
    let mut files = Vec::new();
    source_files(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("src"),
        &["rs"],
        &mut files,
    );
    let mut long = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).unwrap();
        for (line, name, length) in function_lengths(&text) {
            if length > LONGEST_FUNCTION {
                long.push(format!("{}:{line} {name}: {length} lines", file.display()));
            }
        }
    }
    assert!(
        long.is_empty(),
        "functions over {LONGEST_FUNCTION} lines (split them):\n{}",
        long.join("\n")
    );
}

#[test]
fn the_length_checker_measures_a_function_to_its_closing_brace() {
    let text = "impl A {\n    pub(crate) fn short(\n        x: u8,\n    ) -> u8 {\n        if x > 0 {\n            1\n        } else {\n            0\n        }\n    }\n\n    fn declared();\n}\nfn free() {}\nfn after() {\n}\n";
    let found = function_lengths(text);
    assert_eq!(
        found,
        vec![
            (2, "short".to_owned(), 9),
            (14, "free".to_owned(), 1),
            (15, "after".to_owned(), 2)
        ]
    );
}
