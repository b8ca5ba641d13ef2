//! The `ttball` command-line tool: `ttball --help` lists the commands.
//!
//! Errors are `anyhow` here only; a bad configuration exits with code 2, any other failure with 1.

mod cli;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let args = cli::Cli::parse();
    match args.command.run() {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {err:#}");
            cli::exit_code_for(&err)
        }
    }
}
