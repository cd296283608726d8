//! Content leakage ([`fantasystyle::metrics::leakage`]) of one or more stylized views
//! artifacts against the original views and the style image, without the rest of
//! `evaluate` (no networks: a second or so per 16 views of 256x256):
//!
//! ```text
//! cargo run --release --example leakage -- --original runs/source --style style.png runs/a/views runs/b/views
//! ```
//!
//! Prints one line per stylized artifact: the leakage (mean over views, 95% interval),
//! the unexplained share before the division by the style's large-scale share, and the
//! views used.

use clap::Parser;
use fantasystyle::imageio::Image;
use fantasystyle::metrics::leakage;
use std::path::PathBuf;

/// Content leakage of stylized views artifacts against the original views and the style.
#[derive(Parser, Debug)]
struct Args {
    /// Views artifact of the original (unstylized) scene.
    #[arg(long)]
    original: PathBuf,
    /// The style image (PNG or JPEG).
    #[arg(long)]
    style: PathBuf,
    /// Views artifacts of stylized scenes, rendered from the original's cameras.
    #[arg(required = true)]
    stylized: Vec<PathBuf>,
}

fn main() -> std::process::ExitCode {
    match run(Args::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

fn run(a: Args) -> fantasystyle::Result<()> {
    let orig = fantasystyle::artifacts::read_view_set(&a.original)?;
    let style = Image::load(&a.style)?;
    println!("leakage\tci95\tunexplained_share\tviews\tstylized");
    for dir in &a.stylized {
        let styl = fantasystyle::artifacts::read_view_set(dir)?;
        orig.check_same_views(&styl)?;
        let l = leakage::leakage(&orig, &styl, &style);
        let f = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3}"));
        let ci = l
            .ci95
            .map_or("n/a".to_string(), |[lo, hi]| format!("[{lo:.3}, {hi:.3}]"));
        println!(
            "{}\t{ci}\t{}\t{}/{}\t{}",
            f(l.value),
            f(l.unexplained_share),
            l.views_used,
            l.per_view.len(),
            dir.display()
        );
    }
    Ok(())
}
