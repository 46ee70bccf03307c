//! Integration tests: one binary, one module per area.

// Test code may unwrap: a failure is a test failure with a backtrace.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod abuse;
mod architecture;
mod camera_motion;
mod cli;
mod client;
mod demo;
mod deploy;
mod detect_cli;
mod detect_episode;
mod episode_mcap;
mod episode_rosbag2;
mod eval_metrics;
mod export_dataset;
mod faults;
mod fleet;
mod flow_accuracy;
mod flow_golden;
mod fuzz_corpus;
mod kserve;
mod model;
mod model_trained;
#[cfg(feature = "otlp")]
mod otlp;
mod profile_init;
mod registration_accuracy;
mod reliability;
mod render_cli;
mod robot_fk;
mod scorer_model;
mod service;
mod service_admin;
