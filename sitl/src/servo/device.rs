//! One simulated LJ9DA41: memory map, RAM and flash, force, motion, current, heat, and its answers to
//! host packets. Pure: every call is handed `now`; nothing here reads a clock or does I/O.
//!
//! Coordinates: the rod's physical position (`rod_mm`, extend = +) is what moves. Registers use the
//! servo's logical coordinates: the same, or mirrored when Reverse (register 5) is set. The position limits
//! protect the physical ends of travel, so with Reverse set they are mirrored in logical coordinates
//! (manual: "01H に設定した場合、リミット位置の範囲も反転します").

use std::time::{Duration, Instant};

use super::memory_map::{
    self as map, Access, FACTORY_ROM, LJ9DA41_MODEL_NUMBER, MAP_LEN, ROM_END, ROM_LEN, ROM_START,
    STROKE_LIMIT_MM_CENTI, reg,
};
use super::physics::{self, Drive, MECHANICAL_STROKE_MM, Wear, duration_from_secs};
use crate::events::{DamageKind, IgnoreReason};
use crate::protocol::host_packet::{HostPacket, ShortForm, SpecialCommand};
use crate::protocol::return_packet::{
    self, FLAG_FLASH_WRITE_ERROR, FLAG_TEMPERATURE_ALARM, FLAG_TEMPERATURE_ERROR,
};
use crate::protocol::{ACK_BYTE, BROADCAST_ID};

/// How long a flash write (or factory reset) keeps the servo deaf. The manual says to wait at least 1 s;
/// a host that does is never caught by it.
pub const FLASH_WRITE_TIME: Duration = Duration::from_millis(900);
/// How long the servo stays deaf after a reboot or power-on.
pub const BOOT_TIME: Duration = Duration::from_millis(50);
/// Integration step while the rod is driven.
const MOVING_STEP: Duration = Duration::from_millis(1);
/// Integration step otherwise: the temperature model is solved exactly over a step at constant current,
/// so the step only bounds how late the temperature limit is noticed.
const IDLE_STEP: Duration = Duration::from_secs(1);
/// Integration step while the overheat fault ramps the temperature.
const OVERHEAT_STEP: Duration = Duration::from_millis(100);
/// The alarm flag is set this many °C below the temperature limit.
const ALARM_MARGIN_C: i32 = 10;

/// Register 36 as the servo understands it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Force {
    Off,
    On,
    Brake,
}

/// Why the servo cannot listen right now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Busy {
    FlashWrite,
    Booting,
}

/// A move toward a goal: the reference runs linearly from `from_mm` to `to_mm` over `duration`, and the rod
/// follows it at most at the speed the load allows.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Motion {
    started_at: Instant,
    from_mm: f64,
    to_mm: f64,
    duration: Duration,
    /// The Goal Time given for this move (zero: none).
    goal_time: Duration,
}

impl Motion {
    fn reference_mm(&self, t: Instant) -> f64 {
        let elapsed = t.saturating_duration_since(self.started_at);
        if self.duration.is_zero() || elapsed >= self.duration {
            return self.to_mm;
        }
        let fraction = elapsed.as_secs_f64() / self.duration.as_secs_f64();
        self.from_mm + (self.to_mm - self.from_mm) * fraction
    }

    fn profile_done(&self, t: Instant) -> bool {
        t.saturating_duration_since(self.started_at) >= self.duration
    }
}

/// Start-up settings of one servo.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServoConfig {
    /// ID stored in flash.
    pub id: u8,
    /// Baud-rate code stored in flash.
    pub baud_code: u8,
    /// Return Delay Time stored in flash (ms).
    pub return_delay_ms: u8,
    pub voltage_v: f64,
    pub ambient_c: f64,
}

/// What a servo did with one packet.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Reception {
    /// The packet was addressed to this servo and it acted on it.
    pub acted: bool,
    /// Bytes to put on the wire after the return delay.
    pub reply: Option<Vec<u8>>,
    pub damage: Vec<DamageKind>,
    pub ignored: Option<IgnoreReason>,
}

