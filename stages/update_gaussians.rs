//! `update-gaussians`: the stage binary; everything is in [`fantasystyle::stages::update_gaussians`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::update_gaussians::run)
}
