//! The `key=value` arguments of `lj9da-bridge set`, parsed and validated into register writes.
//!
//! Every argument is parsed and checked by the protocol core (the typed constructors and
//! `registers::validate_write`) before the first byte goes out; one bad argument refuses the
//! whole command. Register names of the memory map that `set` does not write (read-only,
//! reserved, goal and force registers) are refused with the reason.

use super::CommissionError;
use crate::protocol::registers::{Access, MAP, addr, register_at, validate_write};
use crate::protocol::units::PositionLimits;
use crate::protocol::{
    BaudRate, Destination, MemoryMap, MmCenti, Percent, ProtocolError, Punch, ReplyRequest,
    ServoId, ShortPacket,
};

/// One validated setting.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Setting {
    /// Register 4.
    Id(ServoId),
    /// Register 5: extend = − when set.
    Reverse(bool),
    /// Register 6.
    Baud(BaudRate),
    /// Register 7, ms.
    ReturnDelay(u8),
    /// Registers 8–9, 0 … +25.00 mm.
    PlusLimit(MmCenti),
    /// Registers 10–11, −25.00 … 0 mm.
    MinusLimit(MmCenti),
    /// Register 24, ≈0.01 mm.
    PlusMargin(u8),
    /// Register 25, ≈0.01 mm.
    MinusMargin(u8),
    /// Register 26, 0.1 mm.
    PlusSlope(u8),
    /// Register 27, 0.1 mm.
    MinusSlope(u8),
    /// Registers 28–29.
    Punch(Punch),
    /// Register 35 (RAM: a flash write does not keep it).
    MaxForce(Percent),
}

/// The keys `set` accepts, for help and error messages.
pub const KEYS: &str = "id, reverse, baud, return-delay, plus-limit, minus-limit, plus-margin, minus-margin, plus-slope, minus-slope, punch, max-force";

fn bad(arg: &str, reason: impl Into<String>) -> CommissionError {
    CommissionError::BadSetting {
        arg: arg.to_string(),
        reason: reason.into(),
    }
}

/// An integer in decimal or `0x` hex, with an optional sign.
fn parse_int(text: &str) -> Option<i64> {
    let t = text.trim().replace('_', "");
    let (negative, digits) = match t.strip_prefix('-') {
        Some(rest) => (true, rest.to_string()),
        None => (false, t.strip_prefix('+').unwrap_or(&t).to_string()),
    };
    let value = if let Some(hex) = digits
        .strip_prefix("0x")
        .or_else(|| digits.strip_prefix("0X"))
    {
        i64::from_str_radix(hex, 16).ok()?
    } else if !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit()) {
        digits.parse::<i64>().ok()?
    } else {
        return None;
    };
    Some(if negative { -value } else { value })
}

fn strip_unit<'a>(text: &'a str, unit: &str) -> &'a str {
    let t = text.trim();
    t.strip_suffix(unit).map_or(t, str::trim_end)
}

fn byte(arg: &str, text: &str, what: &str) -> Result<u8, CommissionError> {
    let value =
        parse_int(text).ok_or_else(|| bad(arg, format!("{what} must be a whole number 0–255")))?;
    u8::try_from(value).map_err(|_| bad(arg, format!("{what} {value} is outside 0–255")))
}

fn millimetres(arg: &str, text: &str) -> Result<f64, CommissionError> {
    let t = strip_unit(text, "mm");
    t.parse::<f64>()
        .ok()
        .filter(|mm| mm.is_finite())
        .ok_or_else(|| {
            bad(
                arg,
                format!("`{t}` is not a length in mm (e.g. 20.0 or -20.0)"),
            )
        })
}

/// `mm` as 0.01 mm, checked by `check` (the protocol core's limit rules).
fn limit(
    mm: f64,
    which: &'static str,
    allowed: &'static str,
    check: fn(MmCenti) -> Result<MmCenti, ProtocolError>,
) -> Result<MmCenti, CommissionError> {
    let centi = (mm * 100.0).round();
    if centi.abs() > f64::from(i16::MAX) {
        return Err(ProtocolError::LimitOutOfRange { which, mm, allowed }.into());
    }
    Ok(check(MmCenti(centi as i16))?)
}

