//! README.md's accuracy tables are what `ttball evaluate --readme` prints, to the digit: a
//! change that moves them fails here with both versions, so that a change of numbers is a
//! reviewed decision. `TTBALL_BLESS=1 cargo test --test cli readme` writes the new tables into
//! README.md, to be read in the diff and committed with the change.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "test code: fail loudly"
)]

use crate::common;

const START: &str = "<!-- the tables below are printed by `ttball evaluate --readme` -->\n";
const END: &str = "<!-- end of `ttball evaluate --readme` -->\n";

#[test]
fn the_readme_holds_the_tables_evaluate_prints() {
    let path = common::root().join("README.md");
    let readme = std::fs::read_to_string(&path).unwrap();
    let start = readme
        .find(START)
        .expect("the README marks where the tables start")
        + START.len();
    let end = readme[start..].find(END).expect("and where they end") + start;
    let printed = common::ok(&["evaluate", "--readme"]);
    if std::env::var_os("TTBALL_BLESS").is_some() {
        let blessed = format!("{}{printed}{}", &readme[..start], &readme[end..]);
        std::fs::write(&path, blessed).unwrap();
        return;
    }
    assert!(
        readme[start..end] == printed,
        "README.md's accuracy tables differ from `ttball evaluate --readme`; if the change is \
         meant, run `TTBALL_BLESS=1 cargo test --test cli readme` and commit README.md:\n\
         README.md:\n{}\nprinted:\n{printed}",
        &readme[start..end]
    );
}
