//! libFuzzer target `penetration`: the body is `octoproxy_tests::fuzz::penetration`, which
//! `tests/tests/fuzz.rs` also runs over `fuzz/corpus/penetration/` in `cargo test`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| octoproxy_tests::fuzz::penetration(data));
