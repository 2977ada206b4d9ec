#![no_main]
//! Fuzz target: see `lj9da_bridge::fuzz_targets::protocol_decoder`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| lj9da_bridge::fuzz_targets::protocol_decoder(data));
