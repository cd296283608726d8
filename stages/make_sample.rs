//! `make-sample`: thin binary over `fantasystyle::stages::make_sample`.
use clap::Parser;
use fantasystyle::stages::{make_sample, run_main};

fn main() -> std::process::ExitCode {
    run_main(make_sample::Args::parse(), make_sample::run)
}
