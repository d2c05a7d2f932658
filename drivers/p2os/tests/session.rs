//! The client session in virtual time, against a scripted robot built from `wire`.

use core::time::Duration;

use ima_hal::Instant;
use ima_hal::base::VelocityCommand;
use ima_p2os::machine::{DisconnectReason, Event, SessionState};
use ima_p2os::wire::{self, Command, IntCommand, Packet, Sip, SonarRaw};
use ima_p2os::{Config, Machine};

fn ms(t: u64) -> Instant {
    Instant::from_millis(t)
}

fn frame(p: &Packet<'_>) -> Vec<u8> {
    let mut buf = [0u8; 300];
    let n = p.emit(&mut buf).unwrap();
    buf[..n].to_vec()
}

/// Everything the session sends at `now` (spacing permitting), as parsed commands.
fn sent(s: &mut Machine, now: Instant) -> Vec<Command<'static>> {
    let mut out = Vec::new();
    let mut buf = [0u8; 300];
    let mut t = now;
    // Step through the pacing gaps within a 50 ms window.
    for _ in 0..10 {
        while let Some(n) = s.poll_transmit(t, &mut buf) {
            let cmd = wire::parse_host_frame(&buf[..n]).unwrap();
            out.push(match cmd {
                Command::Str(..) | Command::Other { .. } => Command::Stop, // not used here
                c => to_static(c),
            });
        }
        t = t + Duration::from_millis(5);
    }
    out
}

fn to_static(c: Command<'_>) -> Command<'static> {
    match c {
        Command::Sync0 => Command::Sync0,
        Command::Sync1 => Command::Sync1,
        Command::Sync2 => Command::Sync2,
        Command::SetOdometry => Command::SetOdometry,
        Command::Stop => Command::Stop,
        Command::EStop => Command::EStop,
        Command::Int(i, v) => Command::Int(i, v),
        Command::Vel2 { left, right } => Command::Vel2 { left, right },
        _ => Command::Stop,
    }
}

fn events(s: &mut Machine) -> Vec<Event> {
    std::iter::from_fn(|| s.poll_event()).collect()
}

fn sip(x: u16, y: u16, th: i16, flags: u16) -> Sip {
    Sip {
        xpos: x,
        ypos: y,
        thpos: th,
        battery: 125,
        flags,
        ..Sip::default()
    }
}

/// The x (m) of the last odometry state among the machine's pending events.
fn last_x(s: &mut Machine) -> Option<f64> {
    events(s)
        .into_iter()
        .filter_map(|e| match e {
            Event::State(st) => Some(st.odometry.value.x_m()),
            _ => None,
        })
        .next_back()
}

fn feed(s: &mut Machine, p: &Packet<'_>, now: Instant) {
    s.handle_bytes(&frame(p), now);
}

const P2AT_REPLY: Packet<'static> = Packet::SyncReply {
    name: b"Skeeter",
    class: b"Pioneer",
    subclass: b"p2at",
};

/// Run the handshake to an open session at t = 0..; returns the time after the first SIP.
fn open(s: &mut Machine) -> Instant {
    s.connect(ms(0));
    // STOP first: on a session a dead client left open, SYNC0 alone would revive the old
    // setpoints (see `a_handshake_into_a_stale_session_never_revives_its_motion`).
    assert_eq!(sent(s, ms(0)), vec![Command::Stop, Command::Sync0]);
    feed(s, &Packet::SyncEcho(0), ms(10));
    assert_eq!(sent(s, ms(10)), vec![Command::Sync1]);
    feed(s, &Packet::SyncEcho(1), ms(20));
    assert_eq!(sent(s, ms(20)), vec![Command::Sync2]);
    feed(s, &P2AT_REPLY, ms(30));
    assert_eq!(sent(s, ms(30)), vec![Command::OPEN]);
    assert_eq!(s.state(), SessionState::Opening);
    feed(s, &Packet::Sip(sip(100, 100, 0, 0)), ms(100));
    assert_eq!(s.state(), SessionState::Open);
    ms(100)
}

