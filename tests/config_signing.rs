//! The `signing_*` keys of `[mavlink]`: each key form read, every mistake refused with the
//! file, line and key, the key itself never shown, and `check` warning when a link reachable
//! from outside is not signed.

use lj9da_bridge::config::Config;
use lj9da_bridge::config::mavlink::KeySource;
use lj9da_bridge::mavlink::signing::SigningKey;
use std::path::PathBuf;
use std::process::Command;

const ORIGIN: &str = "mappings/signed.toml";
const HEX: &str = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff";

fn mapping(connection: &str, signing: &str) -> String {
    format!(
        r#"[mavlink]
connection = "{connection}"
{signing}

[[bus]]
name = "wing"
port = "/dev/null"

[[servo]]
name = "flap"
bus = "wing"
id = 1
channel = 1
"#
    )
}

fn dir(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("config-signing-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The first run of 8 characters of `key` that `shown` holds: a leaked prefix or piece of a
/// key is as bad as the whole.
fn leaked<'k>(shown: &str, key: &'k str) -> Option<&'k str> {
    (0..=key.len().saturating_sub(8))
        .map(|i| &key[i..i + 8])
        .find(|run| shown.contains(run))
}

/// The refusal of `text`: on the line holding `needle`, about `key`, containing `reason`.
#[track_caller]
fn refused(text: &str, needle: &str, key: &str, reason: &str) -> String {
    let line = text.lines().position(|l| l.contains(needle)).unwrap() + 1;
    let message = Config::parse(text, ORIGIN)
        .expect_err("refused")
        .to_string();
    assert!(
        message.starts_with(&format!("{ORIGIN}:{line}:")),
        "line {line}: {message}"
    );
    assert!(message.contains(&format!("key \"{key}\"")), "{message}");
    assert!(message.contains(reason), "{message}");
    message
}

#[test]
fn no_signing_key_means_signing_off() {
    let cfg = Config::parse(&mapping("udpin:127.0.0.1:14560", ""), ORIGIN).unwrap();
    assert_eq!(cfg.mavlink.signing, None);
    assert!(cfg.resolved_table().contains("signing: off"));
}

#[test]
fn a_hex_key_a_key_file_and_a_passphrase_are_read() {
    let cfg = Config::parse(
        &mapping("udpin:0.0.0.0:14560", &format!("signing_key = \"{HEX}\"")),
        ORIGIN,
    )
    .unwrap();
    let s = cfg.mavlink.signing.unwrap();
    assert_eq!(s.key, SigningKey::from_hex(HEX).unwrap());
    assert_eq!(s.key_source, KeySource::Hex);
    assert_eq!(
        s.timestamp_file, None,
        "text without a file has no default place"
    );

    let cfg = Config::parse(
        &mapping(
            "udpin:0.0.0.0:14560",
            "signing_passphrase = \"hunter2 hunter2\"",
        ),
        ORIGIN,
    )
    .unwrap();
    assert_eq!(
        cfg.mavlink.signing.unwrap().key,
        SigningKey::from_passphrase("hunter2 hunter2").unwrap()
    );

    // A key file relative to the mapping file, in either form; the timestamp file beside it.
    let d = dir("file");
    std::fs::write(d.join("hex.key"), format!("{HEX}\n")).unwrap();
    std::fs::write(d.join("raw.key"), [9u8; 32]).unwrap();
    for (file, key) in [
        ("hex.key", SigningKey::from_hex(HEX).unwrap()),
        ("raw.key", SigningKey::from_bytes([9; 32])),
    ] {
        let path = d.join("plane.toml");
        std::fs::write(
            &path,
            mapping(
                "udpin:0.0.0.0:14560",
                &format!("signing_key_file = \"{file}\""),
            ),
        )
        .unwrap();
        let s = Config::load(&path).unwrap().mavlink.signing.unwrap();
        assert_eq!(s.key, key, "{file}");
        assert_eq!(s.key_source, KeySource::File(d.join(file)));
        assert_eq!(
            s.timestamp_file,
            Some(d.join("plane.toml.signing-timestamp"))
        );
    }
    // signing_timestamp_file relative to the mapping file.
    let path = d.join("other.toml");
    std::fs::write(
        &path,
        mapping(
            "udpin:0.0.0.0:14560",
            &format!("signing_key = \"{HEX}\"\nsigning_timestamp_file = \"state/ts\""),
        ),
    )
    .unwrap();
    let s = Config::load(&path).unwrap().mavlink.signing.unwrap();
    assert_eq!(s.timestamp_file, Some(d.join("state/ts")));
    let _ = std::fs::remove_dir_all(d);
}

