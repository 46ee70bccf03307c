//! `vamos serve`: the service, until SIGTERM or Ctrl-C.

use super::async_runtime;
use anyhow::Result;
use std::path::PathBuf;
use vamos::config::Settings;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// gRPC address (default from the settings: 127.0.0.1:8081).
    #[arg(long)]
    pub grpc_addr: Option<String>,
    /// REST and /metrics address (default 127.0.0.1:8080); the gRPC address serves
    /// both on one port.
    #[arg(long)]
    pub rest_addr: Option<String>,
    /// Data directory (models, robots, profiles, calibrations).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Profile files to serve (TOML, as `vamos score --profile` takes); repeatable.
    #[arg(long = "profile")]
    pub profiles: Vec<PathBuf>,
}

/// Applies the flags over the settings and serves.
pub fn run(mut settings: Settings, args: Args) -> Result<()> {
    if let Some(a) = args.grpc_addr {
        settings.service.grpc_addr = a;
    }
    if let Some(a) = args.rest_addr {
        settings.service.rest_addr = a;
    }
    if let Some(d) = args.data_dir {
        settings.service.data_dir = d;
    }
    settings.service.profiles.extend(args.profiles);
    async_runtime()?.block_on(vamos::service::serve(settings))?;
    Ok(())
}
