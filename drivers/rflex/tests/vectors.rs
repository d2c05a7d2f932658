//! Spec `rflex.md` §9 test vectors T1–T13, byte-exact in both directions.

use ima_hal::base::VelocityCommand;
use ima_rflex::framer::{FrameError, Framer};
use ima_rflex::machine::{Config, Machine};
use ima_rflex::wire::{
    Command, DioReport, MAX_CONTENT, MAX_WIRE_FRAME, MotionReport, RawFrame, Report, SetDir,
    SonarEcho, SonarReport, SonarRun, Stuffing, WireError, nudge_u32,
};

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

fn emit_cmd(c: &Command) -> Vec<u8> {
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let n = c.emit(&mut buf).unwrap();
    buf[..n].to_vec()
}

fn emit_rep(r: &Report, id: u8) -> Vec<u8> {
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let n = r.emit_with(id, Stuffing::Full, &mut buf).unwrap();
    buf[..n].to_vec()
}

fn id_of(wire: &[u8]) -> u8 {
    let mut scratch = [0u8; MAX_CONTENT];
    RawFrame::parse_wire(wire, &mut scratch).unwrap().id
}

/// Both directions for a command: emit gives `wire`, parse gives `cmd`.
fn check_cmd(cmd: Command, wire: &str) {
    let w = hex(wire);
    assert_eq!(emit_cmd(&cmd), w, "emit {cmd:?}");
    assert_eq!(Command::parse(&w).unwrap(), cmd, "parse {wire}");
}

fn check_rep(rep: Report, id: u8, wire: &str) {
    let w = hex(wire);
    assert_eq!(emit_rep(&rep, id), w, "emit {rep:?}");
    assert_eq!(Report::parse(&w).unwrap(), rep, "parse {wire}");
    assert_eq!(id_of(&w), id);
}

#[test]
fn t1_brake_and_defaults() {
    check_cmd(Command::BrakeRelease, "1B 02 02 00 0C 00 0E 1B 03");
    check_cmd(Command::BrakeSet, "1B 02 02 00 0B 00 09 1B 03");
    check_cmd(Command::SetDefaults, "1B 02 02 00 0A 00 08 1B 03");
}

#[test]
fn t2_sys_status_request() {
    check_cmd(Command::SysStatusRequest, "1B 02 01 00 01 00 00 1B 03");
}

#[test]
fn t3_reports_dio_sonar_on() {
    check_cmd(
        Command::SystemReportReq {
            period_us: 100_000,
            mask: 3,
        },
        "1B 02 02 00 22 08 00 01 86 A0 00 00 00 03 0C 1B 03",
    );
    check_cmd(
        Command::DioReportsReq { period_us: 100_000 },
        "1B 02 05 00 00 04 00 01 86 A0 26 1B 03",
    );
    check_cmd(
        Command::SonarRun(SonarRun::ON),
        "1B 02 04 04 00 0D 00 00 75 30 00 00 00 00 00 00 00 00 02 4A 1B 03",
    );
    // Spec erratum: §9 says "off: the same with mode 00 and checksum 0D", but 0x0D is only the
    // header XOR (04^04^00^0D). Header 0D ^ (75^30 = 45) = 48, and mode 00 adds nothing, so
    // the off frame's checksum is 0x48 (= on's 0x4A ^ 0x02).
    check_cmd(
        Command::SonarRun(SonarRun::OFF),
        "1B 02 04 04 00 0D 00 00 75 30 00 00 00 00 00 00 00 00 00 48 1B 03",
    );
}

const T4_TRANS: &str = "1B 02 02 00 07 0E 00 00 00 6A 6B 00 00 F8 4F 00 00 75 30 01 F9 1B 03";
const T4_ROT: &str = "1B 02 02 00 07 0E 01 00 00 00 00 00 01 86 A0 00 00 88 B8 01 1C 1B 03";

