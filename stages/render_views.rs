//! `render-views`: thin binary over the library; see `fantasystyle::stages`.
use clap::Parser;

/// render-views (not yet implemented).
#[derive(Parser, Debug)]
#[command(version)]
struct Args {}

fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(Args::parse(), |_a| {
        Err(fantasystyle::Error::Other(
            "render-views: not implemented yet".into(),
        ))
    })
}
