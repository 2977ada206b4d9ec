use super::*;

#[test]
fn varints_round_trip_and_refuse_overflow() {
    for v in [0, 1, 127, 128, 300, u64::from(u32::MAX), u64::MAX] {
        let mut out = Vec::new();
        put_varint(&mut out, v);
        assert_eq!(get_varint(&out), Some((v, out.len())));
    }
    assert_eq!(get_varint(&[0xFF; 10]), None);
    assert_eq!(get_varint(&[0x80]), None);
    assert_eq!(
        get_varint(&[0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02]),
        None
    );
}

#[test]
fn a_telemetry_record_is_laid_out_as_documented() {
    let record = Record {
        t_us: 300,
        body: RecordBody::Telemetry {
            servo: 2,
            telemetry: Telemetry {
                present_position: MmCenti(-100),
                present_time: Ms10(3),
                present_load: Ma10(45),
                present_temperature: Celsius(31),
                present_voltage: Mv10(1200),
            },
            flags: ReplyFlags(0x20),
        },
    };
    let mut out = Vec::new();
    let n = encode_record(&record, &mut out);
    assert_eq!(n, out.len());
    let expected_inner = [
        15, 0, // len: kind 1 + t 2 + payload 12
        2, // kind
        0xAC, 0x02, // 300 as LEB128
        2, 0x20, // servo, flags
        0x9C, 0xFF, // -100
        3, 0, 45, 0, 31, 0, 0xB0, 0x04,
    ];
    assert_eq!(out.get(..17), Some(&expected_inner[..]));
    assert_eq!(
        out.get(17..),
        Some(&crc32(&expected_inner).to_le_bytes()[..])
    );
    assert_eq!(decode_record(&out), Decoded::Record { record, len: 21 });
}

#[test]
fn a_motion_record_is_a_position_record_with_two_words_more() {
    let motion = Record {
        t_us: 300,
        body: RecordBody::Motion {
            servo: 2,
            motion: Motion {
                present_position: MmCenti(-100),
                present_time: Ms10(3),
                present_load: Ma10(45),
            },
            flags: ReplyFlags(0x20),
        },
    };
    let mut out = Vec::new();
    let n = encode_record(&motion, &mut out);
    let expected_inner = [
        11, 0, // len: kind 1 + t 2 + payload 8
        7, // kind: position
        0xAC, 0x02, // 300 as LEB128
        2, 0x20, // servo, flags
        0x9C, 0xFF, // -100
        3, 0, 45, 0, // present time, present load
    ];
    assert_eq!(out.get(..13), Some(&expected_inner[..]));
    assert_eq!(
        decode_record(&out),
        Decoded::Record {
            record: motion,
            len: n
        }
    );
    // Its first 4 payload bytes are the position record a reader of 1.1 or 1.2 takes it
    // for (such a reader ignores the rest).
    let position = Record {
        t_us: 300,
        body: RecordBody::Position {
            servo: 2,
            position: MmCenti(-100),
            flags: ReplyFlags(0x20),
        },
    };
    let mut short = Vec::new();
    encode_record(&position, &mut short);
    assert_eq!(short.get(2..9), out.get(2..9));
}

#[test]
fn unknown_kinds_with_a_good_crc_are_skippable() {
    let mut bytes = vec![3, 0, 10, 0, 0xAA];
    let crc = crc32(&bytes);
    bytes.extend_from_slice(&crc.to_le_bytes());
    assert_eq!(
        decode_record(&bytes),
        Decoded::Unsupported {
            what: "records of kind 10".into(),
            len: 9
        }
    );
}

#[test]
fn header_round_trips_and_names_are_cut_at_char_boundaries() {
    let long = "é".repeat(200);
    let h = RecordHeader::new(
        1_700_000_000_000_000_000,
        vec![
            RecordServo::new("aileron_left", "wing", 1, 1),
            RecordServo::new(long.clone(), "b", 127, 32),
        ],
    );
    let bytes = encode_header(&h);
    let (back, len) = decode_header(&bytes).unwrap();
    assert_eq!(len, bytes.len());
    assert_eq!(back.servos[0], h.servos[0]);
    assert_eq!(back.servos[1].name, "é".repeat(127));
    assert_eq!(back.run_start_unix_ns, h.run_start_unix_ns);
}

#[test]
fn the_aircraft_round_trips_from_1_4_and_an_empty_name_is_none() {
    let servos = vec![RecordServo::new("elevator", "tail", 3, 3)];
    let h = RecordHeader::new(1, servos.clone()).with_aircraft(Some("VH-LJ9 #2"));
    let (back, _) = decode_header(&encode_header(&h)).unwrap();
    assert_eq!(back.aircraft.as_deref(), Some("VH-LJ9 #2"));
    assert_eq!(back, h);
    let none = RecordHeader::new(1, servos.clone()).with_aircraft(Some(""));
    assert_eq!(none.aircraft, None);
    assert_eq!(
        decode_header(&encode_header(&none)).unwrap().0.aircraft,
        None
    );
    // A 1.3 header has no aircraft: what follows its servo table is not read as one.
    let mut old = RecordHeader::new(1, servos).with_aircraft(Some("VH-LJ9"));
    old.version = (1, 3);
    let (back, _) = decode_header(&encode_header(&old)).unwrap();
    assert_eq!(back.aircraft, None);
    assert_eq!(back.servos, old.servos);
}

#[test]
fn the_autopilot_clock_round_trips_and_an_unknown_width_is_skipped() {
    for (time_usec, bits) in [(4_294_967_295, 32), (u64::MAX, 64), (0, 64)] {
        let record = Record {
            t_us: 12_345_678,
            body: RecordBody::AutopilotClock { time_usec, bits },
        };
        let mut bytes = Vec::new();
        let len = encode_record(&record, &mut bytes);
        assert_eq!(decode_record(&bytes), Decoded::Record { record, len });
    }
    let mut bytes = Vec::new();
    encode_record(
        &Record {
            t_us: 1,
            body: RecordBody::AutopilotClock {
                time_usec: 7,
                bits: 16,
            },
        },
        &mut bytes,
    );
    assert!(
        matches!(&decode_record(&bytes), Decoded::Unsupported { what, .. } if what.contains("16 bits")),
        "{:?}",
        decode_record(&bytes)
    );
}

#[test]
fn header_errors() {
    assert_eq!(decode_header(b"PK\x03\x04"), Err(HeaderError::NotARecord));
    assert!(matches!(
        decode_header(b""),
        Err(HeaderError::Truncated { len: 0, .. })
    ));
    let mut bytes = encode_header(&RecordHeader::new(0, vec![]));
    assert!(matches!(
        decode_header(&bytes[..20]),
        Err(HeaderError::Truncated { len: 20, .. })
    ));
    bytes[8] = 2;
    bytes[10] = 1;
    let e = decode_header(&bytes).unwrap_err();
    assert_eq!(e, HeaderError::UnsupportedVersion { major: 2, minor: 1 });
    assert!(e.to_string().contains("format 2.1"));
    bytes[8] = 1;
    bytes[10] = VERSION_MINOR as u8;
    bytes[20] ^= 1;
    assert!(matches!(
        decode_header(&bytes),
        Err(HeaderError::Damaged(_))
    ));
}
