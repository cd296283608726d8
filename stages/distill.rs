//! `distill`: the stage binary; everything is in [`fantasystyle::stages::distill`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::distill::run)
}
