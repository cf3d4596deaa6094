//! The shared-token check run on every call (DESIGN §4 "Security").

use std::sync::Arc;

use tonic::service::Interceptor;
use tonic::{Request, Status};

/// Interceptor that requires `authorization: Bearer <token>` when a token is set.
#[derive(Clone)]
pub(crate) struct TokenCheck {
    expected: Option<Arc<[u8]>>,
}

impl TokenCheck {
    pub(crate) fn new(token: Option<&str>) -> Self {
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

    fn call(check: &mut TokenCheck, header: Option<&str>) -> Result<(), tonic::Code> {
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
}
