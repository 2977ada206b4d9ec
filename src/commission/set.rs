//! `set`: write settings to one servo, read every one back, and with `--save` keep them in flash.
//!
//! Order of work, so that a refusal writes nothing and each step is proven before the next:
//! 1. the servo must answer and be an LJ9DA41; every packet is built (and so validated) first;
//!    a new ID must be free on the bus (pinged); reversing is refused while force is on (the
//!    mirrored goal would make the rod jump);
//! 2. ordinary settings are written one acknowledged packet each, then read back and compared;
//! 3. a new ID is written (the servo answers at it at once) and read back at the new ID;
//! 4. a new baud rate is written at the old rate, the port reopened at the new rate, and the
//!    rate read back there;
//! 5. with `--save`: flash write, a wait of at least 1 s, reboot (never combined with the flash
//!    write, as the manual requires), wait for the servo to answer again, and compare every
//!    ROM-area setting once more. Max force lives in RAM: the flash write does not keep it and
//!    the reboot resets it, so it is written again after the reboot (until power-off).

use super::link::{Link, LinkError};
use super::settings::Setting;
use super::{CommissionError, FLASH_WAIT, REBOOT_WAIT, require_servo, scan};
use crate::protocol::{
    BaudRate, Destination, ForceMode, MemoryMap, ReplyFlags, ReplyRequest, ServoId, ShortPacket,
};
use std::time::Duration;

/// How `set` finishes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SetOptions {
    /// Write flash, reboot and verify that the values survived.
    pub save: bool,
}

/// One setting as it was and as it is now.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Change {
    pub key: &'static str,
    pub before: String,
    pub after: String,
}

/// What `set` did.
#[derive(Debug, Clone, PartialEq)]
pub struct SetReport {
    pub id_before: ServoId,
    pub id_after: ServoId,
    pub baud_before: BaudRate,
    pub baud_after: BaudRate,
    /// Every setting given, in register order, verified.
    pub changes: Vec<Change>,
    /// Flash written, servo rebooted and every ROM setting verified after the reboot.
    pub saved: bool,
    /// The servo's registers 0–29 (and 30–41) as last read.
    pub map_after: MemoryMap,
    /// What the user should know (what is lost at power-off, what the reboot reset).
    pub notes: Vec<String>,
}

async fn read_map(
    link: &mut Link,
    id: ServoId,
    with_ram: bool,
) -> Result<(MemoryMap, ReplyFlags), LinkError> {
    let mut map = MemoryMap::default();
    let rom = link.read(id, ReplyRequest::Registers0To29).await?;
    map.store(rom.address, &rom.data);
    let mut flags = rom.flags;
    if with_ram {
        let ram = link.read(id, ReplyRequest::Registers30To41).await?;
        map.store(ram.address, &ram.data);
        flags = ram.flags;
    }
    Ok((map, flags))
}

fn verify(
    id: ServoId,
    setting: &Setting,
    map: &MemoryMap,
    when: &str,
) -> Result<(), CommissionError> {
    if setting.holds_in(map) {
        Ok(())
    } else {
        Err(CommissionError::Verify {
            id,
            what: format!("{} {when}", setting.key()),
            expected: setting.value_text(),
            got: setting.read_text(map),
            hint: String::new(),
        })
    }
}

