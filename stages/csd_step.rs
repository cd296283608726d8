//! `csd-step`: thin binary over the library; see `fantasystyle::stages`.
use clap::Parser;

/// csd-step (not yet implemented).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |_a| {
        Err(fantasystyle::Error::Other(
            "csd-step: not implemented yet".into(),
        ))
    })
}
