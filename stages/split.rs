//! `split`: the stage binary; everything is in [`fantasystyle::stages::split`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::split::run)
}
