//! libFuzzer target `moving`: the body is `octoproxy_tests::fuzz::moving`, which
//! `tests/tests/fuzz.rs` also runs over `fuzz/corpus/moving/` in `cargo test`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| octoproxy_tests::fuzz::moving(data));