/// A copy of a servo's state for tests and status displays.
#[derive(Debug, Clone, PartialEq)]
pub struct ServoSnapshot {
    /// Position of the servo in the configured ID list.
    pub slot: usize,
    /// Current ID (register 4).
    pub id: u8,
    /// Goal Position register, mm (logical coordinates).
    pub goal_mm: f32,
    /// Present Position register, mm (logical coordinates, 0.02 mm steps).
    pub position_mm: f32,
    /// Physical rod position, mm (extend = +), unquantised.
    pub rod_mm: f32,
    pub current_a: f32,
    pub temperature_c: f32,
    pub ambient_c: f32,
    pub voltage_v: f32,
    pub force: Force,
    /// Temperature alarm (return flag bit 5).
    pub alarm: bool,
    /// Temperature-limit error, latched (return flag bit 7).
    pub error: bool,
    /// Flash-write error (return flag bit 3).
    pub flash_error: bool,
    /// Plugged in and powered.
    pub online: bool,
    /// Deaf for now: flash write under way or booting.
    pub busy: bool,
    /// Current bit rate (`None` after a forbidden baud code was written).
    pub baud: Option<u32>,
    pub registers: [u8; MAP_LEN],
    /// Registers 4–29 as saved in flash.
    pub flash: [u8; ROM_LEN],
    pub model_number: u16,
    pub stalled: bool,
    pub load_n: f32,
    pub overheating: bool,
}

/// One simulated servo.
#[derive(Debug, Clone)]
pub struct Servo {
    map: [u8; MAP_LEN],
    flash: [u8; ROM_LEN],
    pending_flash: Option<[u8; ROM_LEN]>,
    model_number: u16,
    powered: bool,
    busy: Option<(Instant, Busy)>,
    flash_error: bool,
    temperature_error: bool,
    rod_mm: f64,
    motion: Option<Motion>,
    temperature_c: f64,
    ambient_c: f64,
    voltage_v: f64,
    current_a: f64,
    load_n: f64,
    wear: Wear,
    stalled: bool,
    overheating: bool,
    last_update: Instant,
}

impl Servo {
    /// A servo powered and ready at `now`, rod at 0.00 mm, at ambient temperature.
    pub fn new(config: ServoConfig, now: Instant) -> Self {
        let mut flash = FACTORY_ROM;
        flash[reg::SERVO_ID - ROM_START] = config.id;
        flash[reg::BAUD_RATE - ROM_START] = config.baud_code;
        flash[reg::RETURN_DELAY_MS - ROM_START] = config.return_delay_ms;
        let mut servo = Servo {
            map: map::power_on_map(&flash, LJ9DA41_MODEL_NUMBER),
            flash,
            pending_flash: None,
            model_number: LJ9DA41_MODEL_NUMBER,
            powered: true,
            busy: None,
            flash_error: false,
            temperature_error: false,
            rod_mm: 0.0,
            motion: None,
            temperature_c: config.ambient_c,
            ambient_c: config.ambient_c,
            voltage_v: config.voltage_v,
            current_a: physics::STANDING_CURRENT_A,
            load_n: 0.0,
            wear: Wear::default(),
            stalled: false,
            overheating: false,
            last_update: now,
        };
        servo.refresh_live_registers(now);
        servo
    }

    /// Current ID (register 4; takes effect on receipt).
    pub fn id(&self) -> u8 {
        self.map[reg::SERVO_ID]
    }

    /// Current bit rate (register 6; takes effect on receipt). `None` for a forbidden code.
    pub fn baud(&self) -> Option<u32> {
        map::baud_from_code(self.map[reg::BAUD_RATE])
    }

    /// Return Delay Time (register 7).
    pub fn return_delay(&self) -> Duration {
        Duration::from_millis(self.map[reg::RETURN_DELAY_MS].into())
    }

