//! `sweep`: the stage binary; everything is in [`fantasystyle::stages::sweep`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::sweep::run)
}