#[test]
fn handshake_opens_and_configures_the_robot() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    let evs = events(&mut s);
    assert_eq!(evs[0], Event::SetBaud(9600));
    let connected = evs
        .iter()
        .find_map(|e| match e {
            Event::Connected {
                identity,
                params,
                baud,
            } => Some((identity.clone(), *params, *baud)),
            _ => None,
        })
        .expect("connected");
    assert_eq!(connected.0.subclass.as_str(), "p2at");
    assert_eq!(connected.0.name.as_str(), "Skeeter");
    assert_eq!(connected.1.subclass, "p2at");
    assert_eq!(connected.2, 9600);
    // After opening: sonar on, one CONFIG requested.
    assert_eq!(
        sent(&mut s, t),
        vec![
            Command::Int(IntCommand::Sonar, 1),
            Command::Int(IntCommand::Config, 1)
        ]
    );
}

#[test]
fn probes_the_next_baud_after_silence() {
    let mut s = Machine::new(Config::default());
    s.connect(ms(0));
    assert_eq!(events(&mut s), vec![Event::SetBaud(9600)]);
    assert_eq!(sent(&mut s, ms(0)), vec![Command::Stop, Command::Sync0]);
    // First silent attempt: CLOSE (to dislodge a stuck session) then SYNC0 again, same rate.
    let t1 = s.poll_timeout().unwrap();
    assert_eq!(t1, ms(300));
    s.handle_timeout(t1);
    assert_eq!(
        sent(&mut s, t1),
        vec![Command::Stop, Command::CLOSE, Command::Sync0]
    );
    assert!(events(&mut s).is_empty());
    // Second silent attempt: next rate.
    let t2 = s.poll_timeout().unwrap();
    s.handle_timeout(t2);
    assert_eq!(events(&mut s), vec![Event::SetBaud(19200)]);
    let mut bauds = vec![];
    let mut t = t2;
    for _ in 0..8 {
        let _ = sent(&mut s, t);
        t = s.poll_timeout().unwrap();
        s.handle_timeout(t);
        for e in events(&mut s) {
            if let Event::SetBaud(b) = e {
                bauds.push(b);
            }
        }
    }
    assert_eq!(bauds, vec![38400, 57600, 115200, 9600]);
}

#[test]
fn gives_up_after_max_sweeps() {
    let mut s = Machine::new(Config {
        max_sweeps: Some(1),
        ..Config::default()
    });
    s.connect(ms(0));
    let mut t = ms(0);
    let mut failed = false;
    for _ in 0..20 {
        let _ = sent(&mut s, t);
        let Some(next) = s.poll_timeout() else { break };
        t = next;
        s.handle_timeout(t);
        failed |= events(&mut s).contains(&Event::HandshakeFailed);
    }
    assert!(failed);
    assert_eq!(s.state(), SessionState::Failed);
    // 5 rates × 2 attempts × 300 ms.
    assert_eq!(t, ms(3000));
}

#[test]
fn stale_open_session_is_closed_then_resynced() {
    let mut s = Machine::new(Config::default());
    s.connect(ms(0));
    let _ = sent(&mut s, ms(0));
    // The robot was left open: SYNC0 is a PULSE to it and SIPs keep coming.
    feed(&mut s, &Packet::Sip(sip(1, 1, 0, 1)), ms(50));
    assert_eq!(s.state(), SessionState::ClosingStale);
    assert_eq!(sent(&mut s, ms(50)), vec![Command::CLOSE]);
    // More SIPs during the settle time are ignored.
    feed(&mut s, &Packet::Sip(sip(1, 1, 0, 1)), ms(100));
    assert_eq!(s.poll_timeout(), Some(ms(450)));
    s.handle_timeout(ms(450));
    assert!(events(&mut s).contains(&Event::FlushInput));
    assert_eq!(sent(&mut s, ms(450)), vec![Command::Stop, Command::Sync0]);
    assert_eq!(s.state(), SessionState::Syncing);
    // Closed while a stale session is being closed: STOP and CLOSE at the line's rate, where
    // the robot was just heard.
    let mut s = Machine::new(Config::default());
    s.connect(ms(0));
    let _ = sent(&mut s, ms(0));
    feed(&mut s, &Packet::Sip(sip(1, 1, 0, 1)), ms(50));
    assert_eq!(s.state(), SessionState::ClosingStale);
    let _ = events(&mut s);
    s.close();
    assert!(
        !events(&mut s)
            .iter()
            .any(|e| matches!(e, Event::SetBaud(_)))
    );
    assert_eq!(sent(&mut s, ms(50)), vec![Command::Stop, Command::CLOSE]);
}

