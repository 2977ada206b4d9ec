//! `factory-reset`: restore registers 4–29 of one servo to the factory values.
//!
//! After the reset the servo is ID 1 at 115 200 bit/s. So the reset is refused while another
//! servo answers at ID 1 (at the current rate, or at 115 200 bit/s): the two would share an ID.
//! After the reset the servo is found at ID 1, 115 200 bit/s, its ROM area is compared with the
//! factory values, and it is written to flash (with the 1 s wait) so that the factory values
//! survive power-off whichever way the firmware stores a reset.

use super::link::Link;
use super::{CommissionError, FLASH_WAIT, REBOOT_WAIT, require_servo, scan};
use crate::protocol::registers::addr;
use crate::protocol::{BaudRate, Destination, MemoryMap, ReplyRequest, ServoId, ShortPacket};

/// The ID every servo has after a factory reset.
pub const FACTORY_ID: u8 = 1;

/// Factory values of the ROM area that a reset must restore, as (register, bytes, name).
/// Punch is left out: the manual contradicts itself about its default (spec 9.5).
pub const FACTORY_VALUES: &[(u8, &[u8], &str)] = &[
    (addr::SERVO_ID, &[0x01], "servo id"),
    (addr::REVERSE, &[0x00], "reverse"),
    (addr::BAUD_RATE, &[0x07], "baud rate"),
    (addr::RETURN_DELAY, &[0x00], "return delay"),
    (addr::PLUS_LIMIT, &[0xC4, 0x09], "plus position limit"),
    (addr::MINUS_LIMIT, &[0x3C, 0xF6], "minus position limit"),
    (addr::TEMPERATURE_LIMIT, &[0x55, 0x00], "temperature limit"),
    (
        addr::PLUS_COMPLIANCE_MARGIN,
        &[0x08],
        "plus compliance margin",
    ),
    (
        addr::MINUS_COMPLIANCE_MARGIN,
        &[0x08],
        "minus compliance margin",
    ),
    (
        addr::PLUS_COMPLIANCE_SLOPE,
        &[0x00],
        "plus compliance slope",
    ),
    (
        addr::MINUS_COMPLIANCE_SLOPE,
        &[0x00],
        "minus compliance slope",
    ),
];

/// What `factory-reset` did.
#[derive(Debug, Clone, PartialEq)]
pub struct ResetReport {
    pub id_before: ServoId,
    pub baud_before: BaudRate,
    pub id_after: ServoId,
    pub baud_after: BaudRate,
    /// Registers 0–29 after the reset.
    pub map_after: MemoryMap,
    pub notes: Vec<String>,
}

/// [`FACTORY_ID`] as a servo ID (checked when compiling).
pub const FACTORY_SERVO_ID: ServoId = match ServoId::new(FACTORY_ID) {
    Ok(id) => id,
    Err(_) => panic!("ID 1 is in 1–127"),
};

/// Check that servo `id` answers and that no other servo answers at ID 1. Writes nothing.
pub async fn preflight(link: &mut Link, id: ServoId) -> Result<MemoryMap, CommissionError> {
    let map = require_servo(link, id).await?;
    let one = FACTORY_SERVO_ID;
    let taken = |baud: BaudRate| CommissionError::Refused {
        reason: format!(
            "another servo already answers at ID 1 ({baud}); after the reset servo {id} would share ID 1 with it: give that servo another ID or disconnect it first"
        ),
    };
    if id != one && scan::id_answers(link, one).await? {
        return Err(taken(link.baud()));
    }
    let home = link.baud();
    if home != BaudRate::DEFAULT {
        link.reopen(BaudRate::DEFAULT).await?;
        let answered = scan::id_answers(link, one).await;
        link.reopen(home).await?;
        if answered? {
            return Err(taken(BaudRate::DEFAULT));
        }
    }
    Ok(map)
}

/// Factory-reset servo `id`; see the module docs.
pub async fn factory_reset(link: &mut Link, id: ServoId) -> Result<ResetReport, CommissionError> {
    preflight(link, id).await?;
    let baud_before = link.baud();
    let one = FACTORY_SERVO_ID;
    link.send(&ShortPacket::factory_reset(Destination::Servo(id)))
        .await?;
    tokio::time::sleep(FLASH_WAIT).await;
    link.forget(id.get());
    link.reopen(BaudRate::DEFAULT).await?;
    if !link.wait_for(one, REBOOT_WAIT).await? {
        return Err(CommissionError::Failed(format!(
            "after the factory reset servo {id} does not answer at ID 1, {}; power-cycle it and look for it with `lj9da-bridge scan --all-bauds`",
            BaudRate::DEFAULT
        )));
    }
    let read = |reply: crate::protocol::ReturnPacket| {
        let mut map = MemoryMap::default();
        map.store(reply.address, &reply.data);
        map
    };
    let map = read(link.read(one, ReplyRequest::Registers0To29).await?);
    for (address, bytes, name) in FACTORY_VALUES {
        let start = usize::from(*address);
        let got = map.bytes().get(start..start + bytes.len()).unwrap_or(&[]);
        if got != *bytes {
            return Err(CommissionError::Verify {
                id: one,
                what: format!("{name} after the factory reset"),
                expected: super::link::hex(bytes),
                got: super::link::hex(got),
                hint: String::new(),
            });
        }
    }
    link.send(&ShortPacket::write_flash(Destination::Servo(one)))
        .await?;
    tokio::time::sleep(FLASH_WAIT).await;
    let reply = link.read(one, ReplyRequest::Registers0To29).await?;
    if reply.flags.flash_write_error() {
        return Err(CommissionError::Failed(format!(
            "servo {one} reports a flash write error after the factory reset; run the reset again"
        )));
    }
    let map = read(reply);
    let mut notes = vec![format!(
        "servo {id} is now ID 1 at {} with the factory settings (saved to flash)",
        BaudRate::DEFAULT
    )];
    if id != one {
        notes.push(format!(
            "it no longer answers at ID {id}: give it its ID again with `lj9da-bridge set --id 1 id={id} --save`"
        ));
    }
    Ok(ResetReport {
        id_before: id,
        baud_before,
        id_after: one,
        baud_after: link.baud(),
        map_after: map,
        notes,
    })
}
