//! The LJ9DA41 memory map (registers 0–59): names, sizes, access rules, units, and the
//! validation every write passes before it is encoded.
//!
//! A write is refused when it touches a read-only or reserved register, covers only half of a
//! two-byte register (half a limit is an unchecked limit), or carries a value the manual forbids
//! (a limit beyond ±25.00 mm, an unknown baud code, an ID outside 1–127, …).

use super::MEMORY_MAP_LEN;
use super::baud::BaudRate;
use super::error::ProtocolError;
use super::id::ServoId;
use super::reply::Telemetry;
use super::units::{Celsius, MmCenti, Ms10, Percent, PositionLimits, Punch};

/// Whether a register may be written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Access {
    ReadOnly,
    ReadWrite,
    /// Reserved by the maker: nothing may be written there.
    Reserved,
}

/// Where a register lives: fixed, ROM (saved by a flash write, 4–29) or RAM (lost at power-off).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Area {
    Fixed,
    Rom,
    Ram,
}

/// One register (one or two bytes) of the memory map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Register {
    pub address: u8,
    pub size: u8,
    pub name: &'static str,
    pub access: Access,
    pub area: Area,
    /// The unit of the raw value, as the manual gives it.
    pub unit: &'static str,
}

/// Register addresses, named as in the manual.
pub mod addr {
    pub const MODEL_NUMBER: u8 = 0x00;
    pub const FIRMWARE_VERSION: u8 = 0x02;
    pub const SERVO_ID: u8 = 0x04;
    pub const REVERSE: u8 = 0x05;
    pub const BAUD_RATE: u8 = 0x06;
    pub const RETURN_DELAY: u8 = 0x07;
    pub const PLUS_LIMIT: u8 = 0x08;
    pub const MINUS_LIMIT: u8 = 0x0A;
    pub const TEMPERATURE_LIMIT: u8 = 0x0E;
    pub const PLUS_COMPLIANCE_MARGIN: u8 = 0x18;
    pub const MINUS_COMPLIANCE_MARGIN: u8 = 0x19;
    pub const PLUS_COMPLIANCE_SLOPE: u8 = 0x1A;
    pub const MINUS_COMPLIANCE_SLOPE: u8 = 0x1B;
    pub const PUNCH: u8 = 0x1C;
    pub const GOAL_POSITION: u8 = 0x1E;
    pub const GOAL_TIME: u8 = 0x20;
    pub const MAX_FORCE: u8 = 0x23;
    pub const FORCE_ENABLE: u8 = 0x24;
    pub const PRESENT_POSITION: u8 = 0x2A;
    pub const PRESENT_TIME: u8 = 0x2C;
    pub const PRESENT_LOAD: u8 = 0x30;
    pub const PRESENT_TEMPERATURE: u8 = 0x32;
    pub const PRESENT_VOLTAGE: u8 = 0x34;
}

const fn reg(
    address: u8,
    size: u8,
    name: &'static str,
    access: Access,
    area: Area,
    unit: &'static str,
) -> Register {
    Register {
        address,
        size,
        name,
        access,
        area,
        unit,
    }
}

use Access::{ReadOnly as R, ReadWrite as RW, Reserved as RES};
use Area::{Fixed, Ram, Rom};

