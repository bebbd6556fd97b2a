//! The `canopy` command: parses the command line and runs it ([`canopy::cli`]); the viewer
//! when no command is given.

use std::process::ExitCode;

use clap::Parser as _;

use canopy::cli::{Cli, exit_code, run};

fn main() -> ExitCode {
    // Output piped into a program that stops reading (`canopy info | head -1`) ends the
    // process quietly, as for any command-line tool, instead of a panic in println!.
    #[cfg(unix)]
    // SAFETY: restores the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn")).init();
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(exit_code(&e))
        }
    }
}
