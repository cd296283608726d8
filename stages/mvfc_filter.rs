//! `mvfc-filter`: the stage binary; everything is in [`fantasystyle::stages::mvfc_filter`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::mvfc_filter::run)
}
