//! The registration server, one module per subject: the HTTP API, WebSocket and gRPC streams,
//! round trips with the real clients, load, recordings, native TLS and hostile clients against
//! an in-process server on loopback; the OpenIGTLink transport and codec against pyigtl;
//! `livereg serve` started as the deployment files ship it, and two of them behind nginx.
//!
//! One test binary of a few (`tests/*/main.rs`); helpers in `tests/server_support` and the Rust
//! client `examples/client/lib.rs`. One subject alone: `cargo test --test server server_tls::`.

#[path = "../../examples/client/lib.rs"]
mod client;
#[path = "../server_support/mod.rs"]
mod server_support;

mod deployment;
mod openigtlink_pyigtl;
mod scale_out;
mod server_hostile;
mod server_http;
mod server_igtl;
mod server_load;
mod server_recording;
mod server_roundtrip;
mod server_streams;
mod server_tls;
