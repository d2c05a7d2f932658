//! Fuzz entry points, shared by the `cargo fuzz` targets in `fuzz/fuzz_targets/p2os_*.rs` and
//! by the corpus replay test (`tests/fuzz_corpus.rs`).
//!
//! Each function takes arbitrary bytes, must never panic on them, and `assert!`s invariants:
//! * [`p2os_from_robot`] — robot → host stream: the first byte picks a read size, the rest is
//!   fed through [`Framer::new`] in reads of that size; every frame is parsed as a [`Packet`],
//!   and every packet that parses is re-emitted and re-parsed to the same value. The framer's
//!   byte accounting (delivered + dropped + buffered = fed) must hold.
//! * [`p2os_from_host`] — the same for host → robot traffic with [`Framer::for_commands`] and
//!   [`Command`], re-emitted with default and with ARIA/Player [`EncodeOptions`].
//! * [`p2os_roundtrip`] — builds a [`Command`] or [`Packet`] deterministically from the bytes,
//!   emits it, frames it, parses it, and checks it comes back equal.
//!
//! In `cfg(fuzzing)` builds [`wire::frame_payload`] skips the checksum comparison so that the
//! fuzzer reaches the parsers; the replay test runs with checksums on.
//!
//! Known, intended non-identities (normalised before comparing): a SIP's `extra_len` (bytes
//! after DIGOUT are counted but not kept, so not re-emitted); SYNC2 replies and CONFIG packets
//! may grow on re-emission (missing NULs and trailing fields are written out), so their
//! re-emission may exceed a frame — nothing else may.

// The asserts below are the invariants a fuzz target exists to check.
#![allow(clippy::panic)]

use crate::framer::{FrameEvent, Framer};
use crate::wire::{
    self, Arg, Command, Config, ConfigNumbers, EncodeOptions, IntArg, IntCommand,
    MAX_COMMAND_COUNT, MAX_FRAME_LEN, Packet, Sip, SonarRaw, StrCommand, Vel2Style, WireError,
};

/// Read size for a selector byte: 0 = everything at once, else 1..=255 bytes per read.
fn read_size(selector: u8) -> usize {
    match selector {
        0 => usize::MAX,
        s => usize::from(s),
    }
}

/// Bytes fed = bytes in delivered frames + dropped + still buffered.
fn assert_accounted(framer: &Framer, fed: usize, in_frames: u64) {
    let st = framer.stats();
    assert_eq!(
        in_frames + st.dropped_bytes + framer.buffered() as u64,
        fed as u64,
        "framer byte accounting: {st:?}"
    );
}

/// Run `stream` through `framer` in reads of `size`, then abandon whatever partial frames are
/// left (as the caller's inter-byte timeout would), calling `on_payload` for every frame.
fn drive(framer: &mut Framer, stream: &[u8], size: usize, mut on_payload: impl FnMut(&[u8])) {
    let mut in_frames = 0u64;
    for chunk in stream.chunks(size) {
        framer.push(chunk, |ev| {
            if let FrameEvent::Frame(p) = ev {
                in_frames += p.len() as u64 + 5;
                on_payload(p);
            }
        });
    }
    assert_accounted(framer, stream.len(), in_frames);
    while framer.abandon_partial() {
        while let Some(ev) = framer.next_frame() {
            if let FrameEvent::Frame(p) = ev {
                in_frames += p.len() as u64 + 5;
                on_payload(p);
            }
        }
    }
    assert_eq!(framer.buffered(), 0);
    assert_accounted(framer, stream.len(), in_frames);
}

/// Fuzz target `p2os_from_robot`: framer + [`Packet`] parser over a robot → host stream.
pub fn p2os_from_robot(data: &[u8]) {
    let Some((&selector, stream)) = data.split_first() else {
        return;
    };
    let mut framer = Framer::new();
    drive(
        &mut framer,
        stream,
        read_size(selector),
        check_robot_payload,
    );
}

