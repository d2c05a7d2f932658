// #[cfg(test)]: this whole file is a test module (declared `#[cfg(test)] mod tests;`).
//! Session tests in virtual time.

use super::*;
use std::vec::Vec;

fn ms(n: u64) -> Instant {
    Instant::from_millis(n)
}

fn sent(m: &mut Machine) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    let mut buf = [0u8; 16];
    while let Some(n) = m.poll_transmit(&mut buf) {
        out.push(buf[..n].to_vec());
    }
    out
}

fn events(m: &mut Machine) -> Vec<Event> {
    core::iter::from_fn(|| m.poll_event()).collect()
}

fn kramer(expect_reply: bool) -> Machine {
    Machine::new(Config {
        dialect: Dialect::Kramer {
            output: 1,
            machine: 1,
            expect_reply,
        },
        ..Config::default()
    })
}

#[test]
fn extron_select_confirmed_then_settles() {
    let mut m = Machine::new(Config::default());
    m.select(3, ms(1000)).unwrap();
    assert_eq!(sent(&mut m), [b"3!".to_vec()]);
    assert_eq!(m.poll_timeout(), Some(ms(1500)));
    m.handle_bytes(b"In3 All\r\n", ms(1040));
    assert_eq!(
        events(&mut m),
        [Event::Selected(Selection {
            channel: 3,
            confirmed_at: ms(1040),
            settled_at: ms(1190),
        })]
    );
    assert_eq!(m.current_channel(), Some(3));
    assert!(!m.is_busy());
    assert_eq!(m.poll_timeout(), Some(ms(1190)));
    m.handle_timeout(ms(1189));
    assert!(events(&mut m).is_empty());
    m.handle_timeout(ms(1190));
    assert_eq!(events(&mut m), [Event::Settled { channel: 3 }]);
    assert_eq!(m.poll_timeout(), None);
}

#[test]
fn extron_padded_and_video_only_replies() {
    let mut m = Machine::new(Config {
        dialect: Dialect::Extron {
            kind: TieKind::Video,
            output: None,
        },
        ..Config::default()
    });
    m.select(7, ms(0)).unwrap();
    assert_eq!(sent(&mut m), [b"7&".to_vec()]);
    m.handle_bytes(b"In007 Vid\r\n", ms(10));
    assert!(matches!(
        events(&mut m)[..],
        [Event::Selected(Selection { channel: 7, .. })]
    ));
}

#[test]
fn extron_timeout_retries_then_fails() {
    let mut m = Machine::new(Config::default());
    m.select(2, ms(0)).unwrap();
    assert_eq!(sent(&mut m), [b"2!".to_vec()]);
    m.handle_timeout(ms(499));
    assert!(sent(&mut m).is_empty());
    m.handle_timeout(ms(500));
    assert_eq!(sent(&mut m), [b"2!".to_vec()]);
    assert_eq!(m.poll_timeout(), Some(ms(1000)));
    m.handle_timeout(ms(1000));
    assert_eq!(sent(&mut m), [b"2!".to_vec()]);
    m.handle_timeout(ms(1500));
    assert!(sent(&mut m).is_empty());
    assert_eq!(
        events(&mut m),
        [Event::SelectFailed {
            channel: 2,
            failure: Failure::Timeout
        }]
    );
    assert_eq!(m.stats().retransmissions, 2);
    assert_eq!(m.poll_timeout(), None);
    // Free for the next request; a late reply then counts as a front-panel selection.
    m.handle_bytes(b"In2 All\r\n", ms(1600));
    assert_eq!(events(&mut m), [Event::ExternalSelect { channel: 2 }]);
    m.select(4, ms(1700)).unwrap();
}

#[test]
fn extron_error_replies_fail_without_retry() {
    for (line, err) in [
        (&b"E01\r\n"[..], ExtronError::InvalidInput),
        (b"E06\r\n", ExtronError::ChangeNotAllowed),
        (b"E10\r\n", ExtronError::InvalidCommand),
        (b"E13\r\n", ExtronError::InvalidValue),
    ] {
        let mut m = Machine::new(Config::default());
        m.select(5, ms(0)).unwrap();
        let _ = sent(&mut m);
        m.handle_bytes(line, ms(20));
        assert_eq!(
            events(&mut m),
            [Event::SelectFailed {
                channel: 5,
                failure: Failure::Refused(Refusal::Extron(err))
            }]
        );
        m.handle_timeout(ms(5000));
        assert!(sent(&mut m).is_empty(), "no retry after {err:?}");
        assert!(events(&mut m).is_empty());
        assert_eq!(m.current_channel(), None);
    }
}

