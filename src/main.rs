//! The `livereg` executable: a thin wrapper over [`livereg::cli`].

use clap::Parser;

fn main() -> std::process::ExitCode {
    livereg::cli::run(livereg::cli::Cli::parse())
}
