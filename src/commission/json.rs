//! What `--json` output needs beyond `serde_json`: readings written with the decimals their
//! unit has (`25.00` mm, not `25.0`), as the tables print them.

use serde::{Serialize, Serializer};
use serde_json::value::RawValue;

/// A reading written with a fixed number of decimals; not-a-number is written as `null`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fixed {
    pub value: f64,
    pub decimals: usize,
}

/// A reading in hundredths (mm, V), written with two decimals.
pub fn centi(value: f64) -> Fixed {
    Fixed { value, decimals: 2 }
}

impl Serialize for Fixed {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        if !self.value.is_finite() {
            return serializer.serialize_none();
        }
        let text = format!("{:.*}", self.decimals, self.value);
        match RawValue::from_string(text) {
            Ok(raw) => raw.serialize(serializer),
            Err(_) => serializer.serialize_f64(self.value),
        }
    }
}

/// `value` as JSON indented by two spaces per level.
pub fn pretty(value: &impl Serialize) -> String {
    // Plain structs, strings and numbers: serialising them cannot fail.
    serde_json::to_string_pretty(value).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize)]
    struct Sample {
        b: String,
        a: Vec<serde_json::Value>,
        limit: Fixed,
        n: Fixed,
        e: std::collections::BTreeMap<String, u8>,
    }

    #[test]
    fn strings_are_escaped_fields_keep_their_order_and_readings_their_decimals() {
        let j = Sample {
            b: "a \"q\" \\ \n\u{1}".into(),
            a: vec![(-1).into(), 2.5.into()],
            limit: centi(25.0),
            n: Fixed {
                value: f64::NAN,
                decimals: 1,
            },
            e: Default::default(),
        };
        assert_eq!(
            pretty(&j),
            "{\n  \"b\": \"a \\\"q\\\" \\\\ \\n\\u0001\",\n  \"a\": [\n    -1,\n    2.5\n  ],\n  \"limit\": 25.00,\n  \"n\": null,\n  \"e\": {}\n}"
        );
    }
}
