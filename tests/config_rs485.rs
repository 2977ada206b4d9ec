//! `rs485 = { … }` of a `[[bus]]` table: what it asks of the kernel, and a clear refusal (file,
//! line, key, reason) of a mode that cannot work.

use lj9da_bridge::config::{Config, ConfigError};
use lj9da_bridge::serial::rs485::Rs485Mode;

const ORIGIN: &str = "mappings/hat.toml";

/// A file with one bus on a UART; `{rs485}` is replaced by each test's lines.
const FILE: &str = r#"[mavlink]
connection = "udpin:0.0.0.0:14560"

[[bus]]
name = "wing"
port = "/dev/ttyAMA0"
{rs485}

[[servo]]
name = "aileron_left"
bus = "wing"
id = 1
channel = 1
"#;

fn file(rs485: &str) -> String {
    FILE.replace("{rs485}", rs485)
}

fn parse(rs485: &str) -> Result<Config, ConfigError> {
    Config::parse(&file(rs485), ORIGIN)
}

/// Expect a refusal on the line holding `needle`, about `key`, with `reason` in it.
#[track_caller]
fn refused(rs485: &str, needle: &str, key: &str, reason: &str) -> ConfigError {
    let text = file(rs485);
    let line = text
        .lines()
        .position(|l| l.contains(needle))
        .expect("needle in the file")
        + 1;
    let e = Config::parse(&text, ORIGIN).expect_err("the file must be refused");
    let message = e.to_string();
    assert!(
        message.starts_with(&format!("{ORIGIN}:{line}:")),
        "expected {ORIGIN}:{line}: in {message}"
    );
    assert_eq!(e.key(), Some(key), "{message}");
    assert_eq!(e.scope(), Some("bus \"wing\""), "{message}");
    assert!(message.contains(reason), "{reason:?} not in {message}");
    e
}

#[test]
fn without_rs485_the_port_is_left_alone() {
    let c = parse("").unwrap();
    assert_eq!(c.buses[0].rs485, None);
    assert!(c.resolved_table().contains("port's own"));
}

#[test]
fn an_empty_table_asks_for_rts_high_while_sending_and_no_delays() {
    let c = parse("rs485 = {}").unwrap();
    assert_eq!(c.buses[0].rs485, Some(Rs485Mode::default()));
    let c = parse("[bus.rs485]\nrts_on_send = true").unwrap();
    assert_eq!(c.buses[0].rs485, Some(Rs485Mode::default()));
    let table = c.resolved_table();
    assert!(
        table.contains("RTS high while sending, 0 ms before, 0 ms after"),
        "{table}"
    );
}

#[test]
fn every_key_is_read() {
    let c = parse(
        "turnaround_ms = 5\n[bus.rs485]\nrts_after_send = true\ndelay_before_send_ms = 3\n\
         delay_after_send_ms = 1\nrx_during_tx = true",
    )
    .unwrap();
    assert_eq!(
        c.buses[0].rs485,
        Some(Rs485Mode {
            rts_on_send: false,
            rts_after_send: true,
            delay_before_send_ms: 3,
            delay_after_send_ms: 1,
            rx_during_tx: true,
        })
    );
    // One given as false: the other is the true one.
    let c = parse("rs485 = { rts_on_send = false }").unwrap();
    let m = c.buses[0].rs485.unwrap();
    assert!(!m.rts_on_send && m.rts_after_send);
}

#[test]
fn both_polarities_the_same_are_refused() {
    refused(
        "rs485 = { rts_on_send = true, rts_after_send = true }",
        "rs485 =",
        "rts_after_send",
        "both true",
    );
    refused(
        "[bus.rs485]\nrts_on_send = false\nrts_after_send = false",
        "rts_after_send = false",
        "rts_after_send",
        "set exactly one to true",
    );
}

