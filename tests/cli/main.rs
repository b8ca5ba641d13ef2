//! Tests of the `ttball` command line, run as a user runs it: configuration, the node's command
//! line, predictions, the racket commands and the replay's signals.

#![cfg(feature = "cli")]

#[path = "../common/mod.rs"]
mod common;

mod config;
mod doc_tables;
mod golden;
mod node;
mod predict;
mod racket;
mod replay;
