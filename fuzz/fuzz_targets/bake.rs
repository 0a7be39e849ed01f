//! libFuzzer target `bake`: the body is `octoproxy_tests::fuzz::bake`, which
//! `tests/tests/fuzz.rs` also runs over `fuzz/corpus/bake/` in `cargo test`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| octoproxy_tests::fuzz::bake(data));
