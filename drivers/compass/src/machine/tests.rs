// #[cfg(test)]: this whole file is a test module (declared `#[cfg(test)] mod tests;`).
//! Session tests in virtual time.

use super::*;
use std::string::String;
use std::vec::Vec;

fn ms(n: u64) -> Instant {
    Instant::from_millis(n)
}

fn sent(m: &mut Machine) -> Vec<String> {
    let mut out = Vec::new();
    let mut buf = [0u8; 32];
    while let Some(n) = m.poll_transmit(&mut buf) {
        out.push(String::from_utf8(buf[..n].to_vec()).unwrap());
    }
    out
}

fn events(m: &mut Machine) -> Vec<Event> {
    core::iter::from_fn(|| m.poll_event()).collect()
}

fn tcm2_config() -> Config {
    Config::for_dialect(Dialect::Tcm2 {
        sample_rate_hz: 8,
        output: Tcm2Format::Standard,
    })
}

/// A TCM2 standard line with a correct checksum.
fn tcm2_line(body: &str) -> Vec<u8> {
    let sum = crate::wire::checksum(body.as_bytes());
    std::format!("${body}*{sum:02X}\r\n").into_bytes()
}

fn headings(ev: &[Event]) -> Vec<Reading> {
    ev.iter()
        .filter_map(|e| match e {
            Event::Heading(s) => Some(s.value),
            _ => None,
        })
        .collect()
}

/// Drive a TCM2 session through its configuration; returns the time it ends at.
fn configured_tcm2(m: &mut Machine) -> Instant {
    m.start(ms(0));
    assert_eq!(sent(m), ["h\r"]);
    for (t, cmd) in [(100, "sdo=t\r"), (200, "sp=8\r"), (300, "go\r")] {
        assert_eq!(m.poll_timeout(), Some(ms(t)));
        m.handle_timeout(ms(t));
        assert_eq!(sent(m), [cmd]);
    }
    m.handle_bytes(&tcm2_line("C10.0E000"), ms(350));
    let ev = events(m);
    assert_eq!(ev.first(), Some(&Event::Configured));
    ms(350)
}

#[test]
fn nmea_listen_only() {
    let mut m = Machine::new(Config::for_dialect(Dialect::Nmea));
    m.start(ms(0));
    assert!(sent(&mut m).is_empty());
    // A plain NMEA source's rate is not known: long enough for one at 1 Hz.
    assert_eq!(m.poll_timeout(), Some(ms(2500)));
    m.handle_bytes(b"$HCHDM,238.5,M*25\r\n", ms(40));
    let ev = events(&mut m);
    assert_eq!(ev.len(), 2);
    assert_eq!(ev[0], Event::Configured);
    let Event::Heading(h) = ev[1] else { panic!() };
    assert_eq!(h.at, ms(40));
    assert!((h.value.heading.heading_rad - 238.5f64.to_radians()).abs() < 1e-12);
    assert_eq!(h.value.heading.reference, HeadingReference::Magnetic);
    assert_eq!(h.value.source, Source::Nmea(Talker(*b"HC")));
    assert_eq!(h.value.heading.calibration, None);
    // Now only the data watchdog is armed.
    assert_eq!(m.poll_timeout(), Some(ms(2040)));
}

#[test]
fn kvh_configures_with_prompts() {
    let mut m = Machine::new(Config::default());
    m.start(ms(0));
    assert_eq!(sent(&mut m), ["=t,0\r"]);
    m.handle_bytes(b">", ms(20));
    assert_eq!(sent(&mut m), ["=r,600\r"]);
    m.handle_bytes(b">", ms(40));
    assert!(sent(&mut m).is_empty());
    assert_eq!(m.current_job(), Some(Job::Configure));
    m.handle_bytes(b"$HCHDG,238.5,0.0,E,12.3,W*6C\r\n", ms(100));
    let ev = events(&mut m);
    assert_eq!(ev[0], Event::Configured);
    let r = headings(&ev)[0];
    assert!((r.heading.variation_rad.unwrap() + 12.3f64.to_radians()).abs() < 1e-12);
    assert_eq!(r.heading.deviation_rad, Some(0.0));
    let t = r.heading.true_rad().unwrap().to_degrees();
    assert!((t - 226.2).abs() < 1e-9);
    assert_eq!(m.current_job(), None);
}