#[test]
fn bad_keys_are_refused_with_their_line_and_without_the_key() {
    let short = &HEX[..60];
    let m = refused(
        &mapping("udpin:127.0.0.1:1", &format!("signing_key = \"{short}\"")),
        "signing_key",
        "signing_key",
        "is 60 characters long",
    );
    assert_eq!(leaked(&m, short), None, "the key is quoted: {m}");
    let bad = format!("{}zz", &HEX[..62]);
    let m = refused(
        &mapping("udpin:127.0.0.1:1", &format!("signing_key = \"{bad}\"")),
        "signing_key",
        "signing_key",
        "not a hex digit",
    );
    assert_eq!(leaked(&m, &bad), None, "the key is quoted: {m}");
    refused(
        &mapping("udpin:127.0.0.1:1", "signing_passphrase = \"\""),
        "signing_passphrase",
        "signing_passphrase",
        "is empty",
    );
    refused(
        &mapping(
            "udpin:127.0.0.1:1",
            "signing_key_file = \"/nonexistent/lj9da.key\"",
        ),
        "signing_key_file",
        "signing_key_file",
        "cannot read /nonexistent/lj9da.key",
    );
    let d = dir("bad-file");
    std::fs::write(d.join("k"), "not a key").unwrap();
    let text = mapping(
        "udpin:127.0.0.1:1",
        &format!("signing_key_file = \"{}\"", d.join("k").display()),
    );
    refused(
        &text,
        "signing_key_file",
        "signing_key_file",
        "holds 9 bytes",
    );
    let _ = std::fs::remove_dir_all(d);
}

#[test]
fn two_key_forms_or_a_timestamp_file_without_a_key_are_refused() {
    let text = mapping(
        "udpin:127.0.0.1:1",
        &format!("signing_key = \"{HEX}\"\nsigning_passphrase = \"abc\""),
    );
    refused(
        &text,
        "signing_passphrase",
        "signing_passphrase",
        "signing_key is set as well",
    );
    refused(
        &mapping("udpin:127.0.0.1:1", "signing_timestamp_file = \"ts\""),
        "signing_timestamp_file",
        "signing_timestamp_file",
        "signing is off",
    );
}

#[test]
fn check_shows_where_the_key_came_from_never_the_key() {
    let d = dir("check");
    let path = d.join("plane.toml");
    std::fs::write(
        &path,
        mapping("udpin:0.0.0.0:14560", &format!("signing_key = \"{HEX}\"")),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(["check", "--config"])
        .arg(&path)
        .output()
        .expect("lj9da-bridge runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}{stderr}");
    assert!(
        stdout.contains("signing: MAVLink 2, every message signed and checked (key in the file)"),
        "{stdout}"
    );
    assert!(stdout.contains("plane.toml.signing-timestamp"), "{stdout}");
    for shown in [&stdout, &stderr] {
        assert_eq!(leaked(shown, HEX), None, "{shown}");
    }
    assert!(!stdout.contains("signing is off"), "{stdout}");
    let _ = std::fs::remove_dir_all(d);
}

#[test]
fn check_warns_when_a_link_reachable_from_outside_is_not_signed() {
    let warned = |connection: &str, gcs: &str| {
        let cfg = Config::parse(&mapping(connection, gcs), ORIGIN).unwrap();
        cfg.warnings()
            .into_iter()
            .find(|w| w.contains("signing is off"))
    };
    for outside in [
        "udpin:0.0.0.0:14560",
        "udpout:192.168.1.10:14560",
        "tcpout:autopilot.local:5760",
        "udpin:[::]:14560",
        "serial:/dev/ttyAMA0:921600",
    ] {
        let w = warned(outside, "").unwrap_or_else(|| panic!("no warning for {outside}"));
        assert!(w.contains(outside), "{w}");
        assert!(w.contains("signing_passphrase"), "{w}");
        // A key cuts off an autopilot that does not sign: the advice says which do.
        assert!(w.contains("If the autopilot signs"), "{w}");
        assert!(w.contains("not 1.16 or older"), "{w}");
    }
    for inside in [
        "udpin:127.0.0.1:14560",
        "udpout:127.0.0.5:14560",
        "tcpout:localhost:5760",
        "udpin:[::1]:14560",
    ] {
        assert_eq!(warned(inside, ""), None, "{inside}");
    }
    // The ground-station link counts too.
    let w = warned("udpin:127.0.0.1:14560", "gcs = \"udpout:10.0.0.2:14550\"").unwrap();
    assert!(w.contains("gcs = \"udpout:10.0.0.2:14550\""), "{w}");
    // With a key, no warning.
    assert_eq!(
        warned(
            "udpin:0.0.0.0:14560",
            &format!("signing_key = \"{HEX}\"\ngcs = \"udpout:10.0.0.2:14550\"")
        ),
        None
    );
}
