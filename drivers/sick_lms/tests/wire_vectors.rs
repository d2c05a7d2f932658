//! Every test vector of spec §1.1 (and the telegram examples of §2–§3), byte-exact both ways:
//! parse gives the typed message, emit gives back the same bytes.

use ima_sick_lms::wire::*;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// `body` + its CRC, low byte first.
fn with_crc(body: &[u8]) -> Vec<u8> {
    let mut v = body.to_vec();
    v.extend_from_slice(&crc16(body).to_le_bytes());
    v
}

fn emit_cmd(c: &Command) -> Vec<u8> {
    let mut buf = [0u8; 64];
    let n = c.emit(&mut buf).unwrap();
    assert_eq!(n, c.buffer_len());
    buf[..n].to_vec()
}

fn emit_reply_from(r: &Reply<'_>, addr: u8) -> Vec<u8> {
    let mut buf = [0u8; MAX_TELEGRAM];
    let n = r.emit_from(addr, &mut buf).unwrap();
    buf[..n].to_vec()
}

/// Check a command vector: CRC register, wire bytes, parse and emit.
fn check_cmd(body_hex: &str, crc: u16, expected: Command) {
    let body = hex(body_hex);
    assert_eq!(crc16(&body), crc, "CRC of {body_hex}");
    let tele = with_crc(&body);
    assert_eq!(&tele[tele.len() - 2..], &crc.to_le_bytes());
    assert_eq!(Command::parse(&tele).unwrap(), expected, "parse {body_hex}");
    assert_eq!(emit_cmd(&expected), tele, "emit {body_hex}");
}

#[test]
fn crc_check_value() {
    assert_eq!(crc16(b"123456789"), 0xA656);
    assert_eq!(0xA656u16.to_le_bytes(), [0x56, 0xA6]);
    assert_eq!(crc16(&[]), 0);
}

#[test]
fn mode_change_vectors() {
    check_cmd(
        "02 00 02 00 20 25",
        0x0835,
        Command::SetMode(ModeRequest::RequestOnly),
    );
    check_cmd(
        "02 00 02 00 20 24",
        0x0834,
        Command::SetMode(ModeRequest::StreamAll),
    );
    for (code, crc, b) in [
        ("40", 0x0850, BaudRate::B38400),
        ("41", 0x0851, BaudRate::B19200),
        ("42", 0x0852, BaudRate::B9600),
        ("48", 0x0858, BaudRate::B500000),
    ] {
        check_cmd(
            &format!("02 00 02 00 20 {code}"),
            crc,
            Command::SetMode(ModeRequest::Baud(b)),
        );
    }
    check_cmd(
        "02 00 0A 00 20 00 53 49 43 4B 5F 4C 4D 53",
        0xC5BE,
        Command::SetMode(ModeRequest::Installation {
            password: DEFAULT_PASSWORD,
        }),
    );
}

#[test]
fn simple_request_vectors() {
    check_cmd("02 00 01 00 31", 0x1215, Command::Status);
    check_cmd("02 00 01 00 3A", 0x121E, Command::Type);
    check_cmd("02 00 01 00 74", 0x1250, Command::ReadConfig);
    check_cmd("02 00 01 00 10", 0x1234, Command::Reset);
    check_cmd("02 00 02 00 30 01", 0x1831, Command::one_scan());
    // QM example, full telegram.
    assert_eq!(
        emit_cmd(&Command::one_scan()),
        hex("02 00 02 00 30 01 31 18")
    );
    // OVB checksum test: 30 with data 00 01.
    check_cmd(
        "02 00 03 00 30 00 01",
        0x3871,
        Command::RequestValues {
            sub: 0,
            params: Params::from_slice(&[1]).unwrap(),
        },
    );
}

