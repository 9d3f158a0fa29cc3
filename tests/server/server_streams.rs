//! Streams under bad input: WebSocket and gRPC frames that are malformed, non-finite, empty or
//! too large get an error message and the stream goes on; unknown sessions, missing and wrong
//! tokens and other tokens' sessions are refused; a client that disconnects mid-stream leaves
//! its session usable; newest-frame-wins skips and counts; shutdown finishes the frame in
//! flight and closes streams with 1001; a message over the size limit closes with 1009.

use std::time::Duration;

use livereg::server::codec::encode_binary_frame;
use livereg::server::proto;
use tokio_tungstenite::tungstenite::Message;

use crate::client::*;
use crate::server_support::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn websocket_bad_frames_get_errors_and_the_stream_goes_on() {
    let case = small_case("ws-bad", 3);
    let mut cfg = test_config("ws-bad");
    cfg.limits.max_frame_points = 2000;
    cfg.limits.max_body_bytes = 200 * 1024;
    let server = start(cfg).await;
    let addr = server.http_addr;
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let frames = read_frames(&case.join("frames")).unwrap();
    let id = http_create_session(addr, TOKEN_A, &scene).await.unwrap();

    // Refused before the upgrade: missing/wrong token, another token's or an unknown session.
    for (sid, token) in [
        (id.as_str(), "wrong-token-wrong-token"),
        (id.as_str(), TOKEN_B),
        ("0123456789abcdef0123456789abcdef", TOKEN_A),
    ] {
        let e = WsClient::connect(addr, sid, token).await.err().unwrap();
        assert!(e.contains("401") || e.contains("404"), "{e}");
    }

    let mut ws = WsClient::connect(addr, &id, TOKEN_A).await.unwrap();
    let bad: Vec<(Message, &str)> = vec![
        (
            Message::Text("{\"points\": [[1, 2, 3]".into()),
            "bad_request",
        ),
        (Message::Text("{\"points\": []}".into()), "invalid_frame"),
        (Message::Text("[]".into()), "bad_request"),
        (
            Message::Binary(encode_binary_frame(7, &[[0.0, f32::NAN, 0.0]], None).into()),
            "invalid_frame",
        ),
        (
            Message::Binary(encode_binary_frame(8, &[[f32::INFINITY, 0.0, 0.0]], None).into()),
            "invalid_frame",
        ),
        (
            Message::Binary(b"LVRG\x01\x00\x00\x00short".to_vec().into()),
            "bad_request",
        ),
        (
            Message::Binary(encode_binary_frame(9, &vec![[1.0, 1.0, 1.0]; 2500], None).into()),
            "too_many_points",
        ),
    ];
    for (m, code) in bad {
        ws.send_raw(m).await.unwrap();
        match ws.next().await {
            Some(WsEvent::Error(_, c, msg)) => {
                assert_eq!(c, code, "{msg}");
                assert!(msg.len() > 10);
            }
            other => panic!("expected {code}, got {other:?}"),
        }
    }
    // The NaN frame's error names its seq.
    ws.send_raw(Message::Binary(
        encode_binary_frame(42, &[[0.0, f32::NAN, 0.0]], None).into(),
    ))
    .await
    .unwrap();
    assert!(matches!(ws.next().await, Some(WsEvent::Error(42, _, _))));
    // Still streaming: a good frame is registered.
    ws.send_json(1, &frames[0].0, &frames[0].1).await.unwrap();
    match ws.next().await {
        Some(WsEvent::Result(v)) => {
            assert_eq!(v["frame"], 0);
            assert!(v["diagnostics"].get("error").is_none());
        }
        other => panic!("{other:?}"),
    }
    // A message over the size limit ends the stream with close code 1009 (message too big,
    // RFC 6455 §7.4.1), nothing else.
    let huge = "x".repeat(300 * 1024);
    let _ = ws.send_raw(Message::Text(huge.into())).await;
    let end = tokio::time::timeout(Duration::from_secs(10), ws.next())
        .await
        .unwrap();
    assert!(
        matches!(end, Some(WsEvent::Closed(1009))),
        "oversized message: {end:?}"
    );
    // The session is fine: a new stream works.
    let (r, _) = ws_lockstep(addr, &id, TOKEN_A, &frames[1..2], false)
        .await
        .unwrap();
    assert_eq!(r[0]["frame"], 1);
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn disconnects_newest_wins_and_graceful_shutdown() {
    let case = small_case("ws-life", 12);
    let mut cfg = test_config("ws-life");
    cfg.worker_threads = 1;
    let server = start(cfg).await;
    let addr = server.http_addr;
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let frames = read_frames(&case.join("frames")).unwrap();
    let id = http_create_session(addr, TOKEN_A, &scene).await.unwrap();

    // Newest wins: 10 frames at once, fewer results, and results + skipped = frames.
    let mut ws = WsClient::connect(addr, &id, TOKEN_A).await.unwrap();
    for (k, (name, pts)) in frames.iter().enumerate().take(10) {
        ws.send_json(k as u64, name, pts).await.unwrap();
    }
    let (mut results, mut skipped, mut last) = (0, 0, 0);
    while last != 9 {
        match tokio::time::timeout(Duration::from_secs(60), ws.next())
            .await
            .unwrap()
        {
            Some(WsEvent::Result(v)) => {
                results += 1;
                skipped += v["skipped"].as_u64().unwrap();
                last = v["seq"].as_u64().unwrap();
            }
            other => panic!("{other:?}"),
        }
    }
    assert_eq!(
        results + skipped,
        10,
        "{results} results, {skipped} skipped"
    );
    assert!(skipped >= 1, "10 frames sent at once were all registered");

    // A client that disconnects mid-stream (frame in flight, no close handshake).
    ws.send_json(10, &frames[10].0, &frames[10].1)
        .await
        .unwrap();
    drop(ws);
    tokio::time::sleep(Duration::from_millis(50)).await;
    // The session goes on with a new stream.
    let (r, _) = ws_lockstep(addr, &id, TOKEN_A, &frames[11..12], false)
        .await
        .unwrap();
    assert!(r[0]["diagnostics"].get("error").is_none());

    // Graceful shutdown with a frame in flight: its result arrives, then close 1001, and
    // new work is refused meanwhile.
    let mut ws = WsClient::connect(addr, &id, TOKEN_A).await.unwrap();
    ws.send_json(99, &frames[0].0, &frames[0].1).await.unwrap();
    tokio::time::sleep(Duration::from_millis(5)).await;
    let handle = server.shutdown_handle();
    let stopping = tokio::spawn(server.run_until_stopped());
    handle.trigger();
    // New work is refused meanwhile: no session is created (503 `shutting_down`, or the
    // listener has already stopped accepting).
    let refused = http_create_session(addr, TOKEN_A, &scene).await;
    assert!(
        refused.is_err(),
        "a session was created during the shutdown: {refused:?}"
    );
    let mut got_result = false;
    let mut close_code = None;
    while let Some(ev) = tokio::time::timeout(Duration::from_secs(60), ws.next())
        .await
        .unwrap()
    {
        match ev {
            WsEvent::Result(v) => {
                assert_eq!(v["seq"], 99);
                got_result = true;
            }
            WsEvent::Closed(c) => {
                close_code = Some(c);
                break;
            }
            WsEvent::Error(..) => {}
            other @ (WsEvent::BinaryResult(_) | WsEvent::Undecodable(_)) => {
                panic!("a JSON-results stream sent {other:?}")
            }
        }
    }
    assert!(got_result, "the frame in flight was not finished");
    assert_eq!(close_code, Some(1001));
    stopping.await.unwrap().unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_bad_inputs_get_the_right_status() {
    let case = small_case("grpc-bad", 2);
    let mut cfg = test_config("grpc-bad");
    cfg.limits.max_body_bytes = 100 * 1024;
    let server = start(cfg).await;
    let gaddr = server.grpc_addr.unwrap();
    let scene = SceneFiles::read(&case.join("scene.toml")).unwrap();
    let frames = read_frames(&case.join("frames")).unwrap();
    let mut a = GrpcClient::connect(gaddr, TOKEN_A).await.unwrap();
    let info = a.create_session(&scene).await.unwrap();
    use tonic::Code;

    // Tokens: missing, wrong, another token's session.
    let mut none = GrpcClient::connect(gaddr, "").await.unwrap();
    let mut plain = none.inner.clone();
    let st = plain
        .get_session(proto::SessionRef {
            id: info.id.clone(),
        })
        .await
        .unwrap_err();
    assert_eq!(st.code(), Code::Unauthenticated, "{st:?}");
    let mut wrong = GrpcClient::connect(gaddr, "not-a-token-not-a-token")
        .await
        .unwrap();
    let st = wrong.create_session(&scene).await.unwrap_err();
    assert_eq!(st.code(), Code::Unauthenticated);
    let mut b = GrpcClient::connect(gaddr, TOKEN_B).await.unwrap();
    let st = b
        .register(&info.id, 0, "x", &frames[0].1)
        .await
        .unwrap_err();
    assert_eq!(st.code(), Code::NotFound);
    let st = b.close_session(&info.id).await.unwrap_err();
    assert_eq!(st.code(), Code::NotFound);
    let st = none.close_session("x").await.unwrap_err();
    assert_eq!(st.code(), Code::Unauthenticated, "{st:?}");
    // Frames: NaN, empty, not a multiple of 3, oversized message.
    let st = a
        .register(&info.id, 0, "nan", &[[0.0, f64::NAN, 0.0]])
        .await
        .unwrap_err();
    assert_eq!(st.code(), Code::InvalidArgument);
    assert!(st.message().contains("non-finite"), "{}", st.message());
    let st = a
        .register(&info.id, 0, "inf", &[[f64::INFINITY, 0.0, 0.0]])
        .await
        .unwrap_err();
    assert_eq!(st.code(), Code::InvalidArgument);
    let st = a.register(&info.id, 0, "empty", &[]).await.unwrap_err();
    assert_eq!(st.code(), Code::InvalidArgument);
    let mut f = frame_f64(0, "odd", &frames[0].1);
    f.points_f64.pop();
    let st = a
        .inner
        .register(a.req(proto::RegisterRequest {
            session_id: info.id.clone(),
            frame: Some(f),
        }))
        .await
        .unwrap_err();
    assert_eq!(st.code(), Code::InvalidArgument);
    assert!(st.message().contains("multiple of 3"));
    let big = vec![[1.0, 2.0, 3.0]; 10_000];
    let st = a.register(&info.id, 0, "big", &big).await.unwrap_err();
    assert_eq!(st.code(), Code::OutOfRange, "{st:?}");
    let st = a
        .register("0123456789abcdef0123456789abcdef", 0, "x", &frames[0].1)
        .await
        .unwrap_err();
    assert_eq!(st.code(), Code::NotFound);
    // Bad scene.
    let mut s = scene.clone();
    s.scene = "[modle]".into();
    let st = a.create_session(&s).await.unwrap_err();
    assert_eq!(st.code(), Code::InvalidArgument);
    assert!(st.message().contains("invalid_scene"));

    // Malformed protobuf: raw bytes through a pass-through codec.
    let raw = raw_unary(
        gaddr,
        "/livereg.v1.Registration/GetSession",
        vec![0xff, 0xff, 0xff],
    )
    .await;
    assert_eq!(raw.code(), Code::InvalidArgument, "{raw:?}");
    assert!(
        raw.message().contains("malformed protobuf"),
        "{}",
        raw.message()
    );

    // Streams: unknown session ends the stream with NOT_FOUND; bad frames are stream errors
    // and the stream goes on.
    let (tx, rx) = tokio::sync::mpsc::channel::<proto::StreamRequest>(4);
    let mut out = a
        .inner
        .stream(a.req(tokio_stream::wrappers::ReceiverStream::new(rx)))
        .await
        .unwrap()
        .into_inner();
    tx.send(proto::StreamRequest {
        session_id: "0123456789abcdef0123456789abcdef".into(),
        frame: Some(frame_f64(0, "x", &frames[0].1)),
    })
    .await
    .unwrap();
    let st = out.message().await.unwrap_err();
    assert_eq!(st.code(), Code::NotFound);
    let (tx, rx) = tokio::sync::mpsc::channel::<proto::StreamRequest>(4);
    let mut out = a
        .inner
        .stream(a.req(tokio_stream::wrappers::ReceiverStream::new(rx)))
        .await
        .unwrap()
        .into_inner();
    for (seq, pts) in [(1, vec![[f64::NAN, 0.0, 0.0]]), (2, vec![])] {
        tx.send(proto::StreamRequest {
            session_id: info.id.clone(),
            frame: Some(frame_f64(seq, "bad", &pts)),
        })
        .await
        .unwrap();
        match out.message().await.unwrap().unwrap().kind {
            Some(proto::stream_response::Kind::Error(e)) => {
                assert_eq!(e.code, "invalid_frame");
                assert_eq!(e.seq, seq);
            }
            other => panic!("{other:?}"),
        }
    }
    tx.send(proto::StreamRequest {
        session_id: String::new(),
        frame: Some(frame_f64(3, "good", &frames[0].1)),
    })
    .await
    .unwrap();
    match out.message().await.unwrap().unwrap().kind {
        Some(proto::stream_response::Kind::Result(r)) => {
            assert_eq!(r.seq, 3);
            assert!(r.error.is_empty());
        }
        other => panic!("{other:?}"),
    }
    // Disconnect mid-stream: drop both ends with a frame in flight; the session goes on.
    tx.send(proto::StreamRequest {
        session_id: String::new(),
        frame: Some(frame_f64(4, "left", &frames[1].1)),
    })
    .await
    .unwrap();
    drop(out);
    drop(tx);
    tokio::time::sleep(Duration::from_millis(50)).await;
    let r = a
        .register(&info.id, 5, "after", &frames[1].1)
        .await
        .unwrap();
    assert!(r.error.is_empty());
    server.shutdown().await.unwrap();
}

/// Sends `body` as a unary gRPC request to `path` with token A and returns the status.
async fn raw_unary(addr: std::net::SocketAddr, path: &'static str, body: Vec<u8>) -> tonic::Status {
    #[derive(Clone, Default)]
    struct RawCodec;
    struct RawEnc;
    struct RawDec;
    impl tonic::codec::Encoder for RawEnc {
        type Item = Vec<u8>;
        type Error = tonic::Status;
        fn encode(
            &mut self,
            item: Vec<u8>,
            dst: &mut tonic::codec::EncodeBuf<'_>,
        ) -> Result<(), tonic::Status> {
            use bytes_put::BufMutExt;
            dst.put_all(&item);
            Ok(())
        }
    }
    impl tonic::codec::Decoder for RawDec {
        type Item = Vec<u8>;
        type Error = tonic::Status;
        fn decode(
            &mut self,
            src: &mut tonic::codec::DecodeBuf<'_>,
        ) -> Result<Option<Vec<u8>>, tonic::Status> {
            use bytes_put::BufExt;
            Ok(Some(src.take_all()))
        }
    }
    impl tonic::codec::Codec for RawCodec {
        type Encode = Vec<u8>;
        type Decode = Vec<u8>;
        type Encoder = RawEnc;
        type Decoder = RawDec;
        fn encoder(&mut self) -> RawEnc {
            RawEnc
        }
        fn decoder(&mut self) -> RawDec {
            RawDec
        }
    }
    let channel = tonic::transport::Channel::from_shared(format!("http://{addr}"))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut grpc = tonic::client::Grpc::new(channel);
    grpc.ready().await.unwrap();
    let mut req = tonic::Request::new(body);
    req.metadata_mut().insert(
        "authorization",
        format!("Bearer {TOKEN_A}").parse().unwrap(),
    );
    grpc.unary(
        req,
        tonic::codegen::http::uri::PathAndQuery::from_static(path),
        RawCodec,
    )
    .await
    .unwrap_err()
}

/// Buffer helpers over the `bytes` traits re-exported by tonic's codec buffers.
mod bytes_put {
    use bytes::{Buf, BufMut};

    pub trait BufMutExt {
        fn put_all(&mut self, b: &[u8]);
    }
    impl<T: BufMut> BufMutExt for T {
        fn put_all(&mut self, b: &[u8]) {
            self.put_slice(b);
        }
    }
    pub trait BufExt {
        fn take_all(&mut self) -> Vec<u8>;
    }
    impl<T: Buf> BufExt for T {
        fn take_all(&mut self) -> Vec<u8> {
            let mut v = vec![0; self.remaining()];
            self.copy_to_slice(&mut v);
            v
        }
    }
}
