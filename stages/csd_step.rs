//! `csd-step`: the stage binary; everything is in [`fantasystyle::stages::csd_step`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::csd_step::run)
}
