//! `preview`: the stage binary; everything is in [`fantasystyle::stages::preview`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::preview::run)
}
