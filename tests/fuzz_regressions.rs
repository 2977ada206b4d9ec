//! Every saved fuzz input (`fuzz/regressions/<target>/`: seeds and past findings) replayed
//! through the same code the fuzzer runs, so a fixed finding stays fixed without libFuzzer.

use std::path::Path;

fn replay(target: &str, run: fn(&[u8])) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/regressions")
        .join(target);
    let mut count = 0;
    for entry in std::fs::read_dir(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.unwrap().path();
        let data = std::fs::read(&path).unwrap();
        // Shown with the panic's message when an input fails.
        eprintln!("{}", path.display());
        run(&data);
        count += 1;
    }
    assert!(count > 0, "no inputs in {}", dir.display());
}

#[test]
fn protocol_decoder_inputs() {
    replay(
        "protocol_decoder",
        lj9da_bridge::fuzz_targets::protocol_decoder,
    );
}

#[test]
fn mavlink_input_inputs() {
    replay("mavlink_input", lj9da_bridge::fuzz_targets::mavlink_input);
}

#[test]
fn mapping_file_inputs() {
    replay("mapping_file", lj9da_bridge::fuzz_targets::mapping_file);
}

#[test]
fn link_datagram_inputs() {
    replay("link_datagram", lj9da_bridge::fuzz_targets::link_datagram);
}

#[test]
fn signed_stream_inputs() {
    replay("signed_stream", lj9da_bridge::fuzz_targets::signed_stream);
}

#[test]
fn stream_framing_inputs() {
    replay("stream_framing", lj9da_bridge::fuzz_targets::stream_framing);
}
