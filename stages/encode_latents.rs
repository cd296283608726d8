//! `encode-latents`: the stage binary; everything is in [`fantasystyle::stages::encode_latents`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::encode_latents::run)
}