#[test]
fn out_of_sequence_reply_restarts_at_sync0() {
    let mut s = Machine::new(Config::default());
    s.connect(ms(0));
    let _ = sent(&mut s, ms(0));
    feed(&mut s, &Packet::SyncEcho(1), ms(10));
    assert_eq!(sent(&mut s, ms(10)), vec![Command::Stop, Command::Sync0]);
}

#[test]
fn unknown_subclass_is_an_error_unless_overridden() {
    let reply = Packet::SyncReply {
        name: b"X",
        class: b"Pioneer",
        subclass: b"p9zz",
    };
    let mut s = Machine::new(Config::default());
    s.connect(ms(0));
    feed(&mut s, &Packet::SyncEcho(0), ms(1));
    feed(&mut s, &Packet::SyncEcho(1), ms(2));
    feed(&mut s, &reply, ms(3));
    assert_eq!(s.state(), SessionState::Failed);
    assert!(
        events(&mut s)
            .iter()
            .any(|e| matches!(e, Event::UnsupportedRobot(id) if id.subclass.as_str() == "p9zz"))
    );

    let mut s = Machine::new(Config {
        params_override: Some(ima_p2os::params::P2DX),
        ..Config::default()
    });
    s.connect(ms(0));
    feed(&mut s, &Packet::SyncEcho(0), ms(1));
    feed(&mut s, &Packet::SyncEcho(1), ms(2));
    feed(&mut s, &reply, ms(3));
    assert_eq!(s.state(), SessionState::Opening);
    assert_eq!(s.params().map(|p| p.subclass), Some("p2dx"));
}

#[test]
fn keepalive_keeps_the_watchdog_fed() {
    let mut s = Machine::new(Config::default());
    let mut t = open(&mut s);
    let mut last_tx = t;
    let _ = sent(&mut s, t);
    // 5 s of SIPs at 10 Hz, no caller commands: the longest gap between frames sent stays
    // well under the robot's 2 s watchdog.
    let mut max_gap = Duration::ZERO;
    let mut pulses = 0;
    while t < ms(5000) {
        t = t + Duration::from_millis(100);
        feed(&mut s, &Packet::Sip(sip(100, 100, 0, 0)), t);
        if s.poll_timeout().is_some_and(|d| d <= t) {
            s.handle_timeout(t);
        }
        for c in sent(&mut s, t) {
            pulses += usize::from(c == Command::PULSE);
            max_gap = max_gap.max(t.saturating_duration_since(last_tx));
            last_tx = t;
        }
    }
    assert!(pulses >= 10, "pulses {pulses}");
    assert!(max_gap <= Duration::from_millis(500), "gap {max_gap:?}");
}

#[test]
fn caller_going_quiet_stops_the_robot() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    let _ = sent(&mut s, t);
    s.set_velocity(VelocityCommand::new(0.3, -0.5), t).unwrap();
    assert_eq!(
        sent(&mut s, t),
        vec![
            Command::Int(IntCommand::Vel, 300),
            Command::Int(IntCommand::RVel, -29)
        ]
    );
    let deadline = t + Duration::from_millis(1000);
    assert!(s.poll_timeout().unwrap() <= deadline);
    // SIPs keep coming, the caller says nothing.
    let mut now = t;
    while now < deadline {
        now = now + Duration::from_millis(100);
        feed(&mut s, &Packet::Sip(sip(100, 100, 0, 1)), now);
        s.handle_timeout(now);
        let _ = sent(&mut s, now);
    }
    let evs = events(&mut s);
    assert!(evs.contains(&Event::CommandTimeout), "{evs:?}");
    assert_eq!(s.stats().command_timeouts, 1);
}

