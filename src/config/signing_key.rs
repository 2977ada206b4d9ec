//! A MAVLink 2 signing key as a mapping file gives it: 64 hex digits, a key file, or a
//! passphrase hashed as MAVProxy and Mission Planner do (SHA-256). Signing itself is
//! [`crate::mavlink::signing`]'s.

use sha2::{Digest, Sha256};
use std::fmt;
use thiserror::Error;

/// The 32-byte secret key. Its `Debug` never shows the bytes.
#[derive(Clone, PartialEq, Eq)]
pub struct SigningKey([u8; 32]);

impl fmt::Debug for SigningKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("SigningKey(<secret>)")
    }
}

/// Why a key could not be read.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum KeyError {
    #[error(
        "is {0} characters long; a signing key is 64 hex digits (32 bytes), e.g. the output of `openssl rand -hex 32`"
    )]
    HexLength(usize),
    /// At this character (from 1); the character itself is not quoted, being part of a secret.
    #[error("has a character that is not a hex digit (0-9, a-f) at position {0}")]
    NotHex(usize),
    #[error(
        "holds {0} bytes; a key file holds 64 hex digits (surrounding white space allowed) or exactly 32 raw bytes"
    )]
    FileLength(usize),
    #[error("is empty; a passphrase needs at least one character")]
    EmptyPassphrase,
}

impl SigningKey {
    pub const fn from_bytes(bytes: [u8; 32]) -> Self {
        SigningKey(bytes)
    }

    pub fn bytes(&self) -> &[u8; 32] {
        &self.0
    }

    /// 64 hex digits, either case.
    pub fn from_hex(text: &str) -> Result<Self, KeyError> {
        let count = text.chars().count();
        if let Some(i) = text.chars().position(|c| !c.is_ascii_hexdigit()) {
            return Err(KeyError::NotHex(i + 1));
        }
        if count != 64 {
            return Err(KeyError::HexLength(count));
        }
        let mut key = [0u8; 32];
        for (byte, pair) in key.iter_mut().zip(text.as_bytes().chunks(2)) {
            // Both are ASCII hex digits, checked above.
            let digits = std::str::from_utf8(pair).unwrap_or("00");
            *byte = u8::from_str_radix(digits, 16).unwrap_or(0);
        }
        Ok(SigningKey(key))
    }

    /// The key MAVProxy's `signing setup <passphrase>` and `signing key <passphrase>` derive:
    /// SHA-256 of the passphrase's bytes (MAVProxy takes ASCII passphrases only; for those the
    /// UTF-8 bytes used here are the same).
    pub fn from_passphrase(passphrase: &str) -> Result<Self, KeyError> {
        if passphrase.is_empty() {
            return Err(KeyError::EmptyPassphrase);
        }
        Ok(SigningKey(Sha256::digest(passphrase.as_bytes()).into()))
    }

    /// A key file's contents: 64 hex digits (white space around them allowed), or exactly 32
    /// raw bytes.
    pub fn from_file_contents(contents: &[u8]) -> Result<Self, KeyError> {
        if let Ok(text) = std::str::from_utf8(contents) {
            let text = text.trim();
            if text.len() == 64 && text.bytes().all(|b| b.is_ascii_hexdigit()) {
                return Self::from_hex(text);
            }
        }
        match <[u8; 32]>::try_from(contents) {
            Ok(bytes) => Ok(SigningKey(bytes)),
            Err(_) => Err(KeyError::FileLength(contents.len())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_come_from_hex_a_file_or_a_passphrase() {
        let hex = "00112233445566778899aabbccddeeff00112233445566778899AABBCCDDEEFF";
        let key = SigningKey::from_hex(hex).unwrap();
        assert_eq!(key.bytes()[..3], [0x00, 0x11, 0x22]);
        assert_eq!(key.bytes()[31], 0xff);
        assert_eq!(
            SigningKey::from_hex(&hex[..62]),
            Err(KeyError::HexLength(62))
        );
        assert_eq!(
            SigningKey::from_hex(&format!("{}g", &hex[..63])),
            Err(KeyError::NotHex(64))
        );
        assert_eq!(
            SigningKey::from_file_contents(format!("  {hex}\n").as_bytes()),
            Ok(key.clone())
        );
        assert_eq!(SigningKey::from_file_contents(key.bytes()), Ok(key.clone()));
        assert_eq!(
            SigningKey::from_file_contents(b"short"),
            Err(KeyError::FileLength(5))
        );
        // hashlib.sha256(b"correct horse battery staple").hexdigest(), as MAVProxy derives it.
        let passphrase = SigningKey::from_passphrase("correct horse battery staple").unwrap();
        assert_eq!(
            passphrase,
            SigningKey::from_hex(
                "c4bbcb1fbec99d65bf59d85c8cb62ee2db963f0fe106f483d9afa73bd4e39a8a"
            )
            .unwrap()
        );
        assert_eq!(
            SigningKey::from_passphrase(""),
            Err(KeyError::EmptyPassphrase)
        );
        assert_eq!(format!("{key:?}"), "SigningKey(<secret>)");
    }
}