    pub fn is_powered(&self) -> bool {
        self.powered
    }

    /// Register 36 as a [`Force`].
    pub fn force(&self) -> Force {
        match self.map[reg::FORCE_ENABLE] {
            1 => Force::On,
            2 => Force::Brake,
            _ => Force::Off,
        }
    }

    /// The whole memory map as it reads now (call [`Servo::update`] first).
    pub fn registers(&self) -> &[u8; MAP_LEN] {
        &self.map
    }

    fn busy_reason(&self, now: Instant) -> Option<IgnoreReason> {
        match self.busy {
            Some((until, Busy::FlashWrite)) if now < until => Some(IgnoreReason::FlashWriteBusy),
            Some((until, Busy::Booting)) if now < until => Some(IgnoreReason::Booting),
            _ => None,
        }
    }

    // ----- packets -----

    /// Whether `packet` is addressed to this servo.
    pub fn is_addressed(&self, packet: &HostPacket) -> bool {
        match packet {
            HostPacket::Short(short) => short.id == self.id() || short.id == BROADCAST_ID,
            HostPacket::Long(long) => long.blocks.iter().any(|block| block.vid == self.id()),
        }
    }

    /// Act on a packet that fully arrived at `now` (the caller checked the bit rate).
    pub fn receive(&mut self, now: Instant, packet: &HostPacket) -> Reception {
        let mut reception = Reception::default();
        if !self.powered || !self.is_addressed(packet) {
            return reception;
        }
        self.update(now);
        if let Some(reason) = self.busy_reason(now) {
            reception.ignored = Some(reason);
            return reception;
        }
        match packet {
            HostPacket::Long(long) => {
                let my_id = self.id();
                reception.acted = true;
                for block in long.blocks.iter().filter(|block| block.vid == my_id) {
                    self.apply_write(now, long.address, &block.data, &mut reception.damage);
                }
            }
            HostPacket::Short(short) => {
                let broadcast = short.id == BROADCAST_ID;
                let reply = match short.form() {
                    ShortForm::Write {
                        address,
                        data,
                        reply_code,
                    } => {
                        reception.acted = true;
                        self.apply_write(now, address, data, &mut reception.damage);
                        self.reply(reply_code, address, short.length)
                    }
                    ShortForm::Request {
                        address,
                        length,
                        reply_code,
                    } => {
                        reception.acted = true;
                        self.reply(reply_code, address, length)
                    }
                    ShortForm::Special(command) => {
                        reception.acted = true;
                        self.special(now, command, &mut reception.damage);
                        Ok(None)
                    }
                    ShortForm::CombinedSpecial => Err(IgnoreReason::CombinedSpecialFlags),
                    ShortForm::MalformedSpecial => Err(IgnoreReason::MalformedSpecial),
                    ShortForm::CountAboveOne => Err(IgnoreReason::CountAboveOne),
                };
                match reply {
                    Ok(bytes) => reception.reply = bytes.filter(|_| !broadcast),
                    Err(reason) => reception.ignored = Some(reason),
                }
            }
        }
        reception
    }

    /// The reply asked for by flag bits 3–0 (`address`, `length` only matter for code 1111).
    fn reply(
        &self,
        reply_code: u8,
        address: u8,
        length: u8,
    ) -> Result<Option<Vec<u8>>, IgnoreReason> {
        let (start, len) = match reply_code {
            0x0 => return Ok(None),
            0x1 => return Ok(Some(vec![ACK_BYTE])),
            0x3 => (0, 30),
            0x5 => (30, 30),
            0x7 => (20, 10),
            0x9 => (42, 18),
            0xB => (30, 12),
            0xF => {
                let (start, len) = (usize::from(address), usize::from(length));
                if len == 0 || start + len > MAP_LEN {
                    return Err(IgnoreReason::ReadOutOfMap { address, length });
                }
                (start, len)
            }
            other => return Err(IgnoreReason::UnknownReplyCode(other)),
        };
        let start_register = u8::try_from(start).unwrap_or(0);
        Ok(Some(return_packet::encode(
            self.id(),
            self.status_flags(),
            start_register,
            &self.map[start..start + len],
        )))
    }

