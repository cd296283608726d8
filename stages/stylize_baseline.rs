//! `stylize-baseline`: thin binary over `fantasystyle::stages::stylize_baseline`.
use clap::Parser;
use fantasystyle::stages::{run_main, stylize_baseline};

fn main() -> std::process::ExitCode {
    run_main(stylize_baseline::Args::parse(), stylize_baseline::run)
}
