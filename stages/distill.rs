//! `distill`: thin binary over `fantasystyle::stages::distill`.
use clap::Parser;
use fantasystyle::stages::{distill, run_main};

fn main() -> std::process::ExitCode {
    run_main(distill::Args::parse(), distill::run)
}