    /// Return-packet flags: bit 7 temperature error, bit 5 temperature alarm, bit 3 flash-write error.
    pub fn status_flags(&self) -> u8 {
        let mut flags = 0;
        if self.temperature_error {
            flags |= FLAG_TEMPERATURE_ERROR;
        }
        if self.alarm() {
            flags |= FLAG_TEMPERATURE_ALARM;
        }
        if self.flash_error {
            flags |= FLAG_FLASH_WRITE_ERROR;
        }
        flags
    }

    fn temperature_limit_c(&self) -> i32 {
        i32::from(map::get_u16(&self.map, reg::TEMPERATURE_LIMIT))
    }

    fn temperature_register_c(&self) -> i32 {
        self.temperature_c
            .round()
            .clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i32
    }

    fn alarm(&self) -> bool {
        self.powered && self.temperature_register_c() >= self.temperature_limit_c() - ALARM_MARGIN_C
    }

    fn special(&mut self, now: Instant, command: SpecialCommand, damage: &mut Vec<DamageKind>) {
        match command {
            SpecialCommand::WriteFlash => {
                let mut rom = [0u8; ROM_LEN];
                rom.copy_from_slice(&self.map[ROM_START..ROM_END]);
                self.pending_flash = Some(rom);
                self.busy = Some((now + FLASH_WRITE_TIME, Busy::FlashWrite));
            }
            SpecialCommand::Reboot => self.boot(now),
            SpecialCommand::FactoryReset => {
                // Registers 4–29 go back to the factory values at once (ID 1, 115 200 bit/s) and are saved
                // to flash, so the reset survives a reboot.
                self.apply_write(now, reg::SERVO_ID as u8, &FACTORY_ROM, damage);
                self.map[ROM_START..ROM_END].copy_from_slice(&FACTORY_ROM);
                self.pending_flash = Some(FACTORY_ROM);
                self.busy = Some((now + FLASH_WRITE_TIME, Busy::FlashWrite));
            }
        }
    }

    /// Write `data` at `address`: read-only and reserved registers keep their value; then the side effects
    /// in register order (ID, baud, limits, goal, force).
    fn apply_write(
        &mut self,
        now: Instant,
        address: u8,
        data: &[u8],
        damage: &mut Vec<DamageKind>,
    ) {
        let mut touched = [false; MAP_LEN];
        let mut force_request = None;
        for (offset, &byte) in data.iter().enumerate() {
            let register = usize::from(address) + offset;
            if register >= MAP_LEN {
                break;
            }
            if map::access(register) != Access::ReadWrite {
                continue;
            }
            if register == reg::FORCE_ENABLE {
                force_request = Some(byte);
                continue;
            }
            self.map[register] = byte;
            touched[register] = true;
        }
        let id = self.id();
        if touched[reg::SERVO_ID] && !(1..=127).contains(&id) {
            damage.push(DamageKind::ForbiddenId(id));
        }
        if touched[reg::BAUD_RATE] && self.baud().is_none() {
            damage.push(DamageKind::UnknownBaudCode(self.map[reg::BAUD_RATE]));
        }
        let plus_touched =
            touched[reg::PLUS_POSITION_LIMIT] || touched[reg::PLUS_POSITION_LIMIT + 1];
        let minus_touched =
            touched[reg::MINUS_POSITION_LIMIT] || touched[reg::MINUS_POSITION_LIMIT + 1];
        let plus = map::get_i16(&self.map, reg::PLUS_POSITION_LIMIT);
        let minus = map::get_i16(&self.map, reg::MINUS_POSITION_LIMIT);
        if plus_touched && !(0..=STROKE_LIMIT_MM_CENTI).contains(&plus) {
            damage.push(DamageKind::PositionLimitBeyondStroke {
                register: 8,
                value_mm_centi: plus,
            });
        }
        if minus_touched && !(-STROKE_LIMIT_MM_CENTI..=0).contains(&minus) {
            damage.push(DamageKind::PositionLimitBeyondStroke {
                register: 10,
                value_mm_centi: minus,
            });
        }
        let goal_touched = touched[reg::GOAL_POSITION] || touched[reg::GOAL_POSITION + 1];
        let target_moved = touched[reg::REVERSE] || plus_touched || minus_touched;
        if goal_touched {
            let clamped = self.clamp_goal(map::get_i16(&self.map, reg::GOAL_POSITION));
            map::set_u16(&mut self.map, reg::GOAL_POSITION, clamped as u16);
        }
        if (goal_touched || target_moved) && self.force() == Force::On {
            self.start_motion(now);
        }
        if let Some(value) = force_request {
            self.set_force(now, value);
        }
        self.refresh_live_registers(now);
    }