#[test]
fn variant_request_vectors() {
    for (h, crc, a, r) in [
        ("B4 00 32 00", 0x1F3B, 180, 50),
        ("B4 00 64 00", 0x4997, 180, 100),
        ("64 00 19 00", 0x72E7, 100, 25),
    ] {
        check_cmd(
            &format!("02 00 05 00 3B {h}"),
            crc,
            Command::Variant {
                angle_deg: a,
                res_centideg: r,
            },
        );
    }
}

#[test]
fn mode_reply_at_80_and_81() {
    let body = hex("02 80 03 00 A0 00 10");
    assert_eq!(crc16(&body), 0x0A16);
    let tele = with_crc(&body);
    assert_eq!(&tele[7..], &[0x16, 0x0A]);
    let r = Reply::parse(&tele).unwrap();
    assert_eq!(
        r,
        Reply::ModeChanged {
            result: 0,
            status: StatusByte(0x10)
        }
    );
    assert_eq!(emit_reply_from(&r, 0x80), tele);
    // QM units answer at 0x81.
    let tele81 = hex("02 81 03 00 A0 00 10 36 1A");
    assert_eq!(Reply::parse(&tele81).unwrap(), r);
    assert_eq!(emit_reply_from(&r, 0x81), tele81);
}

#[test]
fn reset_confirmation() {
    let tele = hex("02 80 02 00 91 10 79 30");
    assert_eq!(crc16(&tele[..6]), 0x3079);
    let r = Reply::parse(&tele).unwrap();
    assert_eq!(
        r,
        Reply::ResetAck {
            status: StatusByte(0x10)
        }
    );
    assert_eq!(emit_reply_from(&r, 0x80), tele);
}

#[test]
fn power_on_telegram_qm() {
    let mut body = hex("02 81 17 00 90");
    body.extend_from_slice(b"LMS200;301063;V02.06 ");
    body.push(0x13);
    assert_eq!(crc16(&body), 0x5A64);
    let tele = with_crc(&body);
    assert_eq!(&tele[tele.len() - 2..], &[0x64, 0x5A]);
    let r = Reply::parse(&tele).unwrap();
    let Reply::PowerOn { text, status } = r else {
        panic!("{r:?}")
    };
    assert_eq!(text, b"LMS200;301063;V02.06 ");
    assert_eq!(status, StatusByte(0x13));
    assert_eq!(status.severity(), Severity::Error);
    assert_eq!(emit_reply_from(&r, 0x81), tele);
}

#[test]
fn variant_reply_synthetic() {
    let body = hex("02 80 07 00 BB 01 B4 00 32 00 10");
    assert_eq!(crc16(&body), 0x9D03);
    let tele = with_crc(&body);
    let r = Reply::parse(&tele).unwrap();
    assert_eq!(
        r,
        Reply::Variant {
            accepted: 1,
            angle_deg: 180,
            res_centideg: 50,
            status: StatusByte::NORMAL
        }
    );
    assert_eq!(emit_reply_from(&r, 0x80), tele);
}

#[test]
fn three_values_in_mm() {
    let body = hex("02 80 0A 00 B0 03 40 E8 03 D0 07 FF 1F 10");
    assert_eq!(crc16(&body), 0xB116);
    let tele = with_crc(&body);
    assert_eq!(&tele[tele.len() - 2..], &[0x16, 0xB1]);
    let Reply::Scan(s) = Reply::parse(&tele).unwrap() else {
        panic!()
    };
    assert_eq!(s.count_word.count(), 3);
    assert_eq!(s.count_word.units(), Units::Mm);
    assert_eq!(
        s.values.iter().collect::<Vec<_>>(),
        vec![1000, 2000, 0x1FFF]
    );
    assert_eq!(s.indices, None);
    let words = [1000u16, 2000, 0x1FFF];
    let built = Scan::full(&words, Units::Mm, StatusByte::NORMAL);
    assert_eq!(built, s);
    assert_eq!(emit_reply_from(&Reply::Scan(built), 0x80), tele);
}

