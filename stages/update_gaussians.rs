//! `update-gaussians`: thin binary over `fantasystyle::stages::update_gaussians`.
use clap::Parser;
use fantasystyle::stages::{run_main, update_gaussians};

fn main() -> std::process::ExitCode {
    run_main(update_gaussians::Args::parse(), update_gaussians::run)
}