    /// Sign from logical to physical coordinates.
    fn direction(&self) -> i32 {
        if self.map[reg::REVERSE] == 0 { 1 } else { -1 }
    }

    /// Physical position limits, 0.01 mm, ordered (low, high).
    fn physical_limits_centi(&self) -> (i32, i32) {
        let plus = i32::from(map::get_i16(&self.map, reg::PLUS_POSITION_LIMIT));
        let minus = i32::from(map::get_i16(&self.map, reg::MINUS_POSITION_LIMIT));
        (plus.min(minus), plus.max(minus))
    }

    /// A logical goal clamped to the (physical) limits, in logical coordinates.
    fn clamp_goal(&self, goal_centi: i16) -> i16 {
        let (low, high) = self.physical_limits_centi();
        let physical = (self.direction() * i32::from(goal_centi)).clamp(low, high);
        (self.direction() * physical).clamp(i16::MIN.into(), i16::MAX.into()) as i16
    }

    /// Physical target of the Goal Position register, mm.
    fn target_mm(&self) -> f64 {
        let goal = self.clamp_goal(map::get_i16(&self.map, reg::GOAL_POSITION));
        f64::from(self.direction() * i32::from(goal)) / 100.0
    }

    fn drive(&self) -> Drive {
        Drive {
            voltage_v: self.voltage_v,
            max_force_percent: f64::from(self.map[reg::MAX_FORCE].min(100)),
            load_n: self.load_n + self.wear.load_n_at(self.rod_mm),
        }
    }

    fn start_motion(&mut self, now: Instant) {
        let to_mm = self.target_mm();
        let goal_time =
            Duration::from_millis(u64::from(map::get_u16(&self.map, reg::GOAL_TIME)) * 10);
        let speed = self.drive().no_load_speed_mm_s();
        let at_full_speed = if speed > 0.0 {
            duration_from_secs((to_mm - self.rod_mm).abs() / speed)
        } else {
            Duration::ZERO
        };
        self.motion = Some(Motion {
            started_at: now,
            from_mm: self.rod_mm,
            to_mm,
            duration: goal_time.max(at_full_speed),
            goal_time,
        });
    }

    /// Register 36 written with `value`.
    fn set_force(&mut self, now: Instant, value: u8) {
        match value {
            0 => {
                self.map[reg::FORCE_ENABLE] = 0;
                self.motion = None;
            }
            1 => {
                // Refused (register unchanged) while the temperature error is latched or the rod is outside
                // the position limits.
                let (low, high) = self.physical_limits_centi();
                let rod_centi = i32::from(physics::quantise_mm_centi(self.rod_mm));
                if self.temperature_error || rod_centi < low || rod_centi > high {
                    return;
                }
                self.map[reg::FORCE_ENABLE] = 1;
                let present = physics::quantise_mm_centi(f64::from(self.direction()) * self.rod_mm);
                let goal = self.clamp_goal(present);
                map::set_u16(&mut self.map, reg::GOAL_POSITION, goal as u16);
                self.start_motion(now);
            }
            2 => {
                self.map[reg::FORCE_ENABLE] = 2;
                self.motion = None;
            }
            // The manual defines only 0, 1 and 2: other values are ignored.
            _ => {}
        }
    }

