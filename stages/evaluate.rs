//! `evaluate`: the stage binary; everything is in [`fantasystyle::stages::evaluate`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::evaluate::run)
}
