//! Integration tests: one binary, one module per area.

mod architecture;
mod cli;
mod flow_accuracy;
mod flow_golden;
mod registration_accuracy;