fn big_scan(count_word: u16, n: usize, len: [u8; 2], crc: [u8; 2], total: usize) {
    let words = vec![1000u16; n];
    let s = Scan {
        count_word: CountWord(count_word),
        values: Values::Words(&words),
        indices: None,
        status: StatusByte::NORMAL,
    };
    let tele = emit_reply_from(&Reply::Scan(s), 0x80);
    assert_eq!(tele.len(), total);
    assert_eq!(&tele[2..4], &len);
    assert_eq!(&tele[tele.len() - 2..], &crc);
    assert_eq!(
        &tele[4..7],
        &[0xB0, count_word as u8, (count_word >> 8) as u8]
    );
    assert!(tele[7..7 + 2 * n].chunks(2).all(|c| c == [0xE8, 0x03]));
    let Reply::Scan(p) = Reply::parse(&tele).unwrap() else {
        panic!()
    };
    assert_eq!(p, s);
    assert_eq!(p.count_word.count() as usize, n);
    assert_eq!(p.count_word.units(), Units::Mm);
    assert!(!p.count_word.partial());
}

#[test]
fn b0_361_values() {
    big_scan(0x4169, 361, [0xD6, 0x02], [0x55, 0xF1], 732);
}

#[test]
fn b0_181_values() {
    big_scan(0x40B5, 181, [0x6E, 0x01], [0x95, 0x6D], 372);
}

#[test]
fn b0_with_realtime_indices_and_flags() {
    let words = [0x2005u16, 0xE001];
    let s = Scan {
        count_word: CountWord(2 | 0x2000 | (3 << 11) | 0x0400),
        values: Values::Words(&words),
        indices: Some((7, 200)),
        status: StatusByte(0x90),
    };
    let tele = emit_reply_from(&Reply::Scan(s), 0x80);
    assert_eq!(tele.len(), 2 * 2 + 12);
    let Reply::Scan(p) = Reply::parse(&tele).unwrap() else {
        panic!()
    };
    assert_eq!(p, s);
    assert!(p.count_word.partial());
    assert_eq!(p.count_word.partial_index(), 3);
    assert!(p.count_word.reserved_bit());
    assert_eq!(p.count_word.raw_flags(), 0x3C00);
    assert!(p.status.pollution());
    assert!(!p.status.is_error());
}

#[test]
fn status_byte_rules() {
    let s = StatusByte(0x10);
    assert_eq!(s.severity(), Severity::Ok);
    assert!(!s.is_error() && !s.pollution());
    assert_eq!(s.device_type(), 2);
    assert_eq!(StatusByte(0x13).severity(), Severity::Error);
    assert_eq!(StatusByte(0x12).severity(), Severity::Warning);
    assert!(!StatusByte(0x12).is_error());
    assert_eq!(StatusByte(0x14).severity(), Severity::Fatal);
    assert_eq!(StatusByte(0x17).severity(), Severity::Reserved(7));
    let p = StatusByte(0xF8);
    assert!(p.pollution() && p.implausible() && p.restart());
    assert_eq!(p.severity(), Severity::Ok, "nonzero byte is not an error");
}

#[test]
fn status_block_fields() {
    let mut b = StatusBlockBuf::default();
    b.set_variant(100, 25);
    b.set_baud(BaudRate::B38400);
    b.set_measuring_mode(MeasuringMode(3));
    b.set_device_status(0);
    b.set_operating_mode(0x25);
    b.set_units(1);
    b.0[..7].copy_from_slice(b"V02.10 ");
    let r = Reply::Status {
        block: b.view(),
        status: StatusByte::NORMAL,
    };
    let tele = emit_reply_from(&r, 0x80);
    assert_eq!(tele.len(), 152 + 8);
    assert_eq!(&tele[4..5], &[0xB1]);
    // Offsets count B1 as 0: B1 is telegram byte 4.
    assert_eq!(&tele[4 + 107..4 + 111], &[100, 0, 25, 0]);
    assert_eq!(&tele[4 + 116..4 + 118], &[0x19, 0x80]);
    let Reply::Status { block, .. } = Reply::parse(&tele).unwrap() else {
        panic!()
    };
    assert_eq!(block.scan_angle_deg(), Some(100));
    assert_eq!(block.resolution_centideg(), Some(25));
    assert_eq!(block.baud(), Some(BaudRate::B38400));
    assert_eq!(block.baud_code(), Some(0x8019));
    assert_eq!(block.measuring_mode(), Some(MeasuringMode(3)));
    assert_eq!(block.operating_mode(), Some(0x25));
    assert_eq!(block.device_status(), Some(0));
    assert_eq!(block.units(), Some(1));
    assert_eq!(block.firmware(), Some(&b"V02.10 "[..]));
    assert_eq!(block.permanent_baud(), Some(0));
    // A short block reads as None past its end.
    let short = StatusBlock(&[1, 2, 3]);
    assert_eq!(short.device_status(), None);
    assert_eq!(short.operating_mode(), None);
}

