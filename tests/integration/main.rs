//! Integration tests: one binary, one module per area.

mod architecture;
mod cli;
mod flow_golden;