/// kebab-case of a register name of the memory map ("Plus Position Limit" → "plus-position-limit").
fn kebab(name: &str) -> String {
    name.to_ascii_lowercase().replace(' ', "-")
}

impl Setting {
    /// Parse one `key=value` argument.
    pub fn parse(arg: &str) -> Result<Setting, CommissionError> {
        let Some((key, value)) = arg.split_once('=') else {
            return Err(bad(
                arg,
                format!("expected key=value with a key of: {KEYS}"),
            ));
        };
        let key = key.trim().to_ascii_lowercase().replace('_', "-");
        let value = value.trim();
        let setting = match key.as_str() {
            "id" | "servo-id" => {
                let id = parse_int(value)
                    .ok_or_else(|| bad(arg, "the ID must be a whole number 1–127"))?;
                let id = u8::try_from(id).map_err(|_| {
                    bad(
                        arg,
                        format!("servo id {id} is outside 1–127 (the servo accepts 1–127 only)"),
                    )
                })?;
                Setting::Id(ServoId::new(id)?)
            }
            "reverse" => Setting::Reverse(match value.to_ascii_lowercase().as_str() {
                "0" | "false" | "off" | "no" | "normal" => false,
                "1" | "true" | "on" | "yes" | "reversed" => true,
                _ => return Err(bad(arg, "reverse is 0/1 or true/false")),
            }),
            "baud" | "baud-rate" => Setting::Baud(parse_baud(arg, value)?),
            "return-delay" | "return-delay-time" => {
                Setting::ReturnDelay(byte(arg, strip_unit(value, "ms"), "the return delay (ms)")?)
            }
            "plus-limit" | "plus-position-limit" => Setting::PlusLimit(limit(
                millimetres(arg, value)?,
                "plus",
                "0.00 … +25.00 mm",
                PositionLimits::check_plus,
            )?),
            "minus-limit" | "minus-position-limit" => Setting::MinusLimit(limit(
                millimetres(arg, value)?,
                "minus",
                "−25.00 … 0.00 mm",
                PositionLimits::check_minus,
            )?),
            "plus-margin" | "plus-compliance-margin" => {
                Setting::PlusMargin(byte(arg, value, "the margin")?)
            }
            "minus-margin" | "minus-compliance-margin" => {
                Setting::MinusMargin(byte(arg, value, "the margin")?)
            }
            "plus-slope" | "plus-compliance-slope" => {
                Setting::PlusSlope(byte(arg, value, "the slope")?)
            }
            "minus-slope" | "minus-compliance-slope" => {
                Setting::MinusSlope(byte(arg, value, "the slope")?)
            }
            "punch" => {
                let raw = parse_int(value)
                    .ok_or_else(|| bad(arg, "punch is a raw value 0–0x7FFF (decimal or 0x hex)"))?;
                let raw = u16::try_from(raw).map_err(|_| {
                    bad(
                        arg,
                        format!("punch {raw} is outside 0–0x7FFF (68.2 % of the maximum current)"),
                    )
                })?;
                Setting::Punch(Punch::new(raw)?)
            }
            "max-force" => {
                let percent = parse_int(strip_unit(value, "%"))
                    .ok_or_else(|| bad(arg, "max force is a whole percentage 0–100"))?;
                let percent = u8::try_from(percent)
                    .map_err(|_| bad(arg, format!("max force {percent} % is outside 0–100 %")))?;
                Setting::MaxForce(Percent::new(percent)?)
            }
            other => return Err(refuse_other_register(arg, other, value)),
        };
        // The typed values above follow the protocol core's rules; the packet is built once here
        // so that its validation runs too, before anything is sent.
        setting.packet(ServoId::new(1)?, ReplyRequest::None)?;
        Ok(setting)
    }

