//! The fantasystyle DAG runner: load a DAG of stage commands (`dag`), decide what is
//! stale from a lock file of content hashes (`lock`, `state`), run what is stale in
//! dependency order with per-stage logs (`run`), and look inside artifacts (`inspect`).
//! It depends on the artifact schemas only, never on the numerical core or onnxruntime.
//! Every fallible function returns [`error::Result`] (one error enum, [`Error`]).

pub mod dag;
pub mod error;
pub mod export;
pub mod inspect;
pub mod lock;
pub mod run;
pub mod show;
pub mod state;
pub mod tools;

pub use error::{Error, Result};
