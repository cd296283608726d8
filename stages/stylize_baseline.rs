//! `stylize-baseline`: the stage binary; everything is in [`fantasystyle::stages::stylize_baseline`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::stylize_baseline::run)
}