    /// Reboot or power-on: registers from flash, force off, goal 0, deaf for [`BOOT_TIME`]. The temperature
    /// error stays latched only if the temperature is still at or above the limit.
    fn boot(&mut self, now: Instant) {
        self.map = map::power_on_map(&self.flash, self.model_number);
        self.motion = None;
        self.temperature_error = self.temperature_register_c() >= self.temperature_limit_c();
        self.busy = Some((now + BOOT_TIME, Busy::Booting));
        self.refresh_live_registers(now);
    }

    // ----- power and faults -----

    /// Cut the power (unplug). A flash write under way is lost: damage, and the flash-write error flag.
    pub fn power_off(&mut self, now: Instant) -> Vec<DamageKind> {
        self.update(now);
        let mut damage = Vec::new();
        if !self.powered {
            return damage;
        }
        if self.pending_flash.take().is_some() {
            damage.push(DamageKind::PowerLostDuringFlashWrite);
            self.flash_error = true;
        }
        self.powered = false;
        self.busy = None;
        self.motion = None;
        self.map[reg::FORCE_ENABLE] = 0;
        self.current_a = 0.0;
        damage
    }

    /// Restore the power (plug in): power-on state from flash.
    pub fn power_on(&mut self, now: Instant) {
        self.update(now);
        if self.powered {
            return;
        }
        self.powered = true;
        self.boot(now);
    }

    pub fn set_model_number(&mut self, now: Instant, model_number: u16) {
        self.update(now);
        self.model_number = model_number;
        map::set_u16(&mut self.map, reg::MODEL_NUMBER, model_number);
    }

    pub fn set_load_n(&mut self, now: Instant, newtons: f64) {
        self.update(now);
        self.load_n = if newtons.is_finite() {
            newtons.max(0.0)
        } else {
            0.0
        };
    }

    /// Wear from `now` on (friction current both ways, one way or over a spot; a stiff spot);
    /// `Wear::default()` for none.
    pub fn set_wear(&mut self, now: Instant, wear: Wear) {
        self.update(now);
        self.wear = wear;
    }

    /// The wear set with [`Servo::set_wear`].
    pub fn wear(&self) -> Wear {
        self.wear
    }

    pub fn set_stalled(&mut self, now: Instant, stalled: bool) {
        self.update(now);
        self.stalled = stalled;
    }

    pub fn set_overheating(&mut self, now: Instant, overheating: bool) {
        self.update(now);
        self.overheating = overheating;
    }

    pub fn set_ambient_c(&mut self, now: Instant, ambient_c: f64) {
        self.update(now);
        if ambient_c.is_finite() {
            self.ambient_c = ambient_c;
        }
    }

    pub fn set_voltage_v(&mut self, now: Instant, voltage_v: f64) {
        self.update(now);
        if voltage_v.is_finite() {
            self.voltage_v = voltage_v.max(0.0);
        }
        self.refresh_live_registers(now);
    }

    /// Force the temperature (e.g. to test the alarm without waiting).
    pub fn set_temperature_c(&mut self, now: Instant, temperature_c: f64) {
        self.update(now);
        if temperature_c.is_finite() {
            self.temperature_c = temperature_c;
        }
        self.check_temperature();
        self.refresh_live_registers(now);
    }