    /// Parse every argument; refuse the lot if any is bad or a key is given twice. The result
    /// is in register order.
    pub fn parse_all<S: AsRef<str>>(args: &[S]) -> Result<Vec<Setting>, CommissionError> {
        if args.is_empty() {
            return Err(CommissionError::Refused {
                reason: format!("no settings given; give key=value pairs with keys: {KEYS}"),
            });
        }
        let mut out: Vec<Setting> = Vec::with_capacity(args.len());
        for arg in args {
            let setting = Setting::parse(arg.as_ref())?;
            if out.iter().any(|s| s.key() == setting.key()) {
                return Err(bad(
                    arg.as_ref(),
                    format!("`{}` is given twice", setting.key()),
                ));
            }
            out.push(setting);
        }
        out.sort_by_key(|s| s.address());
        Ok(out)
    }

    /// The key as typed on the command line.
    pub fn key(&self) -> &'static str {
        match self {
            Setting::Id(_) => "id",
            Setting::Reverse(_) => "reverse",
            Setting::Baud(_) => "baud",
            Setting::ReturnDelay(_) => "return-delay",
            Setting::PlusLimit(_) => "plus-limit",
            Setting::MinusLimit(_) => "minus-limit",
            Setting::PlusMargin(_) => "plus-margin",
            Setting::MinusMargin(_) => "minus-margin",
            Setting::PlusSlope(_) => "plus-slope",
            Setting::MinusSlope(_) => "minus-slope",
            Setting::Punch(_) => "punch",
            Setting::MaxForce(_) => "max-force",
        }
    }

    /// First register written.
    pub fn address(&self) -> u8 {
        match self {
            Setting::Id(_) => addr::SERVO_ID,
            Setting::Reverse(_) => addr::REVERSE,
            Setting::Baud(_) => addr::BAUD_RATE,
            Setting::ReturnDelay(_) => addr::RETURN_DELAY,
            Setting::PlusLimit(_) => addr::PLUS_LIMIT,
            Setting::MinusLimit(_) => addr::MINUS_LIMIT,
            Setting::PlusMargin(_) => addr::PLUS_COMPLIANCE_MARGIN,
            Setting::MinusMargin(_) => addr::MINUS_COMPLIANCE_MARGIN,
            Setting::PlusSlope(_) => addr::PLUS_COMPLIANCE_SLOPE,
            Setting::MinusSlope(_) => addr::MINUS_COMPLIANCE_SLOPE,
            Setting::Punch(_) => addr::PUNCH,
            Setting::MaxForce(_) => addr::MAX_FORCE,
        }
    }

    /// The bytes written from [`Setting::address`].
    pub fn data(&self) -> Vec<u8> {
        match *self {
            Setting::Id(id) => vec![id.get()],
            Setting::Reverse(r) => vec![u8::from(r)],
            Setting::Baud(b) => vec![b.code()],
            Setting::ReturnDelay(ms)
            | Setting::PlusMargin(ms)
            | Setting::MinusMargin(ms)
            | Setting::PlusSlope(ms)
            | Setting::MinusSlope(ms) => vec![ms],
            Setting::PlusLimit(l) | Setting::MinusLimit(l) => l.to_le_bytes().to_vec(),
            Setting::Punch(p) => p.get().to_le_bytes().to_vec(),
            Setting::MaxForce(p) => vec![p.get()],
        }
    }

    /// The write of this setting to servo `id`, validated by the protocol core.
    pub fn packet(&self, id: ServoId, reply: ReplyRequest) -> Result<ShortPacket, ProtocolError> {
        ShortPacket::write(Destination::Servo(id), self.address(), &self.data(), reply)
    }

    /// Whether the setting lives in the ROM area (kept by a flash write). Max force is RAM.
    pub fn in_flash(&self) -> bool {
        !matches!(self, Setting::MaxForce(_))
    }

    /// Whether `map` holds this setting's value.
    pub fn holds_in(&self, map: &MemoryMap) -> bool {
        let start = usize::from(self.address());
        let data = self.data();
        map.bytes().get(start..start + data.len()) == Some(&data[..])
    }

    /// The value, for people.
    pub fn value_text(&self) -> String {
        let mut map = MemoryMap::default();
        map.store(self.address(), &self.data());
        self.read_text(&map)
    }

    /// This setting's register as `map` holds it, for people.
    pub fn read_text(&self, map: &MemoryMap) -> String {
        let raw = |a: u8| map.bytes()[usize::from(a)];
        match self {
            Setting::Id(_) => raw(addr::SERVO_ID).to_string(),
            Setting::Reverse(_) => if map.reversed() { "1 (reversed)" } else { "0" }.into(),
            Setting::Baud(_) => match map.baud_rate() {
                Ok(b) => b.bits_per_second().to_string(),
                Err(_) => format!("unknown code 0x{:02X}", raw(addr::BAUD_RATE)),
            },
            Setting::ReturnDelay(_) => format!("{} ms", map.return_delay_ms()),
            Setting::PlusLimit(_) => map.plus_limit().to_string(),
            Setting::MinusLimit(_) => map.minus_limit().to_string(),
            Setting::PlusMargin(_) => raw(addr::PLUS_COMPLIANCE_MARGIN).to_string(),
            Setting::MinusMargin(_) => raw(addr::MINUS_COMPLIANCE_MARGIN).to_string(),
            Setting::PlusSlope(_) => raw(addr::PLUS_COMPLIANCE_SLOPE).to_string(),
            Setting::MinusSlope(_) => raw(addr::MINUS_COMPLIANCE_SLOPE).to_string(),
            Setting::Punch(_) => format!("0x{:04X}", map.punch_raw()),
            Setting::MaxForce(_) => format!("{} %", map.max_force_raw()),
        }
    }
}

