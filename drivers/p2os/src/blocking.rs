//! The blocking I/O shell (feature `serial`): a [`Session`] over any `Read + Write` stream,
//! for simple tools that do not want an async runtime. It implements the blocking mirrors of
//! the `ima-hal` traits ([`ima_hal::blocking`]).
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives (a
//! `serialport` port opened by [`open_port`] has a 10 ms timeout), because the session's
//! timers (keep-alive, command timeout) run between reads. Time only advances inside the
//! driver's calls: a tool that stops calling for longer than the robot's watchdog (2 s) lets
//! the robot stop, which is the safe outcome.

use std::io::{self, Read, Write};
use std::time::Duration;

use ima_hal::base::{BaseLimits, BumperState, Odometry, VelocityCommand};
use ima_hal::blocking;
use ima_hal::power::PowerState;
use ima_hal::sonar::{SonarScan, SonarTransducer};
use ima_hal::time::MonotonicClock;
use ima_hal::{ErrorType, Instant, Stamped};

pub use crate::driver::{BaudControl, DriverError, FixedBaud};
use crate::machine::{Config, Event, RobotIdentity, RobotState, Session, SessionStats};
use crate::params::RobotParams;

/// Open a serial port for the blocking shell: 8N1, no flow control, 10 ms read timeout.
///
/// A path that is not a serial port (a regular file, `/dev/null`) fails with
/// [`io::ErrorKind::InvalidInput`] and `PATH is not a serial port (…)`.
pub fn open_port(path: &str, baud: u32) -> io::Result<serialport::TTYPort> {
    serialport::new(path, baud)
        .timeout(Duration::from_millis(10))
        .open_native()
        .map_err(|e| ima_hal::serial::explain_open_error(path, io::Error::from(e)))
}

/// A connected P2OS robot, driven synchronously.
#[derive(Debug)]
pub struct BlockingP2os<S> {
    stream: S,
    session: Session,
    clock: MonotonicClock,
    latest: Option<RobotState>,
    params: RobotParams,
    identity: Option<RobotIdentity>,
    transducers: Vec<SonarTransducer>,
    motors_result: Option<Result<bool, DriverError>>,
    failed: Option<DriverError>,
}

impl<S: Read + Write + BaudControl> BlockingP2os<S> {
    /// Run the handshake on `stream` until the robot streams SIPs, or `timeout` passes.
    pub fn connect(stream: S, cfg: Config, timeout: Duration) -> Result<Self, DriverError> {
        let mut me = Self {
            stream,
            session: Session::new(cfg),
            clock: MonotonicClock::new(),
            latest: None,
            params: crate::params::P2AT,
            identity: None,
            transducers: Vec::new(),
            motors_result: None,
            failed: None,
        };
        me.session.connect(me.clock.now());
        let deadline = std::time::Instant::now() + timeout;
        while me.identity.is_none() {
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            me.pump_once()?;
        }
        Ok(me)
    }

    /// Who answered.
    pub fn identity(&self) -> Option<&RobotIdentity> {
        self.identity.as_ref()
    }

    /// The parameter table in use.
    pub fn params(&self) -> &RobotParams {
        &self.params
    }

    /// Session counters.
    pub fn stats(&self) -> SessionStats {
        self.session.stats()
    }

    /// The latest SIP state.
    pub fn latest(&self) -> Option<&RobotState> {
        self.latest.as_ref()
    }

    /// The driver's clock.
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    /// Run I/O and timers for `d` (use it to wait while staying connected).
    pub fn pump_for(&mut self, d: Duration) -> Result<(), DriverError> {
        let end = std::time::Instant::now() + d;
        while std::time::Instant::now() < end {
            self.pump_once()?;
        }
        Ok(())
    }

    /// One round: send what is due, read what is there (up to the stream's timeout), run
    /// timers, handle events.
    pub fn pump_once(&mut self) -> Result<(), DriverError> {
        if let Some(e) = &self.failed {
            return Err(e.clone());
        }
        let mut tbuf = [0u8; crate::wire::MAX_FRAME_LEN];
        let now = self.clock.now();
        while let Some(n) = self.session.poll_transmit(now, &mut tbuf) {
            let frame = tbuf.get(..n).unwrap_or(&[]);
            self.stream
                .write_all(frame)
                .map_err(|e| DriverError::Io(e.kind()))?;
        }
        let _ = self.stream.flush();
        let mut rbuf = [0u8; 512];
        match self.stream.read(&mut rbuf) {
            Ok(0) => return Err(DriverError::Disconnected),
            Ok(n) => {
                let now = self.clock.now();
                self.session.handle_input(rbuf.get(..n).unwrap_or(&[]), now);
            }
            Err(e)
                if matches!(
                    e.kind(),
                    io::ErrorKind::TimedOut
                        | io::ErrorKind::WouldBlock
                        | io::ErrorKind::Interrupted
                ) => {}
            Err(e) => return Err(DriverError::Io(e.kind())),
        }
        let now = self.clock.now();
        if self.session.poll_timeout().is_some_and(|t| t <= now) {
            self.session.handle_timeout(now);
        }
        self.drain_events()
    }

    fn drain_events(&mut self) -> Result<(), DriverError> {
        while let Some(ev) = self.session.poll_event() {
            match ev {
                Event::SetBaud(b) => self
                    .stream
                    .set_baud(b)
                    .map_err(|e| DriverError::Io(e.kind()))?,
                Event::Connected {
                    identity, params, ..
                } => {
                    self.params = params;
                    self.transducers = crate::driver::transducers(&params);
                    self.identity = Some(identity);
                }
                Event::UnsupportedRobot(id) => {
                    let e = DriverError::UnsupportedRobot(id.subclass.as_str().into());
                    self.failed = Some(e.clone());
                    return Err(e);
                }
                Event::HandshakeFailed => {
                    self.failed = Some(DriverError::HandshakeFailed);
                    return Err(DriverError::HandshakeFailed);
                }
                Event::State(s) => self.latest = Some(s),
                Event::MotorsEnabled(on) => self.motors_result = Some(Ok(on)),
                Event::MotorsRefused => self.motors_result = Some(Err(DriverError::MotorsRefused)),
                Event::FlushInput
                | Event::Disconnected(_)
                | Event::CommandTimeout
                | Event::Config(_)
                | Event::Encoder { .. } => {}
            }
        }
        Ok(())
    }

    fn wait_state(&mut self) -> Result<RobotState, DriverError> {
        let deadline = std::time::Instant::now() + Duration::from_secs(2);
        loop {
            if let Some(s) = &self.latest {
                return Ok(s.clone());
            }
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            self.pump_once()?;
        }
    }

    /// Stop the robot and close the session.
    pub fn close(mut self) -> Result<(), DriverError> {
        self.session.close();
        let now = self.clock.now();
        let mut tbuf = [0u8; crate::wire::MAX_FRAME_LEN];
        for _ in 0..4 {
            while let Some(n) = self
                .session
                .poll_transmit(self.clock.now().max(now), &mut tbuf)
            {
                let frame = tbuf.get(..n).unwrap_or(&[]);
                self.stream
                    .write_all(frame)
                    .map_err(|e| DriverError::Io(e.kind()))?;
            }
            std::thread::sleep(Duration::from_millis(6));
        }
        let _ = self.stream.flush();
        Ok(())
    }
}

impl<S> ErrorType for BlockingP2os<S> {
    type Error = DriverError;
}

impl<S: Read + Write + BaudControl> blocking::DifferentialBase for BlockingP2os<S> {
    fn limits(&self) -> BaseLimits {
        BaseLimits {
            max_v_m_s: self.params.max_velocity_mm_s / 1000.0,
            max_omega_rad_s: self.params.max_rot_velocity_deg_s.to_radians(),
        }
    }

    fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        let now = self.clock.now();
        self.session
            .enable_motors(enable, now)
            .map_err(DriverError::Session)?;
        self.motors_result = None;
        let deadline = std::time::Instant::now() + Duration::from_secs(3);
        loop {
            match self.motors_result.take() {
                Some(Ok(on)) if on == enable => return Ok(()),
                Some(Err(e)) => return Err(e),
                _ => {}
            }
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            self.pump_once()?;
        }
    }

    fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        let now = self.clock.now();
        self.session
            .set_velocity(cmd, now)
            .map_err(DriverError::Session)?;
        self.pump_once()
    }

    fn stop(&mut self) -> Result<(), DriverError> {
        self.session.stop().map_err(DriverError::Session)?;
        self.pump_once()
    }

    fn emergency_stop(&mut self) -> Result<(), DriverError> {
        self.session
            .emergency_stop()
            .map_err(DriverError::Session)?;
        self.pump_once()
    }
}

impl<S: Read + Write + BaudControl> blocking::Odometer for BlockingP2os<S> {
    fn odometry(&mut self) -> Result<Stamped<Odometry>, DriverError> {
        Ok(self.wait_state()?.odometry)
    }

    fn reset_odometry(&mut self) -> Result<(), DriverError> {
        self.session.reset_odometry();
        Ok(())
    }
}

impl<S: Read + Write + BaudControl> blocking::SonarArray for BlockingP2os<S> {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.transducers
    }

    fn sonar(&mut self) -> Result<Stamped<SonarScan>, DriverError> {
        Ok(self.wait_state()?.sonar)
    }
}

impl<S: Read + Write + BaudControl> blocking::Bumpers for BlockingP2os<S> {
    fn bumpers(&mut self) -> Result<Stamped<BumperState>, DriverError> {
        Ok(self.wait_state()?.bumpers)
    }
}

impl<S: Read + Write + BaudControl> blocking::Power for BlockingP2os<S> {
    fn power(&mut self) -> Result<Stamped<PowerState>, DriverError> {
        Ok(self.wait_state()?.power)
    }
}