#[test]
fn t4_set_velocity_frames() {
    check_cmd(
        Command::SetDir(SetDir {
            axis: 0,
            velocity: 27243,
            acceleration: 63567,
            torque: 30000,
            forward: true,
        }),
        T4_TRANS,
    );
    check_cmd(
        Command::SetDir(SetDir {
            axis: 1,
            velocity: 0,
            acceleration: 100_000,
            torque: 35_000,
            forward: true,
        }),
        T4_ROT,
    );
    // And the §5 mapping of the machine gives exactly these from SI values.
    let m = Machine::new(Config::default(), ima_hal::Instant::ZERO);
    let [a, b] = m.set_dir_pair(VelocityCommand::new(0.3, 0.0));
    assert_eq!(emit_cmd(&Command::SetDir(a)), hex(T4_TRANS));
    assert_eq!(emit_cmd(&Command::SetDir(b)), hex(T4_ROT));
}

fn t5_cmd() -> Command {
    Command::SetDir(SetDir {
        axis: 1,
        velocity: 7000,
        acceleration: 100_000,
        torque: 35_000,
        forward: false,
    })
}

const T5_LOGICAL: &str = "1B 02 02 00 07 0E 01 00 00 1B 58 00 01 86 A0 00 00 88 B8 00 5E 1B 03";
const T5_WIRE: &str = "1B 02 02 00 07 0E 01 00 00 1B 00 58 00 01 86 A0 00 00 88 B8 00 5E 1B 03";

#[test]
fn t5_command_needing_stuffing() {
    check_cmd(t5_cmd(), T5_WIRE);
    assert_eq!(hex(T5_WIRE).len(), 24);
    // From SI: −7000/37000 rad/s.
    let m = Machine::new(Config::default(), ima_hal::Instant::ZERO);
    let [_, b] = m.set_dir_pair(VelocityCommand::new(0.0, -7000.0 / 37000.0));
    assert_eq!(Command::SetDir(b), t5_cmd());
    // Unstuffed emission gives the logical form...
    let mut buf = [0u8; MAX_WIRE_FRAME];
    let n = t5_cmd().emit_with(0, Stuffing::None, &mut buf).unwrap();
    assert_eq!(&buf[..n], &hex(T5_LOGICAL)[..]);
    // ...which a strict receiver rejects and a lenient one accepts.
    assert_eq!(
        Command::parse(&hex(T5_LOGICAL)),
        Err(WireError::BadEscape(0x58))
    );
    let mut strict = Framer::strict();
    let mut got = Vec::new();
    strict.push(&hex(T5_LOGICAL), |r| got.push(r.map(|f| f.data.to_vec())));
    assert_eq!(got, vec![Err(FrameError::BadEscape(0x58))]);
    let mut lenient = Framer::lenient();
    let mut cmds = Vec::new();
    lenient.push(&hex(T5_LOGICAL), |r| {
        cmds.push(Command::from_raw(&r.unwrap()).unwrap())
    });
    assert_eq!(cmds, vec![t5_cmd()]);
    // Legacy nudge: 0x1B58 → 0x1AFF (6911).
    assert_eq!(nudge_u32(0x1B58), 0x1AFF);
    let Command::SetDir(n) = t5_cmd().legacy_nudged() else {
        panic!()
    };
    assert_eq!(n.velocity, 6911);
}

#[test]
fn t6_checksum_needing_stuffing() {
    let w = emit_cmd(&Command::SetDir(SetDir {
        axis: 0,
        velocity: 27273,
        acceleration: 63567,
        torque: 30000,
        forward: true,
    }));
    assert_eq!(w.len(), 24);
    assert_eq!(&w[w.len() - 7..], &hex("75 30 01 1B 00 1B 03")[..]);
    assert!(matches!(
        Command::parse(&w),
        Ok(Command::SetDir(SetDir {
            velocity: 27273,
            ..
        }))
    ));
}

fn motion(ts: u32, axis: u8, position: i32, velocity: i32) -> Report {
    Report::Motion(MotionReport {
        rv: 0,
        ts,
        axis,
        position,
        velocity,
        acceleration: 0,
        torque: 0,
    })
}

