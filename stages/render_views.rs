//! `render-views`: thin binary over `fantasystyle::stages::render_views`.
use clap::Parser;
use fantasystyle::stages::{render_views, run_main};

fn main() -> std::process::ExitCode {
    run_main(render_views::Args::parse(), render_views::run)
}
