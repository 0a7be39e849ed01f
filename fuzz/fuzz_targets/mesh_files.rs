//! libFuzzer target `mesh_files`: the body is `octoproxy_tests::fuzz::mesh_files`, which
//! `tests/tests/fuzz.rs` also runs over `fuzz/corpus/mesh_files/` in `cargo test`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| octoproxy_tests::fuzz::mesh_files(data));
