//! `pipeline`: the DAG runner (to be written).
fn main() {
    eprintln!("pipeline: not implemented yet");
    std::process::exit(1);
}
