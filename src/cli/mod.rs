//! Implementations of the larger CLI sub-commands (binary-only; `main.rs` dispatches).

pub mod model;
