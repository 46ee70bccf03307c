//! `vamos health`: a running server's gRPC health (grpc.health.v1) as one JSON object;
//! the exit code says whether it serves.

use super::{Failed, async_runtime};
use anyhow::{Context, Result};
use serde_json::json;
use std::path::PathBuf;
use vamos::client::{Client, ClientOptions};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// gRPC address of the server.
    #[arg(long, default_value = "http://127.0.0.1:8081")]
    pub server: String,
    /// Service to ask about ("" is the whole server).
    #[arg(long, default_value = "vamos.v1.Monitor")]
    pub service: String,
    /// PEM file of the CA for an https:// server.
    #[arg(long)]
    pub ca: Option<PathBuf>,
    /// Give up after this many seconds.
    #[arg(long, default_value_t = 5.0)]
    pub timeout: f64,
}

/// Asks the server; [`Failed`] (exit code 1, nothing more printed) unless it serves.
pub fn run(args: Args) -> Result<()> {
    let Args {
        server,
        service,
        ca,
        timeout,
    } = args;
    let ca_pem = match ca {
        Some(p) => Some(std::fs::read(&p).with_context(|| format!("cannot read {}", p.display()))?),
        None => None,
    };
    let limit = std::time::Duration::from_secs_f64(timeout.clamp(0.1, 3600.0));
    let status = async_runtime()?.block_on(async {
        tokio::time::timeout(limit, async {
            let options = ClientOptions {
                ca_pem,
                connect_timeout: Some(limit),
                ..Default::default()
            };
            let client = Client::connect(&server, options).await?;
            client.health(&service).await
        })
        .await
    });
    let status = match status {
        Ok(Ok(s)) => s,
        Ok(Err(e)) => return unhealthy(&server, "ERROR", e.to_string()),
        Err(_) => {
            return unhealthy(
                &server,
                "UNREACHABLE",
                format!("no answer within {timeout} s"),
            );
        }
    };
    println!(
        "{}",
        json!({ "server": server, "service": service, "status": status })
    );
    if status != "SERVING" {
        return Err(Failed.into());
    }
    Ok(())
}

fn unhealthy(server: &str, status: &str, error: String) -> Result<()> {
    println!(
        "{}",
        json!({ "server": server, "status": status, "error": error })
    );
    Err(Failed.into())
}
