//! The shared token (ARCHITECTURE §4.4): reading it from a file
//! or stdin, the master's interceptor that sends it on every call, and the
//! worker's interceptor that checks it.

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context};
use tonic::metadata::{Ascii, MetadataValue};
use tonic::service::Interceptor;
use tonic::{Request, Status};

/// A token travels in an HTTP header: it must be non-empty printable ASCII
/// without spaces.
pub fn check_token(token: &str) -> anyhow::Result<()> {
    if token.is_empty() {
        bail!("the token is empty; put the workers' shared secret in it");
    }
    if !token.bytes().all(|b| b.is_ascii_graphic()) {
        bail!("the token must be printable ASCII without spaces (it travels in an HTTP header)");
    }
    Ok(())
}

/// Reads a token file: its contents trimmed of surrounding whitespace, checked
/// with [`check_token`].
pub fn read_token_file(path: &Path) -> anyhow::Result<String> {
    let raw = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read the token file {}", path.display()))?;
    read_token(&raw).with_context(|| format!("token file {}", path.display()))
}

/// A token from text (a file's contents or a line of stdin), trimmed and checked.
pub fn read_token(text: &str) -> anyhow::Result<String> {
    let token = text.trim().to_string();
    check_token(&token)?;
    Ok(token)
}

/// Client interceptor adding `authorization: Bearer <token>` to every call
/// (nothing when there is no token):
/// `WorkerClient::with_interceptor(channel, BearerAuth::new(token)?)`.
#[derive(Clone, Default)]
pub struct BearerAuth {
    value: Option<MetadataValue<Ascii>>,
}

impl BearerAuth {
    pub fn new(token: Option<&str>) -> anyhow::Result<Self> {
        let value = token
            .map(|t| {
                format!("Bearer {t}")
                    .parse::<MetadataValue<Ascii>>()
                    .context("the token must be printable ASCII")
            })
            .transpose()?;
        Ok(Self { value })
    }
}

impl std::fmt::Debug for BearerAuth {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BearerAuth")
            .field("token", &self.value.as_ref().map(|_| "<redacted>"))
            .finish()
    }
}

impl Interceptor for BearerAuth {
    fn call(&mut self, mut request: Request<()>) -> Result<Request<()>, Status> {
        if let Some(v) = &self.value {
            request.metadata_mut().insert("authorization", v.clone());
        }
        Ok(request)
    }
}

/// Server interceptor that requires `authorization: Bearer <token>` when a
/// token is set.
#[derive(Clone)]
pub struct TokenCheck {
    expected: Option<Arc<[u8]>>,
}

impl TokenCheck {
    pub fn new(token: Option<&str>) -> Self {
        Self {
            expected: token.map(|t| Arc::from(format!("Bearer {t}").into_bytes())),
        }
    }
}

/// Compares without an early exit, so timing does not reveal the matching prefix.
fn same(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

impl Interceptor for TokenCheck {
    fn call(&mut self, request: Request<()>) -> Result<Request<()>, Status> {
        let Some(expected) = &self.expected else {
            return Ok(request);
        };
        match request.metadata().get("authorization") {
            None => Err(Status::unauthenticated(
                "missing `authorization: Bearer <token>` metadata; this worker requires the shared token",
            )),
            Some(v) if same(v.as_bytes(), expected) => Ok(request),
            Some(_) => Err(Status::unauthenticated(
                "wrong token in the `authorization` metadata",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn call(check: &mut impl Interceptor, header: Option<&str>) -> Result<(), tonic::Code> {
        let mut r = Request::new(());
        if let Some(h) = header {
            r.metadata_mut().insert("authorization", h.parse().unwrap());
        }
        check.call(r).map(|_| ()).map_err(|s| s.code())
    }

    #[test]
    fn token_is_required_when_set() {
        let mut c = TokenCheck::new(Some("abc"));
        assert_eq!(call(&mut c, Some("Bearer abc")), Ok(()));
        assert_eq!(
            call(&mut c, Some("Bearer abd")),
            Err(tonic::Code::Unauthenticated)
        );
        assert_eq!(call(&mut c, Some("abc")), Err(tonic::Code::Unauthenticated));
        assert_eq!(call(&mut c, None), Err(tonic::Code::Unauthenticated));
        let mut open = TokenCheck::new(None);
        assert_eq!(call(&mut open, None), Ok(()));
    }

    #[test]
    fn bearer_auth_passes_the_check() {
        let mut sent = Request::new(());
        BearerAuth::new(Some("s3cret"))
            .unwrap()
            .call(Request::new(()))
            .map(|r| sent = r)
            .unwrap();
        let mut check = TokenCheck::new(Some("s3cret"));
        assert!(check.call(sent).is_ok());
    }

    #[test]
    fn token_files_are_trimmed_and_checked() {
        let dir = std::env::temp_dir().join(format!("texsyn-token-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("token");
        std::fs::write(&f, "  abc123\n").unwrap();
        assert_eq!(read_token_file(&f).unwrap(), "abc123");
        std::fs::write(&f, "\n").unwrap();
        assert!(format!("{:#}", read_token_file(&f).unwrap_err()).contains("empty"));
        std::fs::write(&f, "a b").unwrap();
        assert!(read_token_file(&f).is_err());
        assert!(read_token_file(&dir.join("missing")).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