#[test]
fn velocity_is_clamped_and_latest_wins_in_the_queue() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    let _ = sent(&mut s, t);
    s.set_velocity(VelocityCommand::new(0.1, 0.0), t).unwrap();
    s.set_velocity(VelocityCommand::new(9.0, 100.0), t).unwrap();
    assert_eq!(
        sent(&mut s, t),
        vec![
            Command::Int(IntCommand::Vel, 1200),
            Command::Int(IntCommand::RVel, 300)
        ]
    );
    assert_eq!(
        s.set_velocity(VelocityCommand::new(f64::NAN, 0.0), t),
        Err(ima_p2os::SessionError::InvalidArgument)
    );
}

#[test]
fn commands_before_connect_are_refused() {
    let mut s = Machine::new(Config::default());
    assert_eq!(
        s.set_velocity(VelocityCommand::new(0.1, 0.0), ms(0)),
        Err(ima_p2os::SessionError::NotConnected)
    );
    assert_eq!(
        s.enable_motors(true, ms(0)),
        Err(ima_p2os::SessionError::NotConnected)
    );
}

#[test]
fn motors_enable_is_confirmed_by_flags_or_refused() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    let _ = sent(&mut s, t);
    let _ = events(&mut s);
    s.enable_motors(true, t).unwrap();
    assert_eq!(sent(&mut s, t), vec![Command::enable(true)]);
    feed(
        &mut s,
        &Packet::Sip(sip(100, 100, 0, 1)),
        t + Duration::from_millis(100),
    );
    assert!(events(&mut s).contains(&Event::MotorsEnabled(true)));

    // A robot with its E-stop engaged never sets the flag.
    let mut s = Machine::new(Config::default());
    let mut now = open(&mut s);
    let _ = sent(&mut s, now);
    s.enable_motors(true, now).unwrap();
    let mut enables = 0;
    let mut refused = false;
    for _ in 0..30 {
        for c in sent(&mut s, now) {
            enables += usize::from(c == Command::enable(true));
        }
        now = now + Duration::from_millis(100);
        feed(&mut s, &Packet::Sip(sip(100, 100, 0, 0)), now);
        s.handle_timeout(now);
        refused |= events(&mut s).contains(&Event::MotorsRefused);
    }
    assert!(refused);
    assert_eq!(enables, 3);
}

#[test]
fn enabling_motors_that_are_already_on_is_confirmed() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    feed(
        &mut s,
        &Packet::Sip(sip(100, 100, 0, 1)),
        t + Duration::from_millis(100),
    );
    let _ = events(&mut s);
    s.enable_motors(true, t + Duration::from_millis(150))
        .unwrap();
    feed(
        &mut s,
        &Packet::Sip(sip(100, 100, 0, 1)),
        t + Duration::from_millis(200),
    );
    assert!(events(&mut s).contains(&Event::MotorsEnabled(true)));
}

#[test]
fn link_loss_is_detected_and_the_session_reconnects_at_the_same_rate() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    let _ = sent(&mut s, t);
    let _ = events(&mut s);
    // No SIP for 700 ms.
    let lost_at = s
        .poll_timeout()
        .unwrap()
        .max(t + Duration::from_millis(700));
    let mut now = t;
    while now < lost_at {
        now = s.poll_timeout().unwrap();
        s.handle_timeout(now);
        let _ = sent(&mut s, now);
    }
    assert!(events(&mut s).contains(&Event::Disconnected(DisconnectReason::LinkLost)));
    assert_eq!(s.state(), SessionState::Syncing);
    // The robot comes back: the handshake completes at the old rate.
    feed(
        &mut s,
        &Packet::SyncEcho(0),
        now + Duration::from_millis(10),
    );
    feed(
        &mut s,
        &Packet::SyncEcho(1),
        now + Duration::from_millis(20),
    );
    feed(&mut s, &P2AT_REPLY, now + Duration::from_millis(30));
    feed(
        &mut s,
        &Packet::Sip(sip(5, 5, 0, 0)),
        now + Duration::from_millis(100),
    );
    assert!(s.is_open());
    assert_eq!(s.stats().reconnects, 1);
}

