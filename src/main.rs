//! The `ttball` command-line tool.
fn main() {}
