//! `evaluate`: thin binary over the library; see `fantasystyle::stages`.
use clap::Parser;

/// evaluate (not yet implemented).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |_a| {
        Err(fantasystyle::Error::Other(
            "evaluate: not implemented yet".into(),
        ))
    })
}