/// Every named register of the map, in address order. Addresses not listed are reserved.
pub const MAP: &[Register] = &[
    reg(0x00, 2, "Model Number", R, Fixed, ""),
    reg(0x02, 1, "Firmware Version", R, Fixed, ""),
    reg(0x04, 1, "Servo ID", RW, Rom, "1–127"),
    reg(0x05, 1, "Reverse", RW, Rom, "0 normal, 1 reversed"),
    reg(0x06, 1, "Baud Rate", RW, Rom, "code 00h–0Ah"),
    reg(0x07, 1, "Return Delay Time", RW, Rom, "1 ms"),
    reg(0x08, 2, "Plus Position Limit", RW, Rom, "0.01 mm"),
    reg(0x0A, 2, "Minus Position Limit", RW, Rom, "0.01 mm"),
    reg(0x0E, 2, "Temperature Limit", R, Rom, "°C"),
    reg(0x18, 1, "Plus Compliance Margin", RW, Rom, "≈0.01 mm"),
    reg(0x19, 1, "Minus Compliance Margin", RW, Rom, "≈0.01 mm"),
    reg(0x1A, 1, "Plus Compliance Slope", RW, Rom, "0.1 mm"),
    reg(0x1B, 1, "Minus Compliance Slope", RW, Rom, "0.1 mm"),
    reg(0x1C, 2, "Punch", RW, Rom, "0.00208 % of max current"),
    reg(0x1E, 2, "Goal Position", RW, Ram, "0.01 mm"),
    reg(0x20, 2, "Goal Time", RW, Ram, "10 ms"),
    reg(0x23, 1, "Max Force", RW, Ram, "1 %"),
    reg(0x24, 1, "Force Enable", RW, Ram, "0 off, 1 on, 2 brake"),
    reg(0x2A, 2, "Present Position", R, Ram, "0.01 mm"),
    reg(0x2C, 2, "Present Time", R, Ram, "10 ms"),
    reg(0x30, 2, "Present Load", R, Ram, "10 mA"),
    reg(0x32, 2, "Present Temperature", R, Ram, "°C"),
    reg(0x34, 2, "Present Voltage", R, Ram, "10 mV"),
];

/// The register that contains `address`, or a reserved one-byte placeholder.
pub fn register_at(address: u8) -> Register {
    MAP.iter()
        .copied()
        .find(|r| (r.address..r.address + r.size).contains(&address))
        .unwrap_or_else(|| {
            let area = match address {
                0..=3 => Fixed,
                4..=29 => Rom,
                _ => Ram,
            };
            reg(address, 1, "Reserved", RES, area, "")
        })
}

/// Force Enable (register 36).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ForceMode {
    Off = 0,
    On = 1,
    /// The rod moves by hand with light resistance.
    Brake = 2,
}

impl ForceMode {
    pub fn from_byte(value: u8) -> Result<Self, ProtocolError> {
        match value {
            0 => Ok(ForceMode::Off),
            1 => Ok(ForceMode::On),
            2 => Ok(ForceMode::Brake),
            _ => Err(ProtocolError::InvalidForceMode { value }),
        }
    }
}

/// Check that writing `data` at `address` is allowed and every value in it is safe.
pub fn validate_write(address: u8, data: &[u8]) -> Result<(), ProtocolError> {
    if data.is_empty() {
        return Err(ProtocolError::EmptyWrite);
    }
    let start = usize::from(address);
    let end = start + data.len();
    if end > MEMORY_MAP_LEN {
        return Err(ProtocolError::OutsideMap {
            start,
            end: end - 1,
        });
    }
    let mut at = start;
    while at < end {
        let r = register_at(at as u8);
        let r_start = usize::from(r.address);
        let r_end = r_start + usize::from(r.size);
        match r.access {
            Access::ReadOnly => {
                return Err(ProtocolError::ReadOnlyRegister {
                    address: r.address,
                    name: r.name,
                });
            }
            Access::Reserved => return Err(ProtocolError::ReservedRegister { address: r.address }),
            Access::ReadWrite => {}
        }
        if r_start < start || r_end > end {
            return Err(ProtocolError::SplitRegister {
                start: address,
                len: data.len(),
                address: r.address,
                name: r.name,
            });
        }
        validate_value(r.address, &data[r_start - start..r_end - start])?;
        at = r_end;
    }
    Ok(())
}

