//! Writing and reading artifact directories.
//!
//! [`ArtifactWriter`] writes every file into a temporary sibling directory
//! (`.NAME.partial-PID-N`), then writes the manifest last and renames the directory
//! into place. If the stage fails or is killed, the temporary directory is left behind
//! or removed, and the previous artifact at the target path (if any) is untouched until
//! the final rename. [`Artifact::open`] checks format, kind, schema version, the
//! presence of required files and every file's blake3 before anything is read.
//!
//! One module per concern: `hash` (blake3 of files and directories), `writer`
//! ([`ArtifactWriter`] and its [`TensorStream`]) and `reader` ([`Artifact`]).

mod hash;
mod reader;
mod writer;

pub use hash::{hash_file, hash_path};
pub use reader::Artifact;
pub use writer::{ArtifactWriter, TensorStream};

#[cfg(test)]
mod fixtures;
#[cfg(test)]
mod tests;
