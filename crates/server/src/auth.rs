//! Bearer-token authentication, compared in constant time.
//!
//! Every configured token is compared with the presented one (no early exit on a match, and
//! each comparison folds every byte), so timing reveals neither which token matched nor how
//! many leading bytes were right. A session belongs to the token that created it
//! ([`Owner`]).

use std::sync::Arc;

use super::config::TokenEntry;
use super::error::ApiError;

/// Who is calling: the name of the token used (or `dev` in loopback development mode).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) struct Owner(pub Arc<str>);

impl Owner {
    /// The owner's name (never the token).
    pub(crate) fn name(&self) -> &str {
        &self.0
    }
}

/// Byte strings equal, in time that depends only on their lengths (xor fold over the longer
/// length, the length difference folded in).
pub(crate) fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    let n = a.len().max(b.len());
    let mut diff: u64 = (a.len() ^ b.len()) as u64;
    for i in 0..n {
        let x = a.get(i).copied().unwrap_or(0);
        let y = b.get(i).copied().unwrap_or(0);
        diff |= u64::from(x ^ y);
    }
    std::hint::black_box(diff) == 0
}

/// The accepted tokens.
#[derive(Debug, Clone)]
pub(crate) struct Authenticator {
    tokens: Vec<(Owner, Vec<u8>)>,
    /// No token needed (loopback development mode): everyone is [`Authenticator::DEV_OWNER`].
    open: bool,
}

impl Authenticator {
    /// Owner name of every request in loopback development mode.
    pub(crate) const DEV_OWNER: &'static str = "dev";

    /// Accepts `tokens`; with `open`, requests without a token are accepted as `dev` (a given
    /// token is still checked).
    pub(crate) fn new(tokens: &[TokenEntry], open: bool) -> Self {
        Self {
            tokens: tokens
                .iter()
                .map(|t| {
                    (
                        Owner(Arc::from(t.name.as_str())),
                        t.token.as_bytes().to_vec(),
                    )
                })
                .collect(),
            open,
        }
    }

    /// Owner for an `Authorization` header value (`Bearer <token>`), or 401 naming what is
    /// wrong (missing header, wrong scheme, unknown token).
    pub(crate) fn authenticate(&self, header: Option<&[u8]>) -> Result<Owner, ApiError> {
        let Some(raw) = header else {
            if self.open {
                return Ok(Owner(Arc::from(Self::DEV_OWNER)));
            }
            return Err(ApiError::unauthorized(
                "missing bearer token: send the header `Authorization: Bearer <token>`",
            ));
        };
        let text = std::str::from_utf8(raw)
            .map_err(|_| ApiError::unauthorized("the Authorization header is not valid text"))?;
        // RFC 9110 §11.1: the scheme is case-insensitive (`Bearer`, `bearer`, `BEARER`).
        let token = text
            .trim_start()
            .split_once([' ', '\t'])
            .filter(|(scheme, _)| scheme.eq_ignore_ascii_case("bearer"))
            .map(|(_, token)| token.trim())
            .ok_or_else(|| {
                ApiError::unauthorized("the Authorization header must be `Bearer <token>`")
            })?;
        let mut found: Option<&Owner> = None;
        for (owner, secret) in &self.tokens {
            if constant_time_eq(token.as_bytes(), secret) {
                found = Some(owner);
            }
        }
        match found {
            Some(o) => Ok(o.clone()),
            None => Err(ApiError::unauthorized("the bearer token is not valid")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_match_exactly_and_name_their_owner() {
        assert!(constant_time_eq(b"abc", b"abc"));
        assert!(!constant_time_eq(b"abc", b"abd"));
        assert!(!constant_time_eq(b"abc", b"abcd"));
        assert!(!constant_time_eq(b"", b"a"));
        assert!(constant_time_eq(b"", b""));
        let a = Authenticator::new(
            &[TokenEntry {
                name: "or1".into(),
                token: "0123456789abcdef".into(),
            }],
            false,
        );
        assert_eq!(
            a.authenticate(Some(b"Bearer 0123456789abcdef"))
                .unwrap()
                .name(),
            "or1"
        );
        for scheme in ["bearer", "BEARER", "BeArEr"] {
            let header = format!("{scheme} 0123456789abcdef");
            assert_eq!(
                a.authenticate(Some(header.as_bytes())).unwrap().name(),
                "or1",
                "{scheme}"
            );
        }
        for bad in [
            None,
            Some(&b"Bearer0123456789abcdef"[..]),
            Some(b"Bearers 0123456789abcdef"),
            Some(&b"Bearer 0123456789abcdeX"[..]),
            Some(b"Basic 0123456789abcdef"),
            Some(b"Bearer "),
            Some(b"\xff\xfe"),
        ] {
            let e = a.authenticate(bad).unwrap_err();
            assert_eq!(e.code, "unauthorized");
        }
        let open = Authenticator::new(&[], true);
        assert_eq!(open.authenticate(None).unwrap().name(), "dev");
        assert!(open.authenticate(Some(b"Bearer nope")).is_err());
    }
}