#[test]
fn config_read_and_write_both_forms() {
    for long in [false, true] {
        let mut cfg = LmsConfig::zeroed(long);
        cfg.set_availability(2);
        cfg.set_measuring_mode(MeasuringMode(0));
        cfg.set_units(1);
        let n = if long { 34 } else { 32 };
        assert_eq!(cfg.as_bytes().len(), n);
        // 77 command
        let tele = emit_cmd(&Command::WriteConfig(cfg));
        assert_eq!(tele.len(), n + 7);
        assert_eq!(u16::from_le_bytes([tele[2], tele[3]]) as usize, n + 1);
        assert_eq!(Command::parse(&tele).unwrap(), Command::WriteConfig(cfg));
        // F4 and F7 replies
        for r in [
            Reply::Config {
                config: cfg,
                status: StatusByte::NORMAL,
            },
            Reply::ConfigWritten {
                result: 1,
                config: cfg,
                status: StatusByte::NORMAL,
            },
        ] {
            let t = emit_reply_from(&r, 0x80);
            assert_eq!(Reply::parse(&t).unwrap(), r);
        }
        let t = emit_reply_from(
            &Reply::Config {
                config: cfg,
                status: StatusByte::NORMAL,
            },
            0x80,
        );
        assert_eq!(t.len(), n + 8, "CAR accepts 40 or 42-byte F4 telegrams");
    }
    assert_eq!(
        LmsConfig::from_bytes(&[0; 33]),
        Err(WireError::InvalidField)
    );
}

#[test]
fn type_errors_and_rejection() {
    let r = Reply::Type {
        text: b"LMS200;30106",
        status: StatusByte::NORMAL,
    };
    let t = emit_reply_from(&r, 0x80);
    assert_eq!(Reply::parse(&t).unwrap(), r);
    let raw = [1u8, 2, 3, 4];
    let r = Reply::Errors {
        pairs: ErrorPairs::new(&raw).unwrap(),
        status: StatusByte::NORMAL,
    };
    let t = emit_reply_from(&r, 0x80);
    let Reply::Errors { pairs, .. } = Reply::parse(&t).unwrap() else {
        panic!()
    };
    assert_eq!(pairs.iter().collect::<Vec<_>>(), vec![(1, 2), (3, 4)]);
    // (LEN - 2) / 2 pairs
    assert_eq!(
        pairs.len(),
        (usize::from(u16::from_le_bytes([t[2], t[3]])) - 2) / 2
    );
    // 92 S (the spec's assumed layout)
    let t = with_crc(&hex("02 80 02 00 92 10"));
    assert_eq!(
        Reply::parse(&t).unwrap(),
        Reply::Rejected {
            data: &[],
            status: StatusByte::NORMAL
        }
    );
    // odd error-pair payload is malformed
    let t = with_crc(&hex("02 80 03 00 B2 01 10"));
    assert!(matches!(
        Reply::parse(&t),
        Err(WireError::BadPayload { code: 0xB2, .. })
    ));
}

