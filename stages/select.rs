//! `select`: the stage binary; everything is in [`fantasystyle::stages::select`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::select::run)
}
