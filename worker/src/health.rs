//! `texsyn-worker health`: asks a running worker's `grpc.health.v1` service,
//! with the shared token if it needs one, over TLS as the address and the
//! `--tls-*` options say (ARCHITECTURE §4.1, §4.4).

use std::path::Path;
use std::time::Duration;

use anyhow::{anyhow, bail, Context};
use texsyn_proto::auth::{read_token_file, BearerAuth};
use texsyn_proto::tls::{error_chain, ClientTls};
use tonic_health::pb::health_check_response::ServingStatus;
use tonic_health::pb::{health_client::HealthClient, HealthCheckRequest};

/// Checks that the worker at `address` (host:port or an http(s):// URL)
/// reports SERVING within `timeout`; prints `ADDRESS SERVING` on success.
pub fn check(
    address: &str,
    token_file: Option<&Path>,
    tls: &ClientTls,
    timeout: Duration,
) -> anyhow::Result<()> {
    let token = token_file.map(read_token_file).transpose()?;
    let auth = BearerAuth::new(token.as_deref())?;
    tls.check(&[address])?;
    let endpoint = tls.endpoint(address, timeout)?.timeout(timeout);
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(async {
        let channel = match tokio::time::timeout(timeout, endpoint.connect()).await {
            Ok(Ok(c)) => c,
            Ok(Err(e)) => bail!(
                "cannot reach the worker at {address}: {}",
                tls.explain(address, error_chain(&e))
            ),
            Err(_) => bail!("cannot reach the worker at {address} within {timeout:?}"),
        };
        let mut client = HealthClient::with_interceptor(channel, auth);
        let call = client.check(HealthCheckRequest {
            service: String::new(),
        });
        let reply = match tokio::time::timeout(timeout, call).await {
            Ok(Ok(r)) => r,
            Ok(Err(s)) => {
                let mut text = format!("{:?}: {}", s.code(), s.message());
                if let Some(src) = std::error::Error::source(&s) {
                    text = format!("{text}: {}", error_chain(src));
                }
                return Err(anyhow!(
                    "health check of {address} failed: {}",
                    tls.explain(address, text)
                ));
            }
            Err(_) => bail!("health check of {address} got no answer within {timeout:?}"),
        };
        let status = reply.into_inner().status();
        if status != ServingStatus::Serving {
            bail!("worker {address} is {status:?}");
        }
        println!("{address} SERVING");
        Ok(())
    })
}