/// Check one whole register's new value.
fn validate_value(address: u8, bytes: &[u8]) -> Result<(), ProtocolError> {
    let word = || i16::from_le_bytes([bytes[0], bytes.get(1).copied().unwrap_or(0)]);
    match address {
        addr::SERVO_ID => ServoId::new(bytes[0]).map(drop),
        addr::REVERSE if bytes[0] > 1 => Err(ProtocolError::InvalidReverse { value: bytes[0] }),
        addr::BAUD_RATE => BaudRate::from_code(bytes[0]).map(drop),
        addr::PLUS_LIMIT => PositionLimits::check_plus(MmCenti(word())).map(drop),
        addr::MINUS_LIMIT => PositionLimits::check_minus(MmCenti(word())).map(drop),
        addr::PUNCH => Punch::new(word() as u16).map(drop),
        addr::GOAL_POSITION => MmCenti(word()).within_stroke().map(drop),
        addr::MAX_FORCE => Percent::new(bytes[0]).map(drop),
        addr::FORCE_ENABLE => ForceMode::from_byte(bytes[0]).map(drop),
        _ => Ok(()),
    }
}

/// Check that a read of `length` bytes from `address` stays inside the map.
pub fn validate_read(address: u8, length: u8) -> Result<(), ProtocolError> {
    if length == 0 || usize::from(address) + usize::from(length) > MEMORY_MAP_LEN {
        Err(ProtocolError::ReadOutsideMap {
            address,
            len: length,
        })
    } else {
        Ok(())
    }
}

/// A copy of (part of) a servo's memory map, with typed accessors. Registers not read yet are 0.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MemoryMap {
    bytes: [u8; MEMORY_MAP_LEN],
}

impl Default for MemoryMap {
    fn default() -> Self {
        Self {
            bytes: [0; MEMORY_MAP_LEN],
        }
    }
}

impl MemoryMap {
    /// The map with `data` stored from `address` on (bytes beyond register 59 are dropped).
    pub fn store(&mut self, address: u8, data: &[u8]) {
        let start = usize::from(address).min(MEMORY_MAP_LEN);
        let end = (start + data.len()).min(MEMORY_MAP_LEN);
        self.bytes[start..end].copy_from_slice(&data[..end - start]);
    }

    pub fn bytes(&self) -> &[u8; MEMORY_MAP_LEN] {
        &self.bytes
    }

    fn u16_at(&self, address: u8) -> u16 {
        let a = usize::from(address);
        u16::from_le_bytes([self.bytes[a], self.bytes[a + 1]])
    }

    fn i16_at(&self, address: u8) -> i16 {
        self.u16_at(address) as i16
    }

    fn u8_at(&self, address: u8) -> u8 {
        self.bytes[usize::from(address)]
    }

    pub fn model_number(&self) -> u16 {
        self.u16_at(addr::MODEL_NUMBER)
    }
    pub fn firmware_version(&self) -> u8 {
        self.u8_at(addr::FIRMWARE_VERSION)
    }
    pub fn servo_id(&self) -> Result<ServoId, ProtocolError> {
        ServoId::new(self.u8_at(addr::SERVO_ID))
    }
    pub fn reversed(&self) -> bool {
        self.u8_at(addr::REVERSE) != 0
    }
    pub fn baud_rate(&self) -> Result<BaudRate, ProtocolError> {
        BaudRate::from_code(self.u8_at(addr::BAUD_RATE))
    }
    pub fn return_delay_ms(&self) -> u8 {
        self.u8_at(addr::RETURN_DELAY)
    }
    pub fn plus_limit(&self) -> MmCenti {
        MmCenti(self.i16_at(addr::PLUS_LIMIT))
    }
    pub fn minus_limit(&self) -> MmCenti {
        MmCenti(self.i16_at(addr::MINUS_LIMIT))
    }
    pub fn temperature_limit(&self) -> Celsius {
        Celsius(self.i16_at(addr::TEMPERATURE_LIMIT))
    }
    pub fn compliance_margins(&self) -> (u8, u8) {
        (
            self.u8_at(addr::PLUS_COMPLIANCE_MARGIN),
            self.u8_at(addr::MINUS_COMPLIANCE_MARGIN),
        )
    }
    pub fn compliance_slopes(&self) -> (u8, u8) {
        (
            self.u8_at(addr::PLUS_COMPLIANCE_SLOPE),
            self.u8_at(addr::MINUS_COMPLIANCE_SLOPE),
        )
    }
    pub fn punch_raw(&self) -> u16 {
        self.u16_at(addr::PUNCH)
    }
    pub fn goal_position(&self) -> MmCenti {
        MmCenti(self.i16_at(addr::GOAL_POSITION))
    }
    pub fn goal_time(&self) -> Ms10 {
        Ms10(self.u16_at(addr::GOAL_TIME))
    }
    pub fn max_force_raw(&self) -> u8 {
        self.u8_at(addr::MAX_FORCE)
    }
    pub fn force_mode(&self) -> Result<ForceMode, ProtocolError> {
        ForceMode::from_byte(self.u8_at(addr::FORCE_ENABLE))
    }
    /// Registers 42–59 decoded.
    pub fn telemetry(&self) -> Telemetry {
        Telemetry::from_registers(&self.bytes[usize::from(addr::PRESENT_POSITION)..])
            .unwrap_or_default()
    }