#[test]
fn extron_unsolicited_messages() {
    let mut m = Machine::new(Config::default());
    m.handle_bytes(
        b"(c) Copyright 2002, Extron Electronics, SW AV\r\nIn5 All\r\nSig 1 0 1\r\nVmt1\r\nE10\r\n",
        ms(0),
    );
    assert_eq!(
        events(&mut m),
        [
            Event::Banner,
            Event::ExternalSelect { channel: 5 },
            Event::Signals(Signals {
                mask: 0b101,
                count: 3
            }),
            Event::Mute(true),
            Event::UnsolicitedError(Refusal::Extron(ExtronError::InvalidCommand)),
        ]
    );
    assert_eq!(m.current_channel(), Some(5));

    // Quiet mode: only selections and errors are reported.
    let mut q = Machine::new(Config {
        report_unsolicited: false,
        ..Config::default()
    });
    q.handle_bytes(b"(c) Extron\r\nSig 1\r\nVmt0\r\nIn2 All\r\n", ms(0));
    assert_eq!(events(&mut q), [Event::ExternalSelect { channel: 2 }]);
    assert_eq!(q.stats().ignored, 3);
}

#[test]
fn front_panel_change_while_pending_keeps_waiting() {
    let mut m = Machine::new(Config::default());
    m.select(3, ms(0)).unwrap();
    let _ = sent(&mut m);
    m.handle_bytes(b"In5 All\r\n", ms(10));
    assert_eq!(events(&mut m), [Event::ExternalSelect { channel: 5 }]);
    assert!(m.is_busy());
    m.handle_bytes(b"In3 All\r\n", ms(30));
    assert!(matches!(
        events(&mut m)[..],
        [Event::Selected(Selection { channel: 3, .. })]
    ));
}

#[test]
fn new_select_cancels_settling() {
    let mut m = Machine::new(Config::default());
    m.select(1, ms(0)).unwrap();
    m.handle_bytes(b"In1 All\r\n", ms(10));
    let _ = events(&mut m);
    m.select(2, ms(20)).unwrap();
    m.handle_timeout(ms(160));
    assert!(events(&mut m).is_empty(), "channel 1 never settles");
    m.handle_bytes(b"In2 All\r\n", ms(200));
    m.handle_timeout(ms(350));
    let ev = events(&mut m);
    assert_eq!(ev.last(), Some(&Event::Settled { channel: 2 }));
}

#[test]
fn extron_query() {
    let mut m = Machine::new(Config::default());
    m.query(ms(0)).unwrap();
    assert_eq!(sent(&mut m), [b"!".to_vec()]);
    m.handle_bytes(b"4\r\n", ms(5));
    assert_eq!(events(&mut m), [Event::Current { channel: Some(4) }]);
    assert_eq!(m.current_channel(), Some(4));
    m.query(ms(10)).unwrap();
    m.handle_bytes(b"0\r\n", ms(15));
    assert_eq!(events(&mut m), [Event::Current { channel: None }]);
    // A bare number with nothing pending is ignored.
    m.handle_bytes(b"6\r\n", ms(16));
    assert!(events(&mut m).is_empty());
    m.query(ms(20)).unwrap();
    for t in [520, 1020, 1520] {
        m.handle_timeout(ms(t));
    }
    assert_eq!(
        events(&mut m),
        [Event::QueryFailed {
            failure: Failure::Timeout
        }]
    );
}

#[test]
fn requests_refused() {
    let mut m = Machine::new(Config::default());
    assert_eq!(m.select(0, ms(0)), Err(RequestError::InvalidChannel(0)));
    assert_eq!(m.select(8, ms(0)), Err(RequestError::InvalidChannel(8)));
    m.select(1, ms(0)).unwrap();
    assert_eq!(m.select(2, ms(0)), Err(RequestError::Busy));
    assert_eq!(m.query(ms(0)), Err(RequestError::Busy));
    use ima_hal::Error as _;
    assert_eq!(
        RequestError::InvalidChannel(9).kind(),
        ima_hal::ErrorKind::InvalidArgument
    );
}

#[test]
fn extron_matrix_output() {
    let mut m = Machine::new(Config {
        dialect: Dialect::Extron {
            kind: TieKind::All,
            output: Some(1),
        },
        ..Config::default()
    });
    m.select(3, ms(0)).unwrap();
    assert_eq!(sent(&mut m), [b"3*1!".to_vec()]);
    m.handle_bytes(b"Out2 In3 All\r\n", ms(5));
    assert!(events(&mut m).is_empty(), "another output");
    m.handle_bytes(b"Out1 In3 All\r\n", ms(6));
    assert!(matches!(
        events(&mut m)[..],
        [Event::Selected(Selection { channel: 3, .. })]
    ));
}

