//! Native TLS (`tls.cert` / `tls.key`): the real clients (Rust: HTTPS + WSS and gRPC with TLS;
//! Python: HTTPS and WSS) get the results of `livereg register` on the same frames; a client
//! that does not trust the certificate or checks another name, a plain-text client and a
//! client that connects and never speaks are all refused or ignored without disturbing the
//! others. Certificates: `fixtures/tls/`.

use std::path::PathBuf;
use std::time::Duration;

use livereg::server::config::TlsConfig;

use crate::client::*;
use crate::server_support::*;

const FRAMES: usize = 6;

fn tls_fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("fixtures/tls")
        .join(name)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_clients_get_register_results_and_others_are_refused() {
    let case = small_case("tls", FRAMES);
    let c = case.clone();
    let want = tokio::task::spawn_blocking(move || reference(&c));
    let mut config = test_config("tls");
    config.tls = Some(TlsConfig {
        cert: tls_fixture("server.pem"),
        key: tls_fixture("server.key"),
    });
    let server = start(config).await;
    let http_addr = server.http_addr;
    let grpc_addr = server.grpc_addr.unwrap();
    let ca = tls_fixture("ca.pem");
    let ca_pem = std::fs::read(&ca).unwrap();

    // A client that connects and never starts its handshake holds no one up.
    let silent = tokio::net::TcpStream::connect(http_addr).await.unwrap();
    // Nor do 20 from one address: 8 wait for their handshake (MAX_PENDING_HANDSHAKES_PER_ADDRESS),
    // the other 12 are closed at once.
    let mut flood = Vec::new();
    for _ in 0..20 {
        let sock = tokio::net::TcpSocket::new_v4().unwrap();
        sock.bind("127.0.0.3:0".parse().unwrap()).unwrap();
        flood.push(sock.connect(http_addr).await.unwrap());
    }
    let reads = flood.into_iter().map(|mut c| async move {
        use tokio::io::AsyncReadExt;
        let mut b = [0u8; 1];
        let closed = matches!(
            tokio::time::timeout(Duration::from_millis(1500), c.read(&mut b)).await,
            Ok(Ok(0)) | Ok(Err(_))
        );
        (closed, c)
    });
    let (closed, _waiting): (Vec<_>, Vec<_>) = futures_util::future::join_all(reads)
        .await
        .into_iter()
        .partition(|(closed, _)| *closed);
    let closed_at_once = closed.len();
    assert_eq!(
        closed_at_once,
        20 - livereg::server::tls::MAX_PENDING_HANDSHAKES_PER_ADDRESS
    );

    // gRPC with TLS (Rust client): a session, every frame, close.
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let frames = read_frames(&case.join("frames")).unwrap();
    let mut g = GrpcClient::connect_tls(grpc_addr, TOKEN_A, &ca_pem, "localhost")
        .await
        .unwrap();
    let info = g.create_session(&scene).await.unwrap();
    let mut grpc = Vec::new();
    for (k, (name, pts)) in frames.iter().enumerate() {
        let r = g.register(&info.id, k as u64, name, pts).await.unwrap();
        grpc.push(proto_to_record(&r));
    }
    let closed = g.close_session(&info.id).await.unwrap();
    assert_eq!(closed.frames_registered, FRAMES as u64);

    // HTTPS + WSS (Rust client): create over HTTPS, stream every frame, close.
    let https = Endpoint {
        addr: http_addr,
        tls: Some(ClientTls::new(&ca_pem, "localhost").unwrap()),
    };
    let id = http_create_session(&https, TOKEN_A, &scene).await.unwrap();
    let (wss, _) = ws_lockstep(&https, &id, TOKEN_A, &frames, false)
        .await
        .unwrap();
    let closed = http_close_session(&https, TOKEN_A, &id).await.unwrap();
    assert_eq!(closed["frames_registered"], FRAMES);
    // A client that checks for another name refuses the certificate.
    let wrong_name = Endpoint {
        addr: http_addr,
        tls: Some(ClientTls::new(&ca_pem, "or-3.example").unwrap()),
    };
    let refused = http(&wrong_name, "GET", "/healthz", &[], b"").await;
    assert!(
        refused.as_ref().is_err_and(|e| e.contains("TLS handshake")),
        "{:?}",
        refused.map(|r| r.status)
    );

    // Plain-text gRPC on the TLS port: refused, the server goes on.
    let plain = match GrpcClient::connect(grpc_addr, TOKEN_A).await {
        Ok(mut p) => p
            .create_session(&scene)
            .await
            .map(|_| ())
            .map_err(|e| e.to_string()),
        Err(e) => Err(e),
    };
    assert!(
        plain.is_err(),
        "plain-text gRPC must not reach a TLS server"
    );

    // Plain-text HTTP on the TLS port: no HTTP answer.
    let plain = tokio::time::timeout(
        Duration::from_secs(20),
        http(http_addr, "GET", "/healthz", &[], b""),
    )
    .await
    .expect("a plain-text request is answered or dropped at once, not left hanging");
    assert!(
        plain.is_err(),
        "plain-text HTTP got an HTTP answer from a TLS listener: {plain:?}"
    );

    let want = want.await.unwrap();
    assert_eq!(want.len(), FRAMES);
    for (label, got) in [("grpc", &grpc), ("wss", &wss)] {
        assert_eq!(got.len(), FRAMES, "{label}");
        for (g, w) in got.iter().zip(&want) {
            assert_matches_reference(g, w);
        }
    }

    require_python();
    {
        // HTTPS + WSS (Python, stdlib ssl), checking the certificate against the test CA,
        // by IP address (the certificate names 127.0.0.1 and localhost).
        let url = format!("https://127.0.0.1:{}", http_addr.port());
        let ca_arg = ca.display().to_string();
        for transport in ["ws", "http"] {
            let got = python_roundtrip(
                &url,
                &case,
                &format!("python-tls-{transport}.jsonl"),
                &["--ca-file", &ca_arg],
                &["--transport", transport],
            )
            .await
            .unwrap_or_else(|e| panic!("python over TLS ({transport}): {e}"));
            assert_eq!(got.len(), FRAMES, "{transport}");
            for (g, w) in got.iter().zip(&want) {
                assert_matches_reference(g, w);
            }
        }
        // Without the CA the system trust store does not know the certificate: refused by
        // the client before any token is sent.
        let untrusted = python_roundtrip(&url, &case, "python-untrusted.jsonl", &[], &[])
            .await
            .expect_err("an unknown certificate must be refused");
        assert!(
            untrusted.contains("CERTIFICATE_VERIFY_FAILED"),
            "{untrusted}"
        );
        // Plain http:// against the TLS port fails too.
        let plain_url = format!("http://127.0.0.1:{}", http_addr.port());
        assert!(
            python_roundtrip(&plain_url, &case, "python-plain.jsonl", &[], &[])
                .await
                .is_err()
        );
    }
    drop(silent);
    server.shutdown().await.unwrap();
}

#[tokio::test]
async fn a_bad_certificate_or_key_stops_the_start_with_the_file_named() {
    for (cert, key, want) in [
        ("absent.pem", "server.key", "absent.pem"),
        ("server.pem", "ca.pem", "tls.key"),
        ("ca.pem", "server.key", "does not fit"),
    ] {
        let mut config = test_config("tls-bad");
        config.tls = Some(TlsConfig {
            cert: tls_fixture(cert),
            key: tls_fixture(key),
        });
        let err = livereg::server::start(config).await.unwrap_err();
        assert!(err.contains(want), "{cert} + {key}: {err}");
    }
}
