//! Compiles `proto/livereg/v1/*.proto` into Rust (prost messages, tonic server and client)
//! with `protox`, a pure-Rust protobuf compiler: no system `protoc` is needed.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protos = ["proto/livereg/v1/registration.proto"];
    for p in protos {
        println!("cargo:rerun-if-changed={p}");
    }
    println!("cargo:rerun-if-changed=proto");
    let fds = protox::compile(protos, ["proto"])?;
    tonic_prost_build::configure()
        .build_server(true)
        .build_client(true)
        // Malformed protobuf is INVALID_ARGUMENT (tonic-prost's codec says INTERNAL).
        .codec_path("crate::grpc::Codec")
        .compile_fds(fds)?;
    Ok(())
}
