//! libFuzzer target `proxy_bytes`: the body is `octoproxy_tests::fuzz::proxy_bytes`, which
//! `tests/tests/fuzz.rs` also runs over `fuzz/corpus/proxy_bytes/` in `cargo test`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| octoproxy_tests::fuzz::proxy_bytes(data));