/// At one reading a second the first heading comes up to 1 s after the rate is set: the
/// configuration waits two periods for it (it gave up after 500 ms, so `--rate 1` always
/// failed).
#[test]
fn a_slow_rate_gets_two_periods_for_its_first_reading() {
    let mut m = Machine::new(Config::for_dialect(Dialect::KvhC100 {
        rate_per_minute: 60,
    }));
    m.start(ms(0));
    assert_eq!(sent(&mut m), ["=t,0\r"]);
    m.handle_bytes(b">", ms(20));
    assert_eq!(sent(&mut m), ["=r,60\r"]);
    m.handle_bytes(b">", ms(40));
    assert_eq!(m.poll_timeout(), Some(ms(2040)));
    m.handle_timeout(ms(900));
    m.handle_bytes(b"$HCHDG,238.5,0.0,E,12.3,W*6C\r\n", ms(950));
    assert_eq!(events(&mut m).first(), Some(&Event::Configured));
}

#[test]
fn kvh_prompt_timeout_retries_then_fails() {
    let mut m = Machine::new(Config::default());
    m.start(ms(0));
    assert_eq!(sent(&mut m), ["=t,0\r"]);
    // Early call does nothing.
    m.handle_timeout(ms(499));
    assert!(sent(&mut m).is_empty());
    m.handle_timeout(ms(500));
    assert_eq!(sent(&mut m), ["=t,0\r"]);
    // The second command also gets retries from the same budget.
    m.handle_bytes(b">", ms(600));
    assert_eq!(sent(&mut m), ["=r,600\r"]);
    m.handle_timeout(ms(1100));
    assert_eq!(sent(&mut m), ["=r,600\r"]);
    m.handle_timeout(ms(1600));
    assert!(sent(&mut m).is_empty());
    assert_eq!(
        events(&mut m),
        [Event::JobFailed {
            job: Job::Configure,
            step: 1
        }]
    );
    // Then the data watchdog runs from the failure.
    assert_eq!(m.poll_timeout(), Some(ms(3600)));
    m.handle_timeout(ms(3600));
    assert_eq!(events(&mut m), [Event::DataTimeout]);
    assert_eq!(m.poll_timeout(), None, "reported once");
}

#[test]
fn tcm2_configuration_sequence_and_standard_line() {
    let mut m = Machine::new(tcm2_config());
    let t = configured_tcm2(&mut m);
    m.handle_bytes(
        &tcm2_line("C328.3P28.4R-12.4X55.11Y12.33Z-18.43T22.3E001"),
        t + Duration::from_millis(125),
    );
    let ev = events(&mut m);
    assert_eq!(ev[0], Event::DeviceError { code: 1 });
    let r = headings(&ev)[0];
    assert!((r.heading.heading_rad.to_degrees() - 328.3).abs() < 1e-9);
    assert!((r.pitch_rad.unwrap().to_degrees() - 28.4).abs() < 1e-9);
    assert!((r.roll_rad.unwrap().to_degrees() + 12.4).abs() < 1e-9);
    assert_eq!(r.temperature_c, Some(22.3));
    assert_eq!(r.error_code, Some(1));
    assert_eq!(r.source, Source::Tcm2);
    let q = r.heading.calibration.unwrap();
    assert_eq!(q.horizontal_score, None);
    assert!(!q.auto_calibration);
    // Same code again: no second DeviceError.
    m.handle_bytes(&tcm2_line("C1.0E001"), t + Duration::from_millis(250));
    assert!(
        !events(&mut m)
            .iter()
            .any(|e| matches!(e, Event::DeviceError { .. }))
    );
}

