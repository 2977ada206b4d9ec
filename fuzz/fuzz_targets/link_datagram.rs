#![no_main]
//! Fuzz target: see `lj9da_bridge::fuzz_targets::link_datagram`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| lj9da_bridge::fuzz_targets::link_datagram(data));
