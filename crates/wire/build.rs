//! Compiles every `.proto` under `proto/` with protox (pure Rust: no `protoc` to install) and
//! generates the prost messages and the tonic clients and servers.

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../proto");
    let mut files = Vec::new();
    let mut dirs = vec![root.clone()];
    while let Some(d) = dirs.pop() {
        for e in std::fs::read_dir(&d)? {
            let p = e?.path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|x| x == "proto") {
                files.push(p);
            }
        }
    }
    files.sort();
    println!("cargo:rerun-if-changed={}", root.display());
    for f in &files {
        println!("cargo:rerun-if-changed={}", f.display());
    }
    let fds = protox::compile(&files, [&root])?;
    let out = std::path::PathBuf::from(std::env::var("OUT_DIR")?);
    // The descriptor set feeds the learner's gRPC reflection, so standard tools can list its
    // services: only coadapt's own files (dm_env_rpc is served by `coadapt env-serve`, not there).
    let mut own = fds.clone();
    own.file.retain(|f| f.package().starts_with("coadapt."));
    std::fs::write(out.join("coadapt_descriptor.bin"), prost::Message::encode_to_vec(&own))?;
    let mut inference = fds.clone();
    inference.file.retain(|f| f.package() == "inference");
    std::fs::write(out.join("inference_descriptor.bin"), prost::Message::encode_to_vec(&inference))?;
    tonic_prost_build::configure().bytes(".coadapt").compile_fds(fds)?;
    Ok(())
}
