//! The fantasystyle DAG runner (to be written).
