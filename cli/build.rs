//! With the `cuda` feature, the binary finds the CUDA libraries beside itself (`lib/`) or in
//! the usual toolkit folders without `LD_LIBRARY_PATH` (docs/gpu.md).
fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    if std::env::var_os("CARGO_FEATURE_CUDA").is_some() {
        println!("cargo:rustc-link-arg-bins=-Wl,-rpath,$ORIGIN/lib:$ORIGIN:/usr/local/cuda/lib64:/usr/local/cuda/targets/x86_64-linux/lib");
    }
}