#[test]
fn tcm2_nmea_output_option() {
    let mut m = Machine::new(Config::for_dialect(Dialect::Tcm2 {
        sample_rate_hz: 4,
        output: Tcm2Format::Nmea,
    }));
    m.start(ms(0));
    let mut all = sent(&mut m);
    for t in [100, 200, 300] {
        m.handle_timeout(ms(t));
        all.extend(sent(&mut m));
    }
    assert_eq!(all, ["h\r", "sdo=n\r", "sp=4\r", "go\r"]);
    m.handle_bytes(b"$HCHDM,238.5,M*25\r\n", ms(310));
    assert_eq!(events(&mut m)[0], Event::Configured);
}

#[test]
fn tcm2_no_data_after_go_restarts_the_script() {
    let mut m = Machine::new(tcm2_config());
    m.start(ms(0));
    for t in [100, 200, 300] {
        m.handle_timeout(ms(t));
    }
    assert_eq!(sent(&mut m).len(), 4);
    assert_eq!(m.poll_timeout(), Some(ms(800)));
    m.handle_timeout(ms(800));
    assert_eq!(sent(&mut m), ["h\r"], "whole script again");
}

#[test]
fn user_calibration_round() {
    let mut m = Machine::new(tcm2_config());
    let t0 = configured_tcm2(&mut m);
    let at = |d: u64| t0 + Duration::from_millis(d);
    m.start_user_calibration(at(0)).unwrap();
    assert_eq!(m.start_user_calibration(at(0)), Err(RequestError::Busy));
    assert_eq!(sent(&mut m), ["h\r"]);
    m.handle_timeout(at(100));
    assert_eq!(sent(&mut m), ["mpcal=e\r"]);
    m.handle_timeout(at(200));
    assert_eq!(sent(&mut m), ["go\r"]);
    m.handle_bytes(&tcm2_line("C90.0"), at(250));
    assert_eq!(events(&mut m)[0], Event::CalibrationStarted);
    assert!(m.is_user_calibrating());

    m.stop_user_calibration(at(5000)).unwrap();
    assert_eq!(sent(&mut m), ["h\r"]);
    m.handle_timeout(at(5100));
    assert_eq!(sent(&mut m), ["mpcal=d\r"]);
    assert_eq!(m.poll_timeout(), Some(at(7100)), "score timeout");
    m.handle_bytes(b"H9V8M0.5\r\n", at(5300));
    assert_eq!(sent(&mut m), ["go\r"]);
    m.handle_bytes(&tcm2_line("C91.0"), at(5400));
    let ev = events(&mut m);
    let score = CalScore::parse(b"H9V8M0.5").unwrap();
    assert_eq!(ev[0], Event::CalibrationFinished { score: Some(score) });
    assert!(!m.is_user_calibrating());
    let q = headings(&ev)[0].heading.calibration.unwrap();
    assert_eq!(q.horizontal_score, Some(9));
    assert_eq!(q.vertical_score, Some(8));
    assert_eq!(q.distortion, Some(0.5));
}

#[test]
fn stop_calibration_without_score() {
    let mut m = Machine::new(tcm2_config());
    let t0 = configured_tcm2(&mut m);
    let at = |d: u64| t0 + Duration::from_millis(d);
    m.start_user_calibration(at(0)).unwrap();
    m.handle_timeout(at(100));
    m.handle_timeout(at(200));
    m.handle_bytes(&tcm2_line("C90.0"), at(250));
    let _ = events(&mut m);
    let _ = sent(&mut m);
    m.stop_user_calibration(at(1000)).unwrap();
    m.handle_timeout(at(1100));
    assert_eq!(sent(&mut m), ["h\r", "mpcal=d\r"]);
    m.handle_timeout(at(3099));
    assert!(sent(&mut m).is_empty());
    m.handle_timeout(at(3100));
    assert_eq!(sent(&mut m), ["go\r"]);
    m.handle_bytes(&tcm2_line("C90.0"), at(3150));
    assert_eq!(
        events(&mut m)[0],
        Event::CalibrationFinished { score: None }
    );
}