    /// Move the rod by hand to a physical position (clamped to the mechanical stroke). With force on the
    /// servo drives it back to its goal.
    pub fn move_rod(&mut self, now: Instant, position_mm: f64) {
        self.update(now);
        if position_mm.is_finite() {
            self.rod_mm = position_mm.clamp(-MECHANICAL_STROKE_MM, MECHANICAL_STROKE_MM);
        }
        if self.force() == Force::On {
            self.start_motion(now);
        }
        self.refresh_live_registers(now);
    }

    // ----- physics -----

    /// Advance motion, current and temperature to `now` (no-op if `now` is not later than the last update).
    pub fn update(&mut self, now: Instant) {
        while self.last_update < now {
            self.finish_busy(self.last_update);
            let step = if self.driven(self.last_update) {
                MOVING_STEP
            } else if self.overheating {
                OVERHEAT_STEP
            } else {
                IDLE_STEP
            };
            let dt = step.min(now.saturating_duration_since(self.last_update));
            let t = self.last_update + dt;
            self.step_motion(t, dt);
            self.step_temperature(dt);
            self.check_temperature();
            self.last_update = t;
        }
        self.finish_busy(now);
        self.refresh_live_registers(now);
    }

    fn finish_busy(&mut self, now: Instant) {
        if let Some((until, kind)) = self.busy
            && now >= until
        {
            if kind == Busy::FlashWrite
                && let Some(rom) = self.pending_flash.take()
            {
                self.flash = rom;
                self.flash_error = false;
            }
            self.busy = None;
        }
    }

    /// Whether the rod is being driven toward a goal it has not reached (small integration steps).
    fn driven(&self, t: Instant) -> bool {
        if !self.powered || self.force() != Force::On {
            return false;
        }
        match self.motion {
            Some(motion) => {
                !motion.profile_done(t) || (self.rod_mm - motion.to_mm).abs() > f64::EPSILON
            }
            None => false,
        }
    }

    fn compliance_margin_mm(&self, rod_mm: f64, to_mm: f64) -> f64 {
        // Margins are set in logical coordinates: the "plus" margin is on the logical plus side of the goal.
        let logical_excess = f64::from(self.direction()) * (rod_mm - to_mm);
        let register = if logical_excess >= 0.0 {
            reg::PLUS_COMPLIANCE_MARGIN
        } else {
            reg::MINUS_COMPLIANCE_MARGIN
        };
        f64::from(self.map[register]) / 100.0
    }

    fn step_motion(&mut self, t: Instant, dt: Duration) {
        if !self.powered {
            self.current_a = 0.0;
            return;
        }
        let (Force::On, Some(motion)) = (self.force(), self.motion) else {
            self.current_a = physics::STANDING_CURRENT_A;
            return;
        };
        let drive = self.drive();
        let blocked = self.stalled || drive.overloaded();
        let rod_before = self.rod_mm;
        if !blocked {
            let reference = motion.reference_mm(t);
            let travel = drive.speed_mm_s() * dt.as_secs_f64();
            let error = reference - self.rod_mm;
            self.rod_mm = if error.abs() <= travel {
                reference
            } else {
                self.rod_mm + travel * error.signum()
            };
            self.rod_mm = self
                .rod_mm
                .clamp(-MECHANICAL_STROKE_MM, MECHANICAL_STROKE_MM);
        }
        let off_goal = (motion.to_mm - self.rod_mm).abs();
        let arrived = off_goal <= self.compliance_margin_mm(self.rod_mm, motion.to_mm);
        let at_end_stop =
            self.rod_mm.abs() >= MECHANICAL_STROKE_MM && motion.to_mm.abs() > MECHANICAL_STROKE_MM;
        self.current_a = if arrived && motion.profile_done(t) {
            drive.holding_current_a()
        } else if arrived {
            drive.moving_current_a()
        } else if blocked || at_end_stop {
            drive.stall_current_a()
        } else {
            drive.moving_current_a()
        };
        // Friction draws current in proportion to how fast the rod really moved in this step (and,
        // for the parts of it that act one way or on part of the stroke only, which way and where:
        // the middle of the step).
        let dt_s = dt.as_secs_f64();
        if dt_s > 0.0 {
            let velocity = (self.rod_mm - rod_before) / dt_s;
            let friction = self
                .wear
                .moving_friction_current_a((self.rod_mm + rod_before) / 2.0, velocity);
            self.current_a =
                (self.current_a + friction).min(drive.stall_current_a().max(self.current_a));
        }
    }