/// Fuzz target `p2os_from_host`: framer + [`Command`] parser over a host → robot stream.
pub fn p2os_from_host(data: &[u8]) {
    let Some((&selector, stream)) = data.split_first() else {
        return;
    };
    let mut framer = Framer::for_commands();
    drive(&mut framer, stream, read_size(selector), check_host_payload);
}

/// What a parsed packet must equal after emit → parse (see the module docs).
fn normalised(p: Packet<'_>) -> Packet<'_> {
    match p {
        Packet::Sip(sip) => Packet::Sip(Sip {
            extra_len: 0,
            ..sip
        }),
        other => other,
    }
}

fn check_robot_payload(payload: &[u8]) {
    let Ok(pkt) = Packet::parse(payload) else {
        return;
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
    match pkt.emit(&mut buf) {
        Ok(n) => {
            let frame = buf.get(..n).unwrap_or_default();
            let again = wire::parse_robot_frame(frame);
            assert_eq!(again, Ok(normalised(pkt.clone())), "robot packet re-parse");
            // The canonical form is a fixed point: emitting it again gives the same bytes.
            if let Ok(again) = again {
                let mut buf2 = [0u8; MAX_FRAME_LEN];
                let m = again.emit(&mut buf2);
                assert_eq!(m, Ok(n));
                assert_eq!(buf2.get(..n), Some(frame));
            }
        }
        Err(e) => assert!(
            matches!(pkt, Packet::SyncReply { .. } | Packet::Config(_))
                && matches!(e, WireError::PayloadTooLong(_)),
            "re-emitting {pkt:?} failed: {e:?}"
        ),
    }
}

fn check_host_payload(payload: &[u8]) {
    let Ok(cmd) = Command::parse(payload) else {
        return;
    };
    let options = [
        EncodeOptions::default(),
        EncodeOptions {
            vel2_style: Vel2Style::Player,
            open_close_arg: true,
        },
    ];
    for opts in options {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let emitted = cmd.emit_with(opts, &mut buf);
        // A parsed command re-emits no longer than it came (count ≤ 200), except that ARIA's
        // OPEN/CLOSE gain their `ARGINT 1`, which still fits.
        assert!(emitted.is_ok(), "re-emitting {cmd:?} failed: {emitted:?}");
        let n = emitted.unwrap_or_default();
        let frame = buf.get(..n).unwrap_or_default();
        assert!(frame.get(2).is_some_and(|&c| c <= MAX_COMMAND_COUNT));
        assert_eq!(
            wire::parse_host_frame(frame),
            Ok(cmd),
            "command re-parse ({opts:?})"
        );
    }
}

/// A deterministic reader of fuzz bytes: past the end everything reads as 0 / empty.
struct Bytes<'a>(&'a [u8]);

impl<'a> Bytes<'a> {
    fn u8(&mut self) -> u8 {
        match self.0.split_first() {
            Some((&b, rest)) => {
                self.0 = rest;
                b
            }
            None => 0,
        }
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }
    fn i16(&mut self) -> i16 {
        i16::from_le_bytes([self.u8(), self.u8()])
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }
    fn bool(&mut self) -> bool {
        self.u8() & 1 == 1
    }
    /// Up to `max` bytes (the length is read first).
    fn bytes(&mut self, max: usize) -> &'a [u8] {
        let n = usize::from(self.u8()).min(max).min(self.0.len());
        let (taken, rest) = self.0.split_at(n);
        self.0 = rest;
        taken
    }
    /// Up to `max` bytes containing no NUL (stops before the first NUL and skips it).
    fn no_nul(&mut self, max: usize) -> &'a [u8] {
        let raw = self.bytes(max);
        let end = raw.iter().position(|&b| b == 0).unwrap_or(raw.len());
        raw.split_at(end).0
    }
}

/// Longest string argument whose command still has a count ≤ 200.
const MAX_CMD_STR: usize = MAX_COMMAND_COUNT as usize - 5;

