//! The gate's reading of `authorization`: the `Bearer` scheme name in any case (RFC 6750
//! section 2.1, whose scheme names are case-insensitive by RFC 7235 section 2.1).

#![allow(clippy::unwrap_used, clippy::expect_used)] // tests: a panic is the failure report

use std::sync::Arc;

use coadapt_auth::{Gate, Role, TokenTable, new_token};
use tonic::metadata::MetadataMap;

fn with(value: &str) -> MetadataMap {
    let mut m = MetadataMap::new();
    m.insert("authorization", value.parse().unwrap());
    m
}

#[test]
fn the_bearer_scheme_is_matched_in_any_case_and_nothing_else_passes() {
    let token = new_token();
    let mut table = TokenTable::default();
    table.insert(&token, Role::Optimizer);
    let gate = Gate::new(Some(Arc::new(table)), &[Role::Optimizer]);
    let t = token.expose();
    for scheme in ["Bearer", "bearer", "BEARER", "bEaReR"] {
        assert_eq!(gate.check(&with(&format!("{scheme} {t}"))).unwrap(), Role::Optimizer, "{scheme}");
    }
    assert_eq!(gate.check(&with(&format!("Bearer   {t}  "))).unwrap(), Role::Optimizer, "spaces around the token");
    for bad in [format!("Basic {t}"), format!("Bearer{t}"), t.to_string(), "Bearer ".to_string(), format!("Bearerx {t}")] {
        let e = gate.check(&with(&bad)).unwrap_err();
        assert_eq!(e.code(), tonic::Code::Unauthenticated, "{bad:?}");
        assert!(!e.message().contains(t), "the token never goes back in an error");
    }
    assert_eq!(gate.counts().unauthenticated.load(std::sync::atomic::Ordering::Relaxed), 5);
}
