//! `update-gaussians`: thin binary over the library; see `fantasystyle::stages`.
use clap::Parser;

/// update-gaussians (not yet implemented).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |_a| {
        Err(fantasystyle::Error::Other(
            "update-gaussians: not implemented yet".into(),
        ))
    })
}
