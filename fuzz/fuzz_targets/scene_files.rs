//! libFuzzer target `scene_files`: the body is `octoproxy_tests::fuzz::scene_files` (glTF
//! and baked scene files), which `tests/tests/fuzz.rs` also runs over
//! `fuzz/corpus/scene_files/` in `cargo test`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| octoproxy_tests::fuzz::scene_files(data));
