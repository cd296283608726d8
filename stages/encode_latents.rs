//! `encode-latents`: thin binary over the library; see `fantasystyle::stages`.
use clap::Parser;

/// encode-latents (not yet implemented).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |_a| {
        Err(fantasystyle::Error::Other(
            "encode-latents: not implemented yet".into(),
        ))
    })
}