#[test]
fn t7_odometry_report_axis0() {
    let w = "1B 02 02 05 21 19 00 00 00 00 00 00 12 34 00 00 01 62 BA 00 00 6A 6B 00 00 00 00 00 00 00 00 C1 1B 03";
    assert_eq!(hex(w).len(), 34);
    check_rep(motion(0x1234, 0, 90810, 27243), 5, w);
}

#[test]
fn t8_axis1_report_with_7c() {
    let w = "1B 02 02 06 21 19 00 00 00 00 00 00 12 35 01 00 01 B1 7C 1B 01 FF FF F1 8C 00 00 00 00 00 00 00 00 AB 1B 03";
    assert_eq!(hex(w).len(), 36);
    check_rep(motion(0x1235, 1, 0x0001_B17C, -3700), 6, w);
}

#[test]
fn t9_axis1_report_with_two_1b() {
    let w = "1B 02 02 06 21 19 00 00 00 00 00 00 12 35 01 00 00 1B 00 1B 00 FF FF F1 8C 00 00 00 00 00 00 00 00 67 1B 03";
    check_rep(motion(0x1235, 1, 6939, -3700), 6, w);
}

#[test]
fn t10_sys_status_reply() {
    check_rep(
        Report::SysStatus {
            ts: 0x1236,
            voltage_raw: 2630,
            brake_engaged: false,
        },
        7,
        "1B 02 01 07 01 09 00 00 12 36 00 00 0A 46 00 66 1B 03",
    );
}

#[test]
fn t11_sonar_report() {
    let mut echoes = heapless::Vec::new();
    echoes.push(SonarEcho { id: 0, range: 1476 }).unwrap();
    echoes
        .push(SonarEcho {
            id: 0x10,
            range: 738,
        })
        .unwrap();
    check_rep(
        Report::Sonar(SonarReport {
            rv: 0,
            ts: 0x1237,
            echoes,
        }),
        8,
        "1B 02 04 08 02 0E 00 00 00 00 00 00 12 37 00 05 C4 10 02 E2 14 1B 03",
    );
}

#[test]
fn t12_front_bumper() {
    check_rep(
        Report::Dio(DioReport {
            ts: 0x1238,
            address: 0x40,
            data: 1,
        }),
        9,
        "1B 02 05 09 01 07 00 00 12 38 40 00 01 61 1B 03",
    );
}

#[test]
fn t13_resync() {
    let t1 = hex("1B 02 02 00 0C 00 0E 1B 03");
    let t2 = hex("1B 02 01 00 01 00 00 1B 03");
    let mut stream = vec![0xFF, 0x1B];
    stream.extend_from_slice(&t1);
    stream.extend_from_slice(&hex("1B 02 02 00 0C"));
    stream.extend_from_slice(&t2);
    let mut f = Framer::strict();
    let mut cmds = Vec::new();
    let mut errs = Vec::new();
    f.push(&stream, |r| match r {
        Ok(raw) => cmds.push(Command::from_raw(&raw).unwrap()),
        Err(e) => errs.push(e),
    });
    assert_eq!(cmds, vec![Command::BrakeRelease, Command::SysStatusRequest]);
    assert_eq!(errs, vec![FrameError::Restarted]);
    assert_eq!(f.stats().frames, 2);
    assert_eq!(f.stats().restarts, 1);
}

#[test]
fn nudge_examples() {
    assert_eq!(nudge_u32(0x1B58), 0x1AFF); // T5, low byte ≤ 127: round down
    assert_eq!(nudge_u32(0x1B80), 0x1C00); // low byte > 127: round up
    assert_eq!(nudge_u32(0x001B), 0x001C); // least significant byte
    assert_eq!(nudge_u32(0x1B00_0000), 0x1AFF_FFFF);
    assert_eq!(nudge_u32(0x0001_86A0), 0x0001_86A0); // untouched
}