#[test]
fn delays_beyond_the_kernels_100_ms_are_refused() {
    refused(
        "turnaround_ms = 100\n[bus.rs485]\ndelay_after_send_ms = 150",
        "delay_after_send_ms",
        "delay_after_send_ms",
        "150 ms is outside 0–100 ms",
    );
    refused(
        "[bus.rs485]\ndelay_before_send_ms = -1",
        "delay_before_send_ms",
        "delay_before_send_ms",
        "-1 ms is outside 0–100 ms",
    );
}

#[test]
fn a_delay_before_sending_must_fit_in_the_reply_allowance() {
    let e = refused(
        "[bus.rs485]\ndelay_before_send_ms = 3",
        "delay_before_send_ms",
        "delay_before_send_ms",
        "set turnaround_ms = 5",
    );
    assert!(e.to_string().contains("the default turnaround_ms"), "{e}");
    refused(
        "turnaround_ms = 4\nrs485 = { delay_before_send_ms = 3 }",
        "rs485 =",
        "delay_before_send_ms",
        "reply allowance of 4 ms",
    );
    assert!(parse("turnaround_ms = 5\nrs485 = { delay_before_send_ms = 3 }").is_ok());
}

#[test]
fn unknown_keys_and_wrong_types_are_refused_with_their_key() {
    refused(
        "rs485 = { rts_on_sned = true }",
        "rs485 =",
        "rts_on_sned",
        "unknown key",
    );
    refused(
        "rs485 = { rx_during_tx = 1 }",
        "rs485 =",
        "rx_during_tx",
        "expected a boolean",
    );
    // In a `[bus.rs485]` table of its own: the line and the key all the same.
    let e = parse("[bus.rs485]\nrx_during_tx = 1").unwrap_err();
    assert!(e.to_string().starts_with(&format!("{ORIGIN}:8:")), "{e}");
    assert_eq!(e.key(), Some("rx_during_tx"), "{e}");
}

#[test]
fn holding_the_line_after_sending_is_warned_about_with_the_return_delay_it_needs() {
    let c = parse("rs485 = { delay_after_send_ms = 2 }").unwrap();
    let warnings = c.warnings();
    let w = warnings
        .iter()
        .find(|w| w.contains("delay_after_send_ms"))
        .expect("a warning");
    assert!(w.contains("return-delay=2"), "{w}");
    assert!(w.contains("/dev/ttyAMA0"), "{w}");
    let c = parse("rs485 = {}").unwrap();
    assert!(
        !c.warnings().iter().any(|w| w.contains("rs485")),
        "{:?}",
        c.warnings()
    );
}

#[test]
fn the_example_mappings_commented_rs485_line_is_valid() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/mappings/ardupilot-plane.toml");
    let text = std::fs::read_to_string(path).unwrap();
    let line = text
        .lines()
        .find(|l| l.starts_with("# rs485 = {"))
        .expect("the commented rs485 line");
    let on_hat = text.replacen(line, &line[2..], 1);
    let c = Config::parse(&on_hat, path).unwrap();
    assert_eq!(c.buses[0].rs485, Some(Rs485Mode::default()));
}

#[test]
fn rs485_on_a_usb_adapter_is_warned_about() {
    let text = file("rs485 = {}").replace(
        "/dev/ttyAMA0",
        "/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A50285BI-if00-port0",
    );
    let c = Config::parse(&text, ORIGIN).unwrap();
    let warnings = c.warnings();
    assert!(
        warnings
            .iter()
            .any(|w| w.contains("a USB adapter") && w.contains("Remove `rs485`")),
        "{warnings:?}"
    );
    // Not on a UART, and not without rs485.
    for text in [
        file("rs485 = {}"),
        file("").replace("/dev/ttyAMA0", "/dev/ttyUSB0"),
    ] {
        let c = Config::parse(&text, ORIGIN).unwrap();
        assert!(
            !c.warnings().iter().any(|w| w.contains("a USB adapter")),
            "{:?}",
            c.warnings()
        );
    }
}
