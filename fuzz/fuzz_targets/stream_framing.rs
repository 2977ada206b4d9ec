#![no_main]
//! Fuzz target: see `lj9da_bridge::fuzz_targets::stream_framing`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| lj9da_bridge::fuzz_targets::stream_framing(data));