#[test]
fn extron_garbage_before_reply_in_one_byte_reads() {
    let mut m = Machine::new(Config::default());
    m.select(3, ms(0)).unwrap();
    let _ = sent(&mut m);
    for b in b"\xff\x00junk\r\nIn3 All\r\n" {
        m.handle_bytes(&[*b], ms(50));
    }
    assert!(matches!(
        events(&mut m)[..],
        [Event::Selected(Selection { channel: 3, .. })]
    ));
    let s = m.stats();
    assert_eq!(s.parse_errors, 1, "the junk line");
    assert_eq!(s.framer.dropped_bytes, 2);
}

#[test]
fn kramer_select_with_echo() {
    let mut m = kramer(true);
    m.select(3, ms(0)).unwrap();
    assert_eq!(sent(&mut m), [std::vec![0x01, 0x83, 0x81, 0x81]]);
    // Noise, a message for another machine, then the echo split in two reads.
    m.handle_bytes(&[0xff, 0x41, 0x83, 0x81, 0x82, 0x41, 0x83], ms(10));
    assert!(events(&mut m).is_empty());
    m.handle_bytes(&[0x81, 0x81], ms(12));
    assert_eq!(
        events(&mut m),
        [Event::Selected(Selection {
            channel: 3,
            confirmed_at: ms(12),
            settled_at: ms(162),
        })]
    );
    // Front panel.
    m.handle_bytes(&[0x41, 0x85, 0x81, 0x81], ms(500));
    assert_eq!(events(&mut m), [Event::ExternalSelect { channel: 5 }]);
    assert_eq!(m.current_channel(), Some(5));
}

#[test]
fn kramer_timeout_and_error() {
    let mut m = kramer(true);
    m.select(2, ms(0)).unwrap();
    let _ = sent(&mut m);
    m.handle_timeout(ms(500));
    assert_eq!(sent(&mut m), [std::vec![0x01, 0x82, 0x81, 0x81]]);
    m.handle_bytes(&[0x50, 0x82, 0x81, 0x81], ms(600));
    assert_eq!(
        events(&mut m),
        [Event::SelectFailed {
            channel: 2,
            failure: Failure::Refused(Refusal::Kramer(2))
        }]
    );
    // Our own command echoed without the reply flag (loopback) is ignored.
    m.select(2, ms(700)).unwrap();
    m.handle_bytes(&[0x01, 0x82, 0x81, 0x81], ms(710));
    assert!(events(&mut m).is_empty());
    assert!(m.is_busy());
}

#[test]
fn kramer_without_replies_confirms_at_once() {
    let mut m = kramer(false);
    m.select(4, ms(100)).unwrap();
    assert_eq!(
        events(&mut m),
        [Event::Selected(Selection {
            channel: 4,
            confirmed_at: ms(100),
            settled_at: ms(250),
        })]
    );
    assert_eq!(sent(&mut m), [std::vec![0x01, 0x84, 0x81, 0x81]]);
    assert!(!m.is_busy());
    m.query(ms(300)).unwrap();
    assert!(sent(&mut m).is_empty());
    assert_eq!(events(&mut m), [Event::Current { channel: Some(4) }]);
}

#[test]
fn kramer_query() {
    let mut m = kramer(true);
    m.query(ms(0)).unwrap();
    assert_eq!(sent(&mut m), [std::vec![0x05, 0x80, 0x81, 0x81]]);
    m.handle_bytes(&[0x45, 0x86, 0x81, 0x81], ms(30));
    assert_eq!(events(&mut m), [Event::Current { channel: Some(6) }]);
}

#[test]
fn small_transmit_buffer_keeps_the_command() {
    let mut m = Machine::new(Config::default());
    m.select(3, ms(0)).unwrap();
    assert_eq!(m.poll_transmit(&mut [0u8; 1]), None);
    assert_eq!(sent(&mut m), [b"3!".to_vec()]);
}

#[test]
fn no_retries_configured_fails_on_first_timeout() {
    let mut m = Machine::new(Config {
        retries: 0,
        reply_timeout: Duration::from_millis(200),
        ..Config::default()
    });
    m.select(1, ms(0)).unwrap();
    assert_eq!(sent(&mut m), [b"1!".to_vec()]);
    m.handle_timeout(ms(200));
    assert!(sent(&mut m).is_empty());
    assert_eq!(
        events(&mut m),
        [Event::SelectFailed {
            channel: 1,
            failure: Failure::Timeout
        }]
    );
    assert_eq!(m.stats().retransmissions, 0);
}