#[test]
fn auto_calibration_and_clear() {
    let mut m = Machine::new(tcm2_config());
    let t0 = configured_tcm2(&mut m);
    let at = |d: u64| t0 + Duration::from_millis(d);
    m.set_auto_calibration(true, at(0)).unwrap();
    m.handle_timeout(at(100));
    m.handle_timeout(at(200));
    assert_eq!(sent(&mut m), ["h\r", "autocal=e\r", "go\r"]);
    m.handle_bytes(&tcm2_line("C1.0"), at(210));
    let ev = events(&mut m);
    assert_eq!(ev[0], Event::AutoCalibration(true));
    assert!(
        headings(&ev)[0]
            .heading
            .calibration
            .unwrap()
            .auto_calibration
    );

    m.clear_calibration(at(1000)).unwrap();
    m.handle_timeout(at(1100));
    m.handle_timeout(at(1200));
    assert_eq!(sent(&mut m), ["h\r", "cc\r", "go\r"]);
    m.handle_bytes(&tcm2_line("C1.0"), at(1210));
    assert_eq!(events(&mut m)[0], Event::CalibrationCleared);
}

#[test]
fn requests_refused() {
    let mut k = Machine::new(Config::default());
    assert_eq!(
        k.start_user_calibration(ms(0)),
        Err(RequestError::Unsupported)
    );
    assert_eq!(
        k.set_auto_calibration(true, ms(0)),
        Err(RequestError::Unsupported)
    );
    let mut m = Machine::new(tcm2_config());
    m.start(ms(0));
    assert_eq!(m.clear_calibration(ms(1)), Err(RequestError::Busy));
    let mut m = Machine::new(tcm2_config());
    assert_eq!(
        m.stop_user_calibration(ms(0)),
        Err(RequestError::NotCalibrating)
    );
    use ima_hal::Error as _;
    assert_eq!(RequestError::Busy.kind(), ima_hal::ErrorKind::Other);
}

#[test]
fn data_watchdog_reports_once_and_rearms() {
    let mut m = Machine::new(Config::for_dialect(Dialect::Nmea));
    m.start(ms(0));
    m.handle_bytes(b"$HCHDT,238.5,T*25\r\n", ms(100));
    let _ = events(&mut m);
    assert_eq!(m.poll_timeout(), Some(ms(2100)));
    m.handle_timeout(ms(2099));
    assert!(events(&mut m).is_empty());
    m.handle_timeout(ms(2100));
    assert_eq!(events(&mut m), [Event::DataTimeout]);
    m.handle_timeout(ms(9000));
    assert!(events(&mut m).is_empty());
    m.handle_bytes(b"$HCHDT,238.5,T*25\r\n", ms(9500));
    let ev = events(&mut m);
    assert_eq!(headings(&ev)[0].heading.reference, HeadingReference::True);
    assert_eq!(m.poll_timeout(), Some(ms(11500)));
}

#[test]
fn garbage_is_counted_and_good_lines_still_arrive() {
    let mut m = Machine::new(Config::for_dialect(Dialect::Nmea));
    m.start(ms(0));
    let stream: &[u8] =
        b"\x00\xffnoise\r\n$HCHDM,238.5,M*26\r\n$HCHDM,238.5,M*25\r\n$GPGGA,1*4B\r\n$HCHDT,1,T";
    for chunk in stream.chunks(3) {
        m.handle_bytes(chunk, ms(10));
    }
    m.handle_bytes(b"*00\r\n$HCHDT,238.5,T*25\r\n", ms(20));
    let ev = events(&mut m);
    assert_eq!(headings(&ev).len(), 2);
    let s = m.stats();
    assert_eq!(s.framer.bad_checksums, 2);
    assert!(s.parse_errors >= 2, "noise line and GGA: {s:?}");
    assert_eq!(s.headings, 2);
}