    fn step_temperature(&mut self, dt: Duration) {
        let power_w = self.current_a * self.voltage_v;
        self.temperature_c =
            physics::temperature_after(self.temperature_c, self.ambient_c, power_w, dt);
        if self.overheating && self.temperature_c < physics::OVERHEAT_CEILING_C {
            self.temperature_c = (self.temperature_c
                + physics::OVERHEAT_RATE_C_PER_S * dt.as_secs_f64())
            .min(physics::OVERHEAT_CEILING_C);
        }
    }

    /// At the temperature limit: error flag, force off, latched.
    fn check_temperature(&mut self) {
        if self.powered
            && self.temperature_register_c() >= self.temperature_limit_c()
            && !self.temperature_error
        {
            self.temperature_error = true;
            self.map[reg::FORCE_ENABLE] = 0;
            self.motion = None;
            self.current_a = physics::STANDING_CURRENT_A;
        }
    }

    fn present_time_ms10(&self, now: Instant) -> u16 {
        match self.motion {
            Some(motion) if !motion.goal_time.is_zero() => {
                let elapsed = now.saturating_duration_since(motion.started_at);
                if elapsed < motion.goal_time {
                    (elapsed.as_millis() / 10).min(u16::MAX.into()) as u16
                } else {
                    0
                }
            }
            _ => 0,
        }
    }

    fn refresh_live_registers(&mut self, now: Instant) {
        if !self.powered {
            return;
        }
        let present = physics::quantise_mm_centi(f64::from(self.direction()) * self.rod_mm);
        map::set_u16(&mut self.map, reg::PRESENT_POSITION, present as u16);
        let present_time = self.present_time_ms10(now);
        map::set_u16(&mut self.map, reg::PRESENT_TIME, present_time);
        let load_ma10 = (self.current_a * 100.0)
            .round()
            .clamp(0.0, f64::from(u16::MAX)) as u16;
        map::set_u16(&mut self.map, reg::PRESENT_LOAD, load_ma10);
        let temperature = self.temperature_register_c() as i16;
        map::set_u16(&mut self.map, reg::PRESENT_TEMPERATURE, temperature as u16);
        let voltage_mv10 = (self.voltage_v * 100.0)
            .round()
            .clamp(0.0, f64::from(u16::MAX)) as u16;
        map::set_u16(&mut self.map, reg::PRESENT_VOLTAGE, voltage_mv10);
    }

    /// A copy of the state at `now`.
    pub fn snapshot(&mut self, slot: usize, now: Instant) -> ServoSnapshot {
        self.update(now);
        ServoSnapshot {
            slot,
            id: self.id(),
            goal_mm: f32::from(map::get_i16(&self.map, reg::GOAL_POSITION)) / 100.0,
            position_mm: f32::from(map::get_i16(&self.map, reg::PRESENT_POSITION)) / 100.0,
            rod_mm: self.rod_mm as f32,
            current_a: self.current_a as f32,
            temperature_c: self.temperature_c as f32,
            ambient_c: self.ambient_c as f32,
            voltage_v: self.voltage_v as f32,
            force: self.force(),
            alarm: self.alarm(),
            error: self.temperature_error,
            flash_error: self.flash_error,
            online: self.powered,
            busy: self.busy_reason(now).is_some(),
            baud: self.baud(),
            registers: self.map,
            flash: self.flash,
            model_number: self.model_number,
            stalled: self.stalled,
            load_n: self.load_n as f32,
            overheating: self.overheating,
        }
    }
}