#[test]
fn odometry_unwraps_15_bit_positions_t22() {
    assert_eq!(ima_p2os::machine::unwrap15(32760, 5), 13);
    assert_eq!(ima_p2os::machine::unwrap15(5, 32760), -13);
    assert_eq!(ima_p2os::machine::unwrap12(2047, -2048), 1);
    let mut s = Machine::new(Config::default());
    s.connect(ms(0));
    feed(&mut s, &Packet::SyncEcho(0), ms(1));
    feed(&mut s, &Packet::SyncEcho(1), ms(2));
    feed(&mut s, &P2AT_REPLY, ms(3));
    feed(&mut s, &Packet::Sip(sip(32760, 0, 0, 0)), ms(100));
    feed(&mut s, &Packet::Sip(sip(5, 0, 0, 0)), ms(200));
    let x = last_x(&mut s).unwrap();
    assert!((x - 0.01716).abs() < 1e-9, "x = {x}");
}

#[test]
fn t20_sip_state_in_si_units() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    let _ = events(&mut s);
    let mut p = sip(100, 100, 0, 1);
    p.left_vel = -50;
    p.right_vel = 50;
    p.sonars
        .push(SonarRaw {
            index: 0,
            range: 1866,
        })
        .unwrap();
    p.sonars
        .push(SonarRaw {
            index: 7,
            range: 3731,
        })
        .unwrap();
    p.stall_bumpers = 0x0201; // front bumper 0 + left stall
    feed(&mut s, &Packet::Sip(p), t + Duration::from_millis(100));
    let st = events(&mut s)
        .into_iter()
        .find_map(|e| match e {
            Event::State(st) => Some(st),
            _ => None,
        })
        .unwrap();
    assert!((st.odometry.value.omega_rad_s - 0.17).abs() < 1e-9);
    assert_eq!(st.odometry.value.v_m_s, 0.0);
    assert!((st.power.value.battery_v - 12.5).abs() < 1e-9);
    assert!((st.sonar.value.get(0).unwrap().range_m - 0.500088).abs() < 1e-6);
    assert!((st.sonar.value.get(7).unwrap().range_m - 0.999908).abs() < 1e-6);
    assert!(st.new_sonar && st.motors_enabled);
    assert_eq!(st.bumpers.value.front, 1);
    assert!(st.bumpers.value.left_stall && !st.bumpers.value.right_stall);
}

#[test]
fn implausible_sips_are_dropped_and_counted() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    // A position jump of 2000 units (2.6 m) in 100 ms.
    feed(
        &mut s,
        &Packet::Sip(sip(2100, 100, 0, 0)),
        t + Duration::from_millis(100),
    );
    // A battery of 0.3 V.
    let mut p = sip(100, 100, 0, 0);
    p.battery = 3;
    feed(&mut s, &Packet::Sip(p), t + Duration::from_millis(200));
    // A sonar index beyond the 16-transducer ring.
    let mut p = sip(100, 100, 0, 0);
    p.sonars
        .push(SonarRaw {
            index: 20,
            range: 100,
        })
        .unwrap();
    feed(&mut s, &Packet::Sip(p), t + Duration::from_millis(300));
    assert_eq!(s.stats().implausible_sips, 3);
    assert_eq!(s.stats().sips, 1);
}

