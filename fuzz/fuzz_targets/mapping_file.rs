#![no_main]
//! Fuzz target: see `lj9da_bridge::fuzz_targets::mapping_file`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| lj9da_bridge::fuzz_targets::mapping_file(data));
