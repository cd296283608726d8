//! `make-sample`: the stage binary; everything is in [`fantasystyle::stages::make_sample`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::make_sample::run)
}
