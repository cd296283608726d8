//! `render-views`: the stage binary; everything is in [`fantasystyle::stages::render_views`].
fn main() -> std::process::ExitCode {
    fantasystyle::stages::run_main(fantasystyle::stages::render_views::run)
}
