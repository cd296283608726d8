//! (sample scene generator: being written)