/// Fuzz target `p2os_roundtrip`: a value built from the bytes survives emit → frame → parse.
pub fn p2os_roundtrip(data: &[u8]) {
    let mut b = Bytes(data);
    if b.bool() {
        roundtrip_command(&mut b);
    } else {
        roundtrip_packet(&mut b);
    }
}

fn command_is_modeled(n: u8) -> bool {
    matches!(n, 0 | 1 | 2 | 3 | 7 | 15 | 29 | 32 | 42 | 55) || IntCommand::from_number(n).is_some()
}

fn roundtrip_command(b: &mut Bytes<'_>) {
    let opts = EncodeOptions {
        vel2_style: if b.bool() {
            Vel2Style::Player
        } else {
            Vel2Style::Aria
        },
        open_close_arg: b.bool(),
    };
    let plain = [
        Command::Sync0,
        Command::Sync1,
        Command::Sync2,
        Command::SetOdometry,
        Command::Stop,
        Command::EStop,
    ];
    let strs = [StrCommand::Polling, StrCommand::Say, StrCommand::Tty2];
    let mut str_len = 0;
    let cmd = match b.u8() % 5 {
        0 => match plain.get(usize::from(b.u8()) % plain.len()) {
            Some(c) => *c,
            None => return,
        },
        1 => match IntCommand::ALL.get(usize::from(b.u8()) % IntCommand::ALL.len()) {
            Some(&c) => Command::Int(c, b.i16()),
            None => return,
        },
        2 => Command::Vel2 {
            left: b.u8() as i8,
            right: b.u8() as i8,
        },
        3 => {
            let Some(&c) = strs.get(usize::from(b.u8()) % strs.len()) else {
                return;
            };
            let s = b.bytes(255);
            str_len = s.len();
            Command::Str(c, s)
        }
        _ => {
            let number = b.u8();
            if command_is_modeled(number) {
                return;
            }
            let arg = match b.u8() % 3 {
                0 => Arg::None,
                1 => Arg::Int(IntArg {
                    negative: b.bool(),
                    raw: b.u16(),
                }),
                _ => {
                    let s = b.bytes(255);
                    str_len = s.len();
                    Arg::Str(s)
                }
            };
            Command::Other { number, arg }
        }
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
    match cmd.emit_with(opts, &mut buf) {
        Ok(n) => {
            let frame = buf.get(..n).unwrap_or_default();
            assert_eq!(wire::parse_host_frame(frame), Ok(cmd), "{opts:?}");
            let mut framer = Framer::for_commands();
            let mut seen = 0;
            framer.push(frame, |ev| {
                assert!(matches!(ev, FrameEvent::Frame(p) if Command::parse(p) == Ok(cmd)));
                seen += 1;
            });
            assert_eq!(seen, 1);
        }
        Err(e) => assert!(
            str_len > MAX_CMD_STR && matches!(e, WireError::PayloadTooLong(_)),
            "emitting {cmd:?} failed: {e:?}"
        ),
    }
}

fn packet_type_is_modeled(t: u8) -> bool {
    matches!(t, 0 | 1 | 2 | 0x20 | 0x32 | 0x33 | 0x90 | 0xB0 | 0xB8)
}

fn roundtrip_packet(b: &mut Bytes<'_>) {
    let pkt = match b.u8() % 7 {
        0 => Packet::SyncEcho(b.u8() & 1),
        1 => Packet::SyncReply {
            name: b.no_nul(80),
            class: b.no_nul(80),
            subclass: b.no_nul(80),
        },
        2 => {
            let mut sip = Sip {
                moving: b.bool(),
                xpos: b.u16() & 0x7FFF,
                ypos: b.u16() & 0x7FFF,
                thpos: b.i16(),
                left_vel: b.i16(),
                right_vel: b.i16(),
                battery: b.u8(),
                stall_bumpers: b.u16(),
                control: b.i16(),
                flags: b.u16(),
                compass: b.u8(),
                ..Sip::default()
            };
            let k = b.u8() % 33;
            for _ in 0..k {
                let reading = SonarRaw {
                    index: b.u8() % 32,
                    range: b.u16(),
                };
                if sip.sonars.push(reading).is_err() {
                    break;
                }
            }
            sip.grip_state = b.u8();
            sip.anport = b.u8();
            sip.analog = b.u8();
            sip.digin = b.u8();
            sip.digout = b.u8();
            Packet::Sip(sip)
        }
        3 => Packet::Config(Config {
            robot_type: b.no_nul(30),
            subtype: b.no_nul(30),
            serial: b.no_nul(30),
            four_motors: b.u8(),
            rot_vel_top: b.u16(),
            trans_vel_top: b.u16(),
            rot_acc_top: b.u16(),
            trans_acc_top: b.u16(),
            pwm_max: b.u16(),
            name: b.no_nul(30),
            numbers: config_numbers(b),
            firmware: b.no_nul(30),
        }),
        4 => Packet::Encoder {
            left: b.i32(),
            right: b.i32(),
        },
        5 => Packet::SerAux {
            port: 1 + (b.u8() & 1),
            data: b.bytes(252),
        },
        _ => {
            let ptype = b.u8();
            if packet_type_is_modeled(ptype) {
                return;
            }
            Packet::Unknown {
                ptype,
                body: b.bytes(252),
            }
        }
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
    let emitted = pkt.emit(&mut buf);
    assert!(emitted.is_ok(), "emitting {pkt:?} failed: {emitted:?}");
    let n = emitted.unwrap_or_default();
    let frame = buf.get(..n).unwrap_or_default();
    // The checksum on the wire is the spec's (also in fuzz builds, where parsing skips it).
    let (body, sum) = frame.split_at(n.saturating_sub(2));
    assert_eq!(
        sum,
        wire::checksum(body.get(3..).unwrap_or_default()).to_be_bytes()
    );
    assert_eq!(wire::parse_robot_frame(frame), Ok(pkt.clone()));
    let mut framer = Framer::new();
    let mut seen = 0;
    framer.push(frame, |ev| {
        assert!(matches!(ev, FrameEvent::Frame(p) if Packet::parse(p).as_ref() == Ok(&pkt)));
        seen += 1;
    });
    assert_eq!(seen, 1);
}

fn config_numbers(b: &mut Bytes<'_>) -> ConfigNumbers {
    ConfigNumbers {
        sip_cycle: b.u8(),
        host_baud: b.u8(),
        aux1_baud: b.u8(),
        has_gripper: b.u16(),
        front_sonar: b.u16(),
        rear_sonar: b.u8(),
        low_battery: b.u16(),
        rev_count: b.u16(),
        watchdog: b.u16(),
        normal_mpacs: b.u8(),
        stall_val: b.u16(),
        stall_count: b.u16(),
        joy_vel: b.u16(),
        joy_rot_vel: b.u16(),
        rot_vel_max: b.u16(),
        trans_vel_max: b.u16(),
        rot_accel: b.u16(),
        rot_decel: b.u16(),
        rot_kp: b.u16(),
        rot_kv: b.u16(),
        rot_ki: b.u16(),
        trans_accel: b.u16(),
        trans_decel: b.u16(),
        trans_kp: b.u16(),
        trans_kv: b.u16(),
        trans_ki: b.u16(),
        front_bumps: b.u8(),
        rear_bumps: b.u8(),
        has_charger: b.u8(),
        sonar_cycle: b.u8(),
        reset_baud: b.u8(),
        has_gyro: b.u8(),
        drift_factor: b.i16(),
        aux2_baud: b.u8(),
        aux3_baud: b.u8(),
        ticks_mm: b.u16(),
        shutdown_volts: b.u16(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn harness_accepts_empty_and_tiny_inputs() {
        for data in [&[][..], &[0], &[1, 0xFA], &[0, 0xFA, 0xFB, 0x03, 0, 0, 0]] {
            p2os_from_robot(data);
            p2os_from_host(data);
            p2os_roundtrip(data);
        }
    }
}