/// A baud rate given in bit/s (`230400`) or as a register code in hex (`0x09`).
fn parse_baud(arg: &str, value: &str) -> Result<BaudRate, CommissionError> {
    let v = value.trim();
    if v.starts_with("0x") || v.starts_with("0X") {
        let code = parse_int(v).ok_or_else(|| bad(arg, format!("`{v}` is not a hex code")))?;
        let code = u8::try_from(code).map_err(|_| {
            bad(
                arg,
                format!("baud-rate code {v} is not in the servo's table (0x00–0x0A)"),
            )
        })?;
        return Ok(BaudRate::from_code(code)?);
    }
    let bps = parse_int(strip_unit(v, "bit/s"))
        .ok_or_else(|| bad(arg, "the baud rate is a speed in bit/s, e.g. 230400"))?;
    if (0..=i64::from(BaudRate::B460800.code())).contains(&bps) {
        return Err(bad(
            arg,
            format!("give the rate in bit/s (e.g. 115200) or a register code in hex (0x{bps:02X})"),
        ));
    }
    let bps = u32::try_from(bps).unwrap_or(u32::MAX);
    Ok(BaudRate::from_bits_per_second(bps)?)
}

/// A key that is not a setting: if it names a register of the memory map (or `reg:N`), the
/// protocol core's write validation says why it cannot be written; otherwise it is unknown.
fn refuse_other_register(arg: &str, key: &str, value: &str) -> CommissionError {
    let address = if let Some(n) = key
        .strip_prefix("reg:")
        .or_else(|| key.strip_prefix("register:"))
    {
        match parse_int(n).and_then(|n| u8::try_from(n).ok()) {
            Some(a) => Some(a),
            None => return bad(arg, format!("`{n}` is not a register number 0–59")),
        }
    } else {
        MAP.iter().find(|r| kebab(r.name) == key).map(|r| r.address)
    };
    let Some(address) = address else {
        return bad(arg, format!("unknown key `{key}`; the keys are: {KEYS}"));
    };
    let register = register_at(address);
    let raw = parse_int(value).unwrap_or(0);
    let bytes = if register.size == 2 {
        (raw as i16).to_le_bytes().to_vec()
    } else {
        vec![raw as u8]
    };
    if let Err(e) = validate_write(address, &bytes) {
        return e.into();
    }
    match register.access {
        Access::ReadWrite => bad(
            arg,
            format!(
                "`set` does not write register {address} ({}); use `move` for goals and `force` for force enable; the keys of `set` are: {KEYS}",
                register.name,
            ),
        ),
        _ => bad(arg, format!("register {address} cannot be written")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_key_parses_to_the_spec_bytes() {
        let plus = Setting::parse("plus-limit=20.0").unwrap();
        let id1 = ServoId::new(1).unwrap();
        assert_eq!(
            plus.packet(id1, ReplyRequest::None).unwrap().to_bytes(),
            [0xFA, 0xAF, 0x01, 0x00, 0x08, 0x02, 0x01, 0xD0, 0x07, 0xDD]
        );
        let minus = Setting::parse("minus-limit=-20mm").unwrap();
        assert_eq!(
            minus.packet(id1, ReplyRequest::None).unwrap().to_bytes(),
            [0xFA, 0xAF, 0x01, 0x00, 0x0A, 0x02, 0x01, 0x30, 0xF8, 0xC0]
        );
        let baud = Setting::parse("baud=38400").unwrap();
        assert_eq!(
            baud.packet(id1, ReplyRequest::None).unwrap().to_bytes(),
            [0xFA, 0xAF, 0x01, 0x00, 0x06, 0x01, 0x01, 0x04, 0x03]
        );
        assert_eq!(
            Setting::parse("punch=0x0120").unwrap().data(),
            vec![0x20, 0x01]
        );
        assert_eq!(
            Setting::parse("id=5").unwrap(),
            Setting::Id(ServoId::new(5).unwrap())
        );
        assert_eq!(
            Setting::parse("reverse=true").unwrap(),
            Setting::Reverse(true)
        );
        assert_eq!(
            Setting::parse("baud=0x0A").unwrap(),
            Setting::Baud(BaudRate::B460800)
        );
        assert_eq!(
            Setting::parse("max-force=80%").unwrap(),
            Setting::MaxForce(Percent::new(80).unwrap())
        );
        assert_eq!(
            Setting::parse("return-delay=2ms").unwrap(),
            Setting::ReturnDelay(2)
        );
    }

    #[test]
    fn dangerous_values_are_refused() {
        for arg in [
            "plus-limit=25.01",
            "minus-limit=-25.01",
            "plus-limit=-1",
            "minus-limit=0.5",
            "plus-limit=1e9",
            "baud=921600",
            "baud=0x0B",
            "baud=7",
            "id=0",
            "id=128",
            "id=300",
            "punch=0x8000",
            "max-force=101",
            "reverse=2",
            "plus-margin=256",
            "model-number=1",
            "temperature-limit=90",
            "reg:3=0",
            "reg:0=0",
            "goal-position=0",
            "colour=red",
            "id",
        ] {
            let error = Setting::parse(arg).unwrap_err();
            assert!(error.is_refusal(), "{arg}: {error}");
        }
    }

    #[test]
    fn refusals_say_why() {
        let e = Setting::parse("plus-limit=25.01").unwrap_err().to_string();
        assert!(e.contains("25.01") && e.contains("±25.00 mm"), "{e}");
        let e = Setting::parse("baud=921600").unwrap_err().to_string();
        assert!(e.contains("921600"), "{e}");
        let e = Setting::parse("model-number=1").unwrap_err().to_string();
        assert!(e.contains("read only"), "{e}");
        let e = Setting::parse("id=128").unwrap_err().to_string();
        assert!(e.contains("1–127"), "{e}");
    }

    #[test]
    fn a_key_given_twice_refuses_the_lot() {
        assert!(Setting::parse_all(&["punch=1", "punch=2"]).is_err());
        let all = Setting::parse_all(&["punch=1", "id=3", "plus-limit=10"]).unwrap();
        assert_eq!(
            all.iter().map(Setting::key).collect::<Vec<_>>(),
            ["id", "plus-limit", "punch"]
        );
    }
}