/// In a simulated world running 20 times faster than the driver's clock, the robot really
/// covers 20 times more ground between SIPs: with `motion_time_scale` set, that motion is
/// integrated; without it every such SIP is rejected (and the odometry would stand still).
#[test]
fn a_sped_up_world_widens_the_jump_check_by_its_factor() {
    // 460 units (0.6 m) per 100 ms: 0.3 m/s in a world ×20 (P2-AT: 1.32 mm per position
    // unit; its jump check allows 1.5 × 1.2 m/s × 100 ms + 50 mm = 230 mm at ×1).
    let run_steps = |scale: f64, step: u16| {
        let mut s = Machine::new(Config {
            motion_time_scale: scale,
            ..Config::default()
        });
        let mut t = open(&mut s);
        let _ = events(&mut s);
        for i in 1..=5u16 {
            t = t + Duration::from_millis(100);
            feed(&mut s, &Packet::Sip(sip(100 + step * i, 100, 0, 0)), t);
        }
        let x = last_x(&mut s).unwrap_or(0.0);
        (x, s.stats().implausible_sips)
    };
    let run = |scale: f64| run_steps(scale, 460);
    let (x, rejected) = run(20.0);
    assert_eq!(rejected, 0);
    assert!((x - 5.0 * 460.0 * 1.32 / 1000.0).abs() < 1e-9, "x = {x}");
    let (x, rejected) = run(1.0);
    assert!(rejected >= 3, "{rejected} rejected");
    assert!(x < 1.0, "x = {x}");
    // A scale below 1 or not finite is the robot's own: 180 mm steps pass at ×1 (taken
    // as 0.5 they would not: 140 mm; NaN would reject everything).
    for scale in [1.0, 0.5, f64::NAN, f64::INFINITY] {
        assert_eq!(run_steps(scale, 136).1, 0, "scale {scale}");
    }
}

#[test]
fn reset_odometry_makes_the_current_pose_the_origin() {
    let mut s = Machine::new(Config::default());
    let mut t = open(&mut s);
    for i in 1..=10u16 {
        t = t + Duration::from_millis(100);
        feed(&mut s, &Packet::Sip(sip(100 + 50 * i, 100, 0, 0)), t);
    }
    s.reset_odometry();
    t = t + Duration::from_millis(100);
    feed(&mut s, &Packet::Sip(sip(100 + 50 * 11, 100, 0, 0)), t);
    let x = last_x(&mut s).unwrap();
    assert!((x - 0.066).abs() < 1e-9, "x = {x}");
}

#[test]
fn close_stops_then_closes() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    let _ = sent(&mut s, t);
    s.close();
    assert_eq!(sent(&mut s, t), vec![Command::Stop, Command::CLOSE]);
    assert_eq!(s.state(), SessionState::Closed);
    assert_eq!(s.poll_timeout(), None);
    // Again, for a line that was down (the shell repeats them until the robot is heard).
    s.repeat_close();
    s.repeat_close();
    assert_eq!(
        sent(&mut s, t),
        vec![Command::Stop, Command::CLOSE],
        "once queued"
    );
    // Not before closing.
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    let _ = sent(&mut s, t);
    s.repeat_close();
    assert!(sent(&mut s, t).is_empty());
}

/// Closing while reconnecting after a link loss still stops the robot: it may have been
/// quiet for less than its watchdog and drive on under the last session. STOP and CLOSE go
/// out at the old rate, ahead of the handshake frames (closing sent nothing, and the robot
/// drove on at 0.3 m/s until its watchdog).
#[test]
fn closing_while_reconnecting_stops_the_robot_at_the_old_rate() {
    let mut s = Machine::new(Config::default());
    let t = open(&mut s);
    let _ = sent(&mut s, t);
    let _ = events(&mut s);
    // No SIP: the link is lost, and the probe goes on until the line is at another rate than
    // the session's (within 30 s).
    let mut now = t;
    let mut line = 9600;
    let end = t + Duration::from_secs(30);
    while (s.state() != SessionState::Syncing || line == 9600) && now < end {
        now = now + Duration::from_millis(10);
        if s.poll_timeout().is_some_and(|d| d <= now) {
            s.handle_timeout(now);
        }
        let _ = sent(&mut s, now);
        for e in events(&mut s) {
            if let Event::SetBaud(b) = e {
                line = b;
            }
        }
    }
    assert_ne!(line, 9600, "the probe never left the session's rate");
    s.close();
    assert!(events(&mut s).contains(&Event::SetBaud(9600)));
    assert_eq!(sent(&mut s, now), vec![Command::Stop, Command::CLOSE]);
    assert_eq!(s.state(), SessionState::Closed);
    // Never connected: nothing is sent to whatever is on the port.
    let mut fresh = Machine::new(Config::default());
    fresh.connect(ms(0));
    let _ = sent(&mut fresh, ms(0));
    fresh.close();
    assert_eq!(sent(&mut fresh, ms(1)), vec![]);
}