#[test]
fn small_transmit_buffer_keeps_the_command() {
    let mut m = Machine::new(Config::default());
    m.start(ms(0));
    assert_eq!(m.poll_transmit(&mut [0u8; 3]), None);
    assert_eq!(sent(&mut m), ["=t,0\r"]);
}

#[test]
fn unpolled_events_drop_oldest() {
    let mut m = Machine::new(Config::for_dialect(Dialect::Nmea));
    for i in 0..40 {
        m.handle_bytes(b"$HCHDM,238.5,M*25\r\n", ms(i));
    }
    let ev = events(&mut m);
    assert_eq!(ev.len(), EVENT_CAPACITY);
    assert_eq!(m.stats().events_dropped, 40 - EVENT_CAPACITY as u32);
    let Event::Heading(last) = ev[EVENT_CAPACITY - 1] else {
        panic!()
    };
    assert_eq!(last.at, ms(39));
}

#[test]
fn tcm2_data_before_go_does_not_confirm_and_retries_run_out() {
    let mut m = Machine::new(Config {
        retries: 1,
        ..tcm2_config()
    });
    m.start(ms(0));
    // The device was still streaming when `h` went out: that data is not the confirmation.
    m.handle_bytes(&tcm2_line("C10.0"), ms(50));
    assert!(!events(&mut m).contains(&Event::Configured));
    for t in [100, 200, 300] {
        m.handle_timeout(ms(t));
    }
    assert_eq!(sent(&mut m), ["h\r", "sdo=t\r", "sp=8\r", "go\r"]);
    // Silence after `go`: one retry of the whole script, then failure at the `go` step.
    m.handle_timeout(ms(800));
    for t in [900, 1000, 1100] {
        m.handle_timeout(ms(t));
    }
    assert_eq!(sent(&mut m), ["h\r", "sdo=t\r", "sp=8\r", "go\r"]);
    m.handle_timeout(ms(1600));
    let ev = events(&mut m);
    assert_eq!(
        ev,
        [Event::JobFailed {
            job: Job::Configure,
            step: 3
        }]
    );
    assert_eq!(m.current_job(), None);
    // Requests work again after a failed job.
    m.set_auto_calibration(true, ms(1700)).unwrap();
    assert_eq!(sent(&mut m), ["h\r"]);
}

#[test]
fn nmea_sentences_do_not_configure_a_tcm2() {
    let mut m = Machine::new(tcm2_config());
    m.start(ms(0));
    let _ = sent(&mut m);
    let sum = crate::wire::checksum(b"HCHDG,101.1,,,,");
    let line = std::format!("$HCHDG,101.1,,,,*{sum:02X}\r\n");
    let mut t = 0;
    let mut failed = None;
    while t < 10_000 && failed.is_none() {
        t += 50;
        m.handle_bytes(line.as_bytes(), ms(t));
        m.handle_timeout(ms(t));
        let _ = sent(&mut m);
        for e in events(&mut m) {
            assert!(!matches!(e, Event::Heading(_) | Event::Configured), "{e:?}");
            if let Event::JobFailed { job, .. } = e {
                failed = Some(job);
            }
        }
    }
    assert_eq!(failed, Some(Job::Configure));
    assert_eq!(
        m.foreign_line(),
        Some(ForeignLine::Nmea {
            talker: Talker::MAGNETIC_COMPASS,
            sentence: *b"HDG"
        })
    );
    assert!(m.stats().foreign_lines > 10);
    assert_eq!(m.stats().headings, 0);
    assert_eq!(
        std::format!("{}", m.foreign_line().unwrap()),
        "NMEA ($HCHDG…)"
    );
}

#[test]
fn tcm2_lines_are_foreign_to_an_nmea_source() {
    let mut m = Machine::new(Config::for_dialect(Dialect::Nmea));
    m.start(ms(0));
    m.handle_bytes(&tcm2_line("C10.0E000"), ms(10));
    assert!(events(&mut m).is_empty());
    assert_eq!(m.foreign_line(), Some(ForeignLine::Tcm2));
    assert_eq!(m.stats().bytes as usize, tcm2_line("C10.0E000").len());
}
