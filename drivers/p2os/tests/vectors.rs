//! Every test vector of the P2OS spec (§9, T1–T22), byte-exact in both directions.

use ima_p2os::wire::{
    self, Command, EncodeOptions, IntCommand, Packet, Sip, SonarRaw, StrCommand, Vel2Style,
};

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

fn emit(c: &Command<'_>) -> Vec<u8> {
    let mut buf = [0u8; 300];
    let n = c.emit(&mut buf).unwrap();
    buf[..n].to_vec()
}

/// Commands whose canonical encoding is the vector: emit gives the bytes, parse gives the value.
#[test]
fn command_vectors_t1_to_t18() {
    let cases: &[(&str, Command<'static>, &str)] = &[
        ("T1", Command::Sync0, "FA FB 03 00 00 00"),
        ("T2", Command::Sync1, "FA FB 03 01 00 01"),
        ("T3", Command::Sync2, "FA FB 03 02 00 02"),
        ("T4", Command::Stop, "FA FB 03 1D 00 1D"),
        ("T5", Command::enable(true), "FA FB 06 04 3B 01 00 05 3B"),
        ("T6", Command::enable(false), "FA FB 06 04 3B 00 00 04 3B"),
        (
            "T7",
            Command::Int(IntCommand::Vel, 200),
            "FA FB 06 0B 3B C8 00 D3 3B",
        ),
        (
            "T8",
            Command::Int(IntCommand::Vel, -200),
            "FA FB 06 0B 1B C8 00 D3 1B",
        ),
        (
            "T9",
            Command::Int(IntCommand::RVel, -30),
            "FA FB 06 15 1B 1E 00 33 1B",
        ),
        (
            "T10",
            Command::Vel2 { left: 5, right: 10 },
            "FA FB 06 20 3B 0A 05 2A 40",
        ),
        (
            "T12",
            Command::Vel2 {
                left: -5,
                right: 10,
            },
            "FA FB 06 20 1B F6 04 16 1F",
        ),
        (
            "T13",
            Command::Int(IntCommand::SetA, -500),
            "FA FB 06 05 1B F4 01 F9 1C",
        ),
        (
            "T14",
            Command::Int(IntCommand::Sonar, 1),
            "FA FB 06 1C 3B 01 00 1D 3B",
        ),
        (
            "T15",
            Command::Int(IntCommand::Encoder, 2),
            "FA FB 06 13 3B 02 00 15 3B",
        ),
        (
            "T16",
            Command::Int(IntCommand::Config, 1),
            "FA FB 06 12 3B 01 00 13 3B",
        ),
        (
            "T17",
            Command::Int(IntCommand::Move, 1000),
            "FA FB 06 08 3B E8 03 F0 3E",
        ),
        (
            "T18",
            Command::Str(StrCommand::Say, &[10, 60, 10, 80]),
            "FA FB 09 0F 2B 04 0A 3C 0A 50 4F 6F",
        ),
    ];
    for (id, cmd, bytes) in cases {
        let bytes = hex(bytes);
        assert_eq!(emit(cmd), bytes, "{id}: emit");
        assert_eq!(wire::parse_host_frame(&bytes).unwrap(), *cmd, "{id}: parse");
    }
}

#[test]
fn t11_player_style_vel2_decodes_like_aria_style() {
    let t11 = hex("FA FB 06 20 3B 0A FB 2B 36");
    let cmd = wire::parse_host_frame(&t11).unwrap();
    assert_eq!(
        cmd,
        Command::Vel2 {
            left: -5,
            right: 10
        }
    );
    // Re-emitting in Player style reproduces T11 exactly.
    let mut buf = [0u8; 16];
    let opts = EncodeOptions {
        vel2_style: Vel2Style::Player,
        ..EncodeOptions::default()
    };
    let n = cmd.emit_with(opts, &mut buf).unwrap();
    assert_eq!(&buf[..n], &t11[..]);
    // Wheel speeds in mm/s with Vel2Divisor 20: left −100, right 200.
    let Command::Vel2 { left, right } = cmd else {
        unreachable!()
    };
    assert_eq!((i32::from(left) * 20, i32::from(right) * 20), (-100, 200));
}

#[test]
fn aria_open_close_carry_argint_one_and_parse_back() {
    let opts = EncodeOptions {
        open_close_arg: true,
        ..EncodeOptions::default()
    };
    let mut buf = [0u8; 16];
    let n = Command::OPEN.emit_with(opts, &mut buf).unwrap();
    assert_eq!(&buf[..n], &hex("FA FB 06 01 3B 01 00 02 3B")[..]);
    assert_eq!(wire::parse_host_frame(&buf[..n]).unwrap(), Command::OPEN);
    // ROS appends a bare ARGINT to SETO: still SETO.
    let mut frame = [0u8; 16];
    let n = wire::encode_frame(&[7, 0x3B], &mut frame).unwrap();
    assert_eq!(
        wire::parse_host_frame(&frame[..n]).unwrap(),
        Command::SetOdometry
    );
}

#[test]
fn t19_sync2_reply() {
    let bytes = hex("FA FB 15 02 50 32 41 54 00 50 69 6F 6E 65 65 72 00 70 32 61 74 00 F1 73");
    let p = Packet::SyncReply {
        name: b"P2AT",
        class: b"Pioneer",
        subclass: b"p2at",
    };
    assert_eq!(wire::parse_robot_frame(&bytes).unwrap(), p);
    let mut buf = [0u8; 64];
    let n = p.emit(&mut buf).unwrap();
    assert_eq!(&buf[..n], &bytes[..]);
}

fn t20_sip() -> Sip {
    let mut sonars = heapless::Vec::new();
    sonars
        .push(SonarRaw {
            index: 0,
            range: 1866,
        })
        .unwrap();
    sonars
        .push(SonarRaw {
            index: 7,
            range: 3731,
        })
        .unwrap();
    Sip {
        moving: true,
        xpos: 1000,
        ypos: 500,
        thpos: 1024,
        left_vel: -50,
        right_vel: 50,
        battery: 125,
        stall_bumpers: 0,
        control: 1024,
        flags: 0x0001,
        compass: 0,
        sonars,
        grip_state: 0,
        anport: 0,
        analog: 0,
        digin: 0xFF,
        digout: 0x0F,
        extra_len: 0,
    }
}

#[test]
fn t20_synthetic_sip() {
    let bytes = hex(
        "FA FB 21 33 E8 03 F4 01 00 04 CE FF 32 00 7D 00 00 00 04 01 00 00 02 00 4A 07 07 93 0E 00 00 00 FF 0F D9 B2",
    );
    assert_eq!(wire::checksum(&bytes[3..bytes.len() - 2]), 0xD9B2);
    let sip = t20_sip();
    assert_eq!(
        wire::parse_robot_frame(&bytes).unwrap(),
        Packet::Sip(sip.clone())
    );
    let mut buf = [0u8; 64];
    let n = Packet::Sip(sip.clone()).emit(&mut buf).unwrap();
    assert_eq!(&buf[..n], &bytes[..]);
    assert_eq!(sip.payload_len(), 31);
    assert!(sip.motors_enabled());
}

#[test]
fn t21_encoder_packet() {
    let bytes = hex("FA FB 0B 90 C4 80 01 00 86 D9 FF FF EB B5");
    let p = Packet::Encoder {
        left: 98_500,
        right: -9_850,
    };
    assert_eq!(wire::parse_robot_frame(&bytes).unwrap(), p);
    let mut buf = [0u8; 32];
    let n = p.emit(&mut buf).unwrap();
    assert_eq!(&buf[..n], &bytes[..]);
}

#[test]
fn bad_checksum_is_reported_with_both_values() {
    let mut bytes = hex("FA FB 06 0B 3B C8 00 D3 3B");
    bytes[8] = 0x3C;
    assert_eq!(
        wire::parse_host_frame(&bytes),
        Err(wire::WireError::BadChecksum {
            expected: 0xD33B,
            got: 0xD33C
        })
    );
}

#[test]
fn config_packet_longer_than_127_bytes_round_trips() {
    let cfg = wire::Config {
        robot_type: b"Pioneer",
        subtype: b"p2at",
        serial: b"SN-0042",
        four_motors: 1,
        rot_vel_top: 300,
        trans_vel_top: 1200,
        rot_acc_top: 300,
        trans_acc_top: 2000,
        pwm_max: 500,
        name: b"Skeeter",
        numbers: wire::ConfigNumbers {
            sip_cycle: 100,
            watchdog: 2000,
            reset_baud: 0,
            ticks_mm: 19,
            ..Default::default()
        },
        firmware: b"P2OS 1.M (ima mock build, long firmware string)",
    };
    let mut buf = [0u8; 300];
    let n = Packet::Config(cfg).emit(&mut buf).unwrap();
    assert!(buf[2] >= 128, "count byte {} should exceed 127", buf[2]);
    assert_eq!(
        wire::parse_robot_frame(&buf[..n]).unwrap(),
        Packet::Config(cfg)
    );
}

#[test]
fn short_config_reads_missing_fields_as_zero() {
    let mut frame = [0u8; 64];
    let n = wire::encode_frame(b"\x20Pioneer\0p3dx-sh\0SN\0\x00\x68\x01", &mut frame).unwrap();
    let Packet::Config(c) = wire::parse_robot_frame(&frame[..n]).unwrap() else {
        panic!("not a config")
    };
    assert_eq!(c.subtype, b"p3dx-sh");
    assert_eq!(c.rot_vel_top, 360);
    assert_eq!(c.trans_vel_top, 0);
    assert_eq!(c.numbers.watchdog, 0);
}

#[test]
fn unknown_packet_types_and_commands_are_reported_not_fatal() {
    let mut frame = [0u8; 16];
    let n = wire::encode_frame(&[0x77, 1, 2, 3], &mut frame).unwrap();
    assert_eq!(
        wire::parse_robot_frame(&frame[..n]).unwrap(),
        Packet::Unknown {
            ptype: 0x77,
            body: &[1, 2, 3]
        }
    );
    let n = wire::encode_frame(&[99, 0x3B, 5, 0], &mut frame).unwrap();
    let c = wire::parse_host_frame(&frame[..n]).unwrap();
    assert_eq!(c.number(), 99);
    assert_eq!(c.name(), "unknown_command");
}

#[test]
fn sip_with_inconsistent_sonar_count_or_index_is_rejected() {
    let mut sip = t20_sip();
    let mut buf = [0u8; 64];
    let n = Packet::Sip(sip.clone()).emit(&mut buf).unwrap();
    // Claim 9 readings with only 2 present (the sonar count is payload byte 19).
    let mut payload = buf[3..n - 2].to_vec();
    payload[19] = 9;
    let mut frame = [0u8; 64];
    let m = wire::encode_frame(&payload, &mut frame).unwrap();
    assert_eq!(
        wire::parse_robot_frame(&frame[..m]),
        Err(wire::WireError::BadSonarCount(9))
    );
    sip.sonars[1].index = 40;
    let n = Packet::Sip(sip).emit(&mut buf).unwrap();
    assert_eq!(
        wire::parse_robot_frame(&buf[..n]),
        Err(wire::WireError::BadSonarIndex(40))
    );
}

#[test]
fn every_int_command_number_round_trips() {
    for &c in IntCommand::ALL {
        assert_eq!(IntCommand::from_number(c.number()), Some(c));
        for v in [0i16, 1, -1, 32767, -32767, -32768] {
            let cmd = Command::Int(c, v);
            assert_eq!(
                wire::parse_host_frame(&emit(&cmd)).unwrap(),
                cmd,
                "{c:?} {v}"
            );
        }
    }
}
