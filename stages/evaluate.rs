//! `evaluate`: thin binary over [`fantasystyle::stages::evaluate`].
use clap::Parser;
use fantasystyle::stages::{evaluate, run_main};

fn main() -> std::process::ExitCode {
    run_main(evaluate::Args::parse(), |a| evaluate::run(a).map(|_| ()))
}