    /// Every register with its raw value and a human reading, for inspection tools.
    pub fn describe(&self) -> Vec<(Register, u16, String)> {
        let mut out = Vec::new();
        let mut at = 0u8;
        while usize::from(at) < MEMORY_MAP_LEN {
            let r = register_at(at);
            let raw = if r.size == 2 {
                self.u16_at(r.address)
            } else {
                u16::from(self.u8_at(r.address))
            };
            out.push((r, raw, self.reading(r, raw)));
            at += r.size;
        }
        out
    }

    fn reading(&self, r: Register, raw: u16) -> String {
        match r.address {
            addr::MODEL_NUMBER => format!(
                "0x{raw:04X}{}",
                if raw == super::LJ9DA41_MODEL_NUMBER {
                    " (LJ9DA41)"
                } else {
                    " (not an LJ9DA41)"
                }
            ),
            addr::REVERSE => if raw == 0 {
                "extend = +"
            } else {
                "extend = − (reversed)"
            }
            .into(),
            addr::BAUD_RATE => match BaudRate::from_code(raw as u8) {
                Ok(b) => b.to_string(),
                Err(_) => format!("unknown code 0x{raw:02X}"),
            },
            addr::RETURN_DELAY => format!("{raw} ms"),
            addr::PLUS_LIMIT | addr::MINUS_LIMIT | addr::GOAL_POSITION | addr::PRESENT_POSITION => {
                MmCenti(raw as i16).to_string()
            }
            addr::TEMPERATURE_LIMIT | addr::PRESENT_TEMPERATURE => Celsius(raw as i16).to_string(),
            addr::PUNCH => format!(
                "{:.1} % of max current",
                Punch::new(raw).map(Punch::percent).unwrap_or(f64::NAN)
            ),
            addr::GOAL_TIME | addr::PRESENT_TIME => Ms10(raw).to_string(),
            addr::MAX_FORCE => format!("{} %", raw.min(100)),
            addr::FORCE_ENABLE => match ForceMode::from_byte(raw as u8) {
                Ok(ForceMode::Off) => "off".into(),
                Ok(ForceMode::On) => "on".into(),
                Ok(ForceMode::Brake) => "brake".into(),
                Err(_) => format!("unknown 0x{raw:02X}"),
            },
            addr::PRESENT_LOAD => super::units::Ma10(raw).to_string(),
            addr::PRESENT_VOLTAGE => super::units::Mv10(raw).to_string(),
            _ => format!("{raw}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_to_read_only_registers_are_refused() {
        for address in [0x00, 0x02, 0x0E, 0x2A, 0x30, 0x34] {
            assert!(
                matches!(
                    validate_write(address, &[0, 0]),
                    Err(ProtocolError::ReadOnlyRegister { .. })
                ),
                "register {address}"
            );
        }
    }

    #[test]
    fn writes_to_reserved_registers_are_refused() {
        for address in [0x03, 0x0C, 0x10, 0x17, 0x22, 0x25, 0x26, 0x2E, 0x36, 0x3B] {
            assert!(
                matches!(
                    validate_write(address, &[0]),
                    Err(ProtocolError::ReservedRegister { .. })
                ),
                "register {address}"
            );
        }
    }

    #[test]
    fn half_of_a_two_byte_register_cannot_be_written() {
        assert!(matches!(
            validate_write(0x09, &[0x09]),
            Err(ProtocolError::SplitRegister { address: 0x08, .. })
        ));
        assert!(matches!(
            validate_write(0x08, &[0xC4]),
            Err(ProtocolError::SplitRegister { .. })
        ));
    }

    #[test]
    fn dangerous_values_are_refused() {
        assert!(validate_write(addr::PLUS_LIMIT, &2501i16.to_le_bytes()).is_err());
        assert!(validate_write(addr::MINUS_LIMIT, &(-2501i16).to_le_bytes()).is_err());
        assert!(validate_write(addr::BAUD_RATE, &[0x0B]).is_err());
        assert!(validate_write(addr::SERVO_ID, &[0]).is_err());
        assert!(validate_write(addr::SERVO_ID, &[128]).is_err());
        assert!(validate_write(addr::MAX_FORCE, &[101]).is_err());
        assert!(validate_write(addr::PUNCH, &0x8000u16.to_le_bytes()).is_err());
        assert!(validate_write(addr::FORCE_ENABLE, &[3]).is_err());
        assert!(validate_write(addr::REVERSE, &[2]).is_err());
        // A span write is checked register by register.
        let mut span = [0u8; 6];
        span[..2].copy_from_slice(&2600i16.to_le_bytes());
        assert!(validate_write(addr::PLUS_LIMIT, &span[..4]).is_err());
    }

    #[test]
    fn safe_values_are_accepted() {
        assert!(validate_write(addr::PLUS_LIMIT, &2500i16.to_le_bytes()).is_ok());
        assert!(validate_write(addr::MINUS_LIMIT, &(-2500i16).to_le_bytes()).is_ok());
        assert!(
            validate_write(
                addr::PLUS_COMPLIANCE_MARGIN,
                &[1, 1, 0x10, 0x10, 0x20, 0x01]
            )
            .is_ok()
        );
        assert!(validate_write(addr::GOAL_POSITION, &[0x84, 0x03, 0xF4, 0x01]).is_ok());
        assert!(validate_write(addr::BAUD_RATE, &[0x0A]).is_ok());
    }

    #[test]
    fn writes_past_register_59_are_refused() {
        assert!(matches!(
            validate_write(59, &[0, 0]),
            Err(ProtocolError::OutsideMap { .. })
        ));
        assert!(validate_read(0x2A, 18).is_ok());
        assert!(validate_read(0x3B, 2).is_err());
        assert!(validate_read(0x00, 0).is_err());
    }

    #[test]
    fn memory_map_decodes_defaults() {
        let mut m = MemoryMap::default();
        m.store(
            0,
            &[
                0x10, 0x75, 0x01, 0x00, 0x01, 0x00, 0x07, 0x00, 0xC4, 0x09, 0x3C, 0xF6, 0, 0, 0x55,
                0,
            ],
        );
        assert_eq!(m.model_number(), 0x7510);
        assert_eq!(m.servo_id().unwrap().get(), 1);
        assert_eq!(m.baud_rate().unwrap(), BaudRate::B115200);
        assert_eq!(m.plus_limit(), MmCenti(2500));
        assert_eq!(m.minus_limit(), MmCenti(-2500));
        assert_eq!(m.temperature_limit(), Celsius(85));
        let described = m.describe();
        assert_eq!(
            described
                .iter()
                .map(|(r, _, _)| usize::from(r.size))
                .sum::<usize>(),
            60
        );
        assert!(described[0].2.contains("LJ9DA41"));
    }
}