#[test]
fn errors_are_typed() {
    let good = hex("02 80 02 00 91 10 79 30");
    let mut bad = good.clone();
    bad[6] ^= 1;
    assert_eq!(
        Reply::parse(&bad),
        Err(WireError::BadChecksum {
            expected: 0x3079,
            got: 0x3078
        })
    );
    assert_eq!(Reply::parse(&good[..5]), Err(WireError::Truncated));
    let mut x = good.clone();
    x[0] = 0x03;
    assert_eq!(Reply::parse(&x), Err(WireError::BadStx(3)));
    assert_eq!(
        Reply::parse(&with_crc(&hex("02 80 00 00"))),
        Err(WireError::BadLength(0))
    );
    assert_eq!(
        Reply::parse(&with_crc(&hex("02 80 29 03 B0"))),
        Err(WireError::BadLength(809))
    );
    // A command address in a reply, and vice versa.
    assert_eq!(
        Reply::parse(&hex("02 00 02 00 20 25 35 08")),
        Err(WireError::BadAddress(0))
    );
    assert_eq!(Command::parse(&good), Err(WireError::BadAddress(0x80)));
    assert_eq!(
        Reply::parse(&with_crc(&hex("02 80 02 00 C4 10"))),
        Err(WireError::UnknownCommand(0xC4))
    );
    assert_eq!(
        Command::parse(&with_crc(&hex("02 00 01 00 66"))),
        Err(WireError::UnknownCommand(0x66)),
        "the permanent-baud command is not even typed"
    );
    // B0 whose count disagrees with LEN
    assert!(matches!(
        Reply::parse(&with_crc(&hex("02 80 08 00 B0 03 40 E8 03 D0 07 10"))),
        Err(WireError::CountMismatch { count: 3, .. })
    ));
    // Extra byte after a fixed-size reply
    assert!(matches!(
        Reply::parse(&with_crc(&hex("02 80 04 00 A0 00 00 10"))),
        Err(WireError::BadPayload { code: 0xA0, .. })
    ));
    // Output buffer too small
    let mut small = [0u8; 7];
    assert_eq!(
        Command::one_scan().emit(&mut small),
        Err(WireError::BufferTooSmall)
    );
    // Other never carries a typed code
    let c = Command::SetMode(ModeRequest::Other {
        code: 0x24,
        params: Params::new(),
    });
    assert_eq!(c.emit(&mut [0u8; 32]), Err(WireError::InvalidField));
}

#[test]
fn reply_codes_follow_request_plus_0x80() {
    assert_eq!(expected_reply(cmd::SET_MODE), reply::MODE);
    assert_eq!(expected_reply(cmd::REQUEST_VALUES), reply::SCAN);
    assert_eq!(expected_reply(cmd::STATUS), reply::STATUS);
    assert_eq!(expected_reply(cmd::ERRORS), reply::ERRORS);
    assert_eq!(expected_reply(cmd::TYPE), reply::TYPE);
    assert_eq!(expected_reply(cmd::VARIANT), reply::VARIANT);
    assert_eq!(expected_reply(cmd::READ_CONFIG), reply::CONFIG);
    assert_eq!(expected_reply(cmd::WRITE_CONFIG), reply::CONFIG_WRITTEN);
    assert_eq!(expected_reply(cmd::RESET), reply::RESET_ACK);
}

#[test]
fn baud_codes() {
    for b in BaudRate::PROBE_ORDER {
        assert_eq!(BaudRate::from_bps(b.bps()), Some(b));
        assert_eq!(BaudRate::from_mode_code(b.mode_code()), Some(b));
        assert_eq!(BaudRate::from_status_code(b.status_code()), Some(b));
    }
    assert_eq!(BaudRate::B9600.status_code(), 0x8067);
    assert_eq!(BaudRate::B500000.status_code(), 0x8001);
    assert_eq!(BaudRate::from_mode_code(0x43), None, "OVB's 0x43 is wrong");
}
