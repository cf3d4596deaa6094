//! `texsyn-worker health`: asks a running worker's `grpc.health.v1` service,
//! with the shared token if it needs one (ARCHITECTURE §4.1, §4.4).

use std::path::Path;
use std::time::Duration;

use anyhow::{bail, Context};
use texsyn_proto::auth::{read_token_file, BearerAuth};
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};

/// Checks that the worker at `address` (host:port or a URL) reports SERVING
/// within `timeout`; prints `ADDRESS SERVING` on success.
pub fn check(address: &str, token_file: Option<&Path>, timeout: Duration) -> anyhow::Result<()> {
    let token = token_file.map(read_token_file).transpose()?;
    let auth = BearerAuth::new(token.as_deref())?;
    let url = if address.contains("://") {
        address.to_string()
    } else {
        format!("http://{address}")
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(async {
        let channel = tonic::transport::Endpoint::from_shared(url)
            .with_context(|| format!("'{address}' is not a worker address (host:port)"))?
            .connect_timeout(timeout)
            .timeout(timeout)
            .connect()
            .await
            .with_context(|| format!("cannot reach the worker at {address}"))?;
        let mut client = HealthClient::with_interceptor(channel, auth);
        let reply = client
            .check(HealthCheckRequest {
                service: String::new(),
            })
            .await
            .with_context(|| format!("health check of {address} failed"))?;
        let status = reply.into_inner().status();
        if status != ServingStatus::Serving {
            bail!("worker {address} is {status:?}");
        }
        println!("{address} SERVING");
        Ok(())
    })
}
