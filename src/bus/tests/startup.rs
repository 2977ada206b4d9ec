//! Start-up, before the first goal: each servo's identity, RAM and telemetry are read and force
//! is left OFF; a configured max force is written (and left alone when not configured); a
//! servo of another model is refused and never commanded; a servo that does not answer at
//! start-up is reported lost.

use super::*;

#[test]
fn startup_reads_identity_ram_and_telemetry_and_leaves_force_off() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.servo(2).reverse = 1;
    rig.servo(2).plus = 2000;
    rig.servo(2).minus = -1500;
    rig.servo(2).return_delay_ms = 1;
    rig.run(ms(100));
    let kinds = rig.kinds_since(0);
    let of = |n: u8| -> Vec<Vec<u8>> {
        rig.log
            .iter()
            .filter(|s| s.tx.bytes[2] == n)
            .map(|s| s.tx.bytes.clone())
            .take(3)
            .collect()
    };
    // Registers 0–29, then 30–41, then 42–59.
    assert_eq!(of(1)[0], vec![0xFA, 0xAF, 1, 0x03, 0, 0, 1, 0x03]);
    assert_eq!(of(1)[1], vec![0xFA, 0xAF, 1, 0x0B, 0, 0, 1, 0x0B]);
    assert_eq!(of(1)[2], vec![0xFA, 0xAF, 1, 0x09, 0, 0, 1, 0x09]);
    assert!(
        kinds
            .iter()
            .all(|k| !matches!(k, TxKind::Force(_) | TxKind::Command))
    );
    let st = rig.m.status();
    let s2 = st.servo(id(2)).unwrap();
    assert_eq!(s2.health, Health::Online);
    assert_eq!(s2.identity.model, Some(0x7510));
    assert_eq!(s2.identity.firmware, Some(3));
    assert_eq!(s2.identity.reversed, Some(true));
    assert_eq!(s2.identity.return_delay, Some(ms(1)));
    assert_eq!(
        s2.identity.limits.map(|l| (l.minus(), l.plus())),
        Some((MmCenti(-1500), MmCenti(2000)))
    );
    assert_eq!(s2.force, ForceState::Off);
    assert!(rig.events.contains(&BusEvent::ServoOnline { id: id(1) }));
    assert!(rig.events.contains(&BusEvent::ServoOnline { id: id(2) }));
    assert_eq!(rig.servo(1).force, 0, "no force before the first goal");
}

#[test]
fn max_force_is_written_at_startup_when_configured() {
    let mut cfg = config(&[1]);
    cfg.servos[0].max_force = Some(Percent::new(80).unwrap());
    let mut rig = Rig::new(cfg);
    rig.run(ms(50));
    assert_eq!(rig.servo(1).max_force, 80);
    let mut cfg = config(&[1]);
    cfg.servos[0].max_force = None;
    let mut rig = Rig::new(cfg);
    rig.servo(1).max_force = 55;
    rig.run(ms(50));
    assert_eq!(rig.servo(1).max_force, 55, "left alone when not configured");
}

#[test]
fn a_different_model_is_refused_and_never_commanded() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.servo(2).model = 0x1234;
    rig.run(ms(100));
    assert_eq!(rig.health(2), Health::WrongModel);
    assert!(rig.events.contains(&BusEvent::WrongModel {
        id: id(2),
        found: 0x1234
    }));
    assert_eq!(
        BusEvent::WrongModel {
            id: id(2),
            found: 0x1234
        }
        .to_string(),
        "servo 2 is model 0x1234, not an LJ9DA41 (0x7510): not commanded"
    );
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(50)));
    rig.set_goal(2, Goal::Position(MmCenti(50)));
    rig.run(ms(500));
    assert!(rig.sent_since(from).iter().all(|s| s.tx.bytes[2] != 2));
    assert!(
        rig.commands_since(from)
            .iter()
            .all(|c| c.iter().all(|e| e.0 != 2))
    );
    assert_eq!(rig.servo(2).force, 0);
    assert_eq!(rig.servo(1).position, 50);
}

#[test]
fn a_servo_missing_at_startup_is_reported_lost() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.servo(2).present = false;
    rig.run(ms(500));
    assert_eq!(rig.health(2), Health::Offline);
    assert!(rig.events.contains(&BusEvent::ServoLost { id: id(2) }));
    assert_eq!(rig.health(1), Health::Online);
}
