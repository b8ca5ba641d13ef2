//! `ttball config print|check`: the effective configuration, and checking a configuration file.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Subcommand};
use ttball::config::yaml::{self, LoadError};

use super::{ConfigArgs, EXIT_BAD_CONFIG, Overrides, write_stdout};

/// `ttball config ...`.
#[derive(Debug, Subcommand)]
pub enum ConfigCommand {
    /// Print the effective configuration as a ROS 2 parameters file.
    ///
    /// The effective configuration is the defaults, then --config, then each -p; it is printed
    /// on standard output.
    #[command(after_help = "Examples:\n  \
        ttball config print                                  # the defaults\n  \
        ttball config print > my.yaml                        # a file to edit\n  \
        ttball config print --config my.yaml -p intercept.plane_x:=-1.45\n\n\
        The output loads back with --config and as a ROS 2 --params-file. For the unit and \
        source of every parameter see config/ttball.yaml.")]
    Print(PrintArgs),

    /// Check a configuration file and list every problem in it.
    ///
    /// Unknown or misspelt keys, wrong types and out-of-range values are all reported. Prints
    /// `FILE: ok` and exits with 0 when the file is valid, else lists every problem and exits
    /// with 2.
    #[command(after_help = "Examples:\n  \
        ttball config check my.yaml\n  \
        ttball config check my.yaml -p table.restitution:=0.92   # with overrides applied\n\n\
        Each problem names the dotted parameter, the file and line (or the -p argument) and \
        what is allowed, e.g.\n  \
        my.yaml:5: unknown parameter `table.restitutoin`; did you mean `table.restitution`?")]
    Check(CheckArgs),
}

/// Arguments of `ttball config print`.
#[derive(Debug, Args)]
pub struct PrintArgs {
    /// The configuration to print.
    #[command(flatten)]
    pub config: ConfigArgs,
}

/// Arguments of `ttball config check`.
#[derive(Debug, Args)]
pub struct CheckArgs {
    /// The ROS 2 parameters file to check.
    #[arg(value_name = "FILE")]
    pub file: PathBuf,

    /// Overrides applied on top of the file before checking.
    #[command(flatten)]
    pub overrides: Overrides,
}

impl ConfigCommand {
    /// Runs the command.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        match self {
            Self::Print(args) => {
                let config = args.config.load()?;
                let mut text = String::from(
                    "# The effective ttball configuration (`ttball config print`).\n\
                     # Load it with --config, or as a ROS 2 --params-file.\n\
                     # Units and sources of every parameter: config/ttball.yaml.\n",
                );
                text.push_str(&yaml::to_ros_params_yaml(&config));
                write_stdout(&text)?;
                Ok(ExitCode::SUCCESS)
            }
            Self::Check(args) => check(&args),
        }
    }
}

fn check(args: &CheckArgs) -> anyhow::Result<ExitCode> {
    let name = args.file.display();
    let report = match yaml::load(Some(&args.file), &args.overrides.params) {
        Ok(_) => {
            write_stdout(&format!("{name}: ok\n"))?;
            return Ok(ExitCode::SUCCESS);
        }
        Err(LoadError::Rejected { problems }) => {
            let count = problems.len();
            let mut report = format!(
                "{name}: {count} problem{}\n",
                if count == 1 { "" } else { "s" }
            );
            for problem in problems {
                report.push_str(&format!("  - {problem}\n"));
            }
            report
        }
        Err(err @ LoadError::Internal { .. }) => return Err(err.into()),
        // These messages start with the file's name already.
        Err(err) => format!("{err}\n"),
    };
    write_stdout(&report)?;
    Ok(ExitCode::from(EXIT_BAD_CONFIG))
}