/// After a link loss the robot stays away for a while: the session must keep the line speed it
/// announces (SetBaud) in step with the rate it believes it is using, and find the robot again
/// at the old rate as soon as it answers.
#[test]
fn reconnect_probing_keeps_the_line_speed_in_step() {
    let mut s = Machine::new(Config::default());
    let mut now = open(&mut s);
    let _ = sent(&mut s, now);
    let mut line = 0u32;
    for e in events(&mut s) {
        if let Event::SetBaud(b) = e {
            line = b;
        }
    }
    assert_eq!(line, 9600);
    // The robot is silent for 3 s, then answers only at 9600 (the host's line must be there).
    let back_at = now + Duration::from_secs(3);
    let mut step = 0u8;
    let mut reconnected_at = None;
    while now < back_at + Duration::from_secs(3) {
        now = now + Duration::from_millis(10);
        if s.poll_timeout().is_some_and(|t| t <= now) {
            s.handle_timeout(now);
        }
        for e in events(&mut s) {
            if let Event::SetBaud(b) = e {
                line = b;
            }
        }
        for c in sent(&mut s, now) {
            if now < back_at || line != 9600 {
                continue;
            }
            let reply = match (step, c) {
                (_, Command::Sync0) => {
                    step = 1;
                    Some(Packet::SyncEcho(0))
                }
                (1, Command::Sync1) => {
                    step = 2;
                    Some(Packet::SyncEcho(1))
                }
                (2, Command::Sync2) => {
                    step = 3;
                    Some(P2AT_REPLY)
                }
                (3, Command::Sync1) => {
                    step = 4;
                    None
                }
                _ => None,
            };
            if let Some(r) = reply {
                feed(&mut s, &r, now);
            }
        }
        if step == 4 {
            feed(
                &mut s,
                &Packet::Sip(sip(7, 7, 0, 0)),
                now + Duration::from_millis(50),
            );
            step = 5;
        }
        if s.is_open() && reconnected_at.is_none() && now > back_at {
            reconnected_at = Some(now);
        }
    }
    let t = reconnected_at.expect("never reconnected");
    assert!(
        t.saturating_duration_since(back_at) < Duration::from_millis(1500),
        "reconnected {:?} after the robot came back",
        t.saturating_duration_since(back_at)
    );
}

#[test]
fn unchanged_velocity_is_not_resent_every_call() {
    let mut s = Machine::new(Config::default());
    let mut t = open(&mut s);
    let _ = sent(&mut s, t);
    let mut frames = 0;
    // The caller refreshes the same command at 50 Hz for 2 s.
    for _ in 0..100 {
        s.set_velocity(VelocityCommand::new(0.2, 0.0), t).unwrap();
        frames += sent(&mut s, t)
            .iter()
            .filter(|c| matches!(c, Command::Int(IntCommand::Vel | IntCommand::RVel, _)))
            .count();
        t = t + Duration::from_millis(20);
    }
    // Sent at once, then re-asserted every 500 ms: 4 times × 2 frames.
    assert_eq!(frames, 8);
    // A change goes out immediately.
    s.set_velocity(VelocityCommand::new(0.3, 0.0), t).unwrap();
    assert_eq!(
        sent(&mut s, t),
        vec![
            Command::Int(IntCommand::Vel, 300),
            Command::Int(IntCommand::RVel, 0)
        ]
    );
    assert_eq!(
        s.stats().command_timeouts,
        0,
        "refreshing keeps the command alive"
    );
}