/// Apply `settings` to servo `id`; see the module docs.
pub async fn set(
    link: &mut Link,
    id: ServoId,
    settings: &[Setting],
    options: SetOptions,
) -> Result<SetReport, CommissionError> {
    if settings.is_empty() {
        return Err(CommissionError::Refused {
            reason: format!(
                "no settings given; give key=value pairs with keys: {}",
                super::settings::KEYS
            ),
        });
    }
    // 1. Nothing is written before every check has passed.
    let with_ram = settings.iter().any(|s| !s.in_flash());
    let mut before = require_servo(link, id).await?;
    match link.read(id, ReplyRequest::Registers30To41).await {
        Ok(ram) => before.store(ram.address, &ram.data),
        Err(LinkError::Timeout { .. }) => {
            return Err(CommissionError::NoServo {
                id,
                baud: link.baud(),
            });
        }
        Err(e) => return Err(e.into()),
    }
    let reverses = settings
        .iter()
        .any(|s| matches!(s, Setting::Reverse(r) if *r != before.reversed()));
    if reverses && before.force_mode() == Ok(ForceMode::On) {
        return Err(CommissionError::Refused {
            reason: format!(
                "servo {id} has force on: reversing it would mirror its goal and make the rod jump; switch force off first (`lj9da-bridge force --id {id} off`)"
            ),
        });
    }
    let baud_before = link.baud();
    let new_id = settings
        .iter()
        .find_map(|s| match s {
            Setting::Id(n) => Some(*n),
            _ => None,
        })
        .filter(|n| *n != id);
    let new_baud = settings
        .iter()
        .find_map(|s| match s {
            Setting::Baud(b) => Some(*b),
            _ => None,
        })
        .filter(|b| *b != baud_before);
    let final_id = new_id.unwrap_or(id);
    let mut plain: Vec<(Setting, ShortPacket)> = Vec::new();
    for s in settings {
        if !matches!(s, Setting::Id(_) | Setting::Baud(_)) {
            plain.push((*s, s.packet(id, ReplyRequest::Ack)?));
        }
    }
    let id_packet = new_id
        .map(|n| Setting::Id(n).packet(id, ReplyRequest::None))
        .transpose()?;
    let baud_packet = new_baud
        .map(|b| Setting::Baud(b).packet(final_id, ReplyRequest::None))
        .transpose()?;
    if let Some(n) = new_id
        && scan::id_answers(link, n).await?
    {
        return Err(CommissionError::IdTaken {
            new: n,
            baud: baud_before,
        });
    }

    // 2. Ordinary settings, acknowledged, then read back.
    for (setting, packet) in &plain {
        link.transact(packet).await?;
        if let Setting::ReturnDelay(ms) = setting {
            link.learn_return_delay(id.get(), Duration::from_millis(u64::from(*ms)));
        }
    }
    let mut after = before.clone();
    if !plain.is_empty() {
        let (map, _) = read_map(link, id, with_ram).await?;
        after = map;
        for (setting, _) in &plain {
            verify(id, setting, &after, "after writing")?;
        }
    }

    // 3. The ID: the servo answers at the new ID as soon as it has the packet.
    if let (Some(packet), Some(n)) = (&id_packet, new_id) {
        link.send(packet).await?;
        link.learn_return_delay(n.get(), link.return_delay(id.get()));
        link.forget(id.get());
        let map = match read_map(link, n, with_ram).await {
            Ok((map, _)) => map,
            Err(LinkError::Timeout { .. }) => {
                return Err(CommissionError::Verify {
                    id,
                    what: "the ID".into(),
                    expected: format!("an answer at ID {n}"),
                    got: "no answer".into(),
                    hint: format!(
                        " (the servo may still be at ID {id}; check with `lj9da-bridge scan`)"
                    ),
                });
            }
            Err(e) => return Err(e.into()),
        };
        after = map;
        verify(n, &Setting::Id(n), &after, "at its new ID")?;
    }

    // 4. The baud rate: written at the old rate, proven at the new one.
    if let (Some(packet), Some(b)) = (&baud_packet, new_baud) {
        link.send(packet).await?;
        link.reopen(b).await?;
        let map = match read_map(link, final_id, with_ram).await {
            Ok((map, _)) => map,
            Err(LinkError::Timeout { .. }) => {
                return Err(CommissionError::Verify {
                    id: final_id,
                    what: "the baud rate".into(),
                    expected: format!("an answer at {b}"),
                    got: "no answer".into(),
                    hint: " (find the servo with `lj9da-bridge scan --all-bauds`)".into(),
                });
            }
            Err(e) => return Err(e.into()),
        };
        after = map;
        verify(final_id, &Setting::Baud(b), &after, "at the new rate")?;
    }

    let mut notes = Vec::new();
    let mut saved = false;
    if options.save {
        after = save_and_reboot(link, final_id, settings, with_ram, &mut notes).await?;
        saved = true;
    } else {
        notes.push(
            "not saved: the new values are in the servo's RAM and are lost at power-off (run again with --save to keep them)"
                .into(),
        );
    }
    if with_ram && options.save {
        notes.push(
            "max force lives in RAM: the flash write does not keep it; it was written again after the reboot and lasts until power-off"
                .into(),
        );
    }

    let changes = settings
        .iter()
        .map(|s| Change {
            key: s.key(),
            before: s.read_text(&before),
            after: s.read_text(&after),
        })
        .collect();
    Ok(SetReport {
        id_before: id,
        id_after: final_id,
        baud_before,
        baud_after: link.baud(),
        changes,
        saved,
        map_after: after,
        notes,
    })
}

/// Flash write, wait, reboot, wait for the servo, verify every ROM setting, restore RAM ones.
async fn save_and_reboot(
    link: &mut Link,
    id: ServoId,
    settings: &[Setting],
    with_ram: bool,
    notes: &mut Vec<String>,
) -> Result<MemoryMap, CommissionError> {
    let dest = Destination::Servo(id);
    link.send(&ShortPacket::write_flash(dest)).await?;
    tokio::time::sleep(FLASH_WAIT).await;
    link.send(&ShortPacket::reboot(dest)).await?;
    if !link.wait_for(id, REBOOT_WAIT).await? {
        return Err(CommissionError::Failed(format!(
            "servo {id} did not answer within {} s of its reboot at {}; power-cycle it and check with `lj9da-bridge scan --all-bauds`",
            REBOOT_WAIT.as_secs(),
            link.baud()
        )));
    }
    let (mut map, flags) = read_map(link, id, false).await?;
    if flags.flash_write_error() {
        return Err(CommissionError::Failed(format!(
            "servo {id} reports a flash write error after saving; its settings may not survive power-off: run `set … --save` again"
        )));
    }
    for setting in settings.iter().filter(|s| s.in_flash()) {
        verify(id, setting, &map, "after flash write and reboot").map_err(|e| match e {
            CommissionError::Verify {
                id,
                what,
                expected,
                got,
                ..
            } => CommissionError::Verify {
                id,
                what,
                expected,
                got,
                hint: " (the flash write did not keep it)".into(),
            },
            other => other,
        })?;
    }
    notes.push(format!(
        "saved to flash and rebooted: servo {id} came back at {} with every setting; the reboot switched force off",
        link.baud()
    ));
    if with_ram {
        for setting in settings.iter().filter(|s| !s.in_flash()) {
            link.transact(&setting.packet(id, ReplyRequest::Ack)?)
                .await?;
        }
        let ram = link.read(id, ReplyRequest::Registers30To41).await?;
        map.store(ram.address, &ram.data);
        for setting in settings.iter().filter(|s| !s.in_flash()) {
            verify(id, setting, &map, "after the reboot")?;
        }
    }
    Ok(map)
}
