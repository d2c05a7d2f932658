//! The blocking I/O shell (feature `serial`): a [`Machine`] over any `Read + Write` stream,
//! for simple tools that do not want an async runtime. It implements the blocking mirrors of
//! the `ima-hal` traits ([`ima_hal::blocking`]).
//!
//! The stream's `read` must return within a few milliseconds when nothing arrives (a port
//! opened by [`open_port`] has a 5 ms timeout), because the machine's timers (keep-alive at
//! 10 Hz, ≥ 5 ms pacing, the 0.5 s command watchdog) run between reads. Time only advances
//! inside the driver's calls: a tool that stops calling for longer than the controller's
//! fail-safe lets the robot stop, which is the safe outcome. Emergency stop behaves as in the
//! async shell: zero both axes, then engage the brake.

use std::io::{self, Read, Write};
use std::time::Duration;

use ima_hal::base::{BaseLimits, BumperState, Odometry, VelocityCommand};
use ima_hal::blocking;
use ima_hal::power::PowerState;
use ima_hal::sonar::{SonarScan, SonarTransducer};
use ima_hal::time::MonotonicClock;
use ima_hal::{ErrorType, Instant, Stamped};

pub use crate::driver::{BAUD, DriverError};
use crate::machine::{Config, Event, Machine, Phase, Stats, TX_BUF};

/// Open a serial port for the blocking shell: 8N1, no flow control, 5 ms read timeout.
///
/// A path that is not a serial port (a regular file, `/dev/null`) fails with
/// [`io::ErrorKind::InvalidInput`] and `PATH is not a serial port (…)`.
pub fn open_port(path: &str, baud: u32) -> io::Result<serialport::TTYPort> {
    serialport::new(path, baud)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::None)
        .stop_bits(serialport::StopBits::One)
        .flow_control(serialport::FlowControl::None)
        .timeout(Duration::from_millis(5))
        .open_native()
        .map_err(|e| ima_hal::serial::explain_open_error(path, io::Error::from(e)))
}

/// A connected rFLEX base, driven synchronously.
#[derive(Debug)]
pub struct BlockingRflex<S> {
    stream: S,
    machine: Machine,
    clock: MonotonicClock,
    odometry: Option<Stamped<Odometry>>,
    scan: SonarScan,
    scan_at: Option<Instant>,
    bumpers: Option<Stamped<BumperState>>,
    power: Option<Stamped<PowerState>>,
    brake: Option<Stamped<bool>>,
    transducers: Vec<SonarTransducer>,
    sonar_wanted: bool,
    reinit_at: Option<Instant>,
    link_up: bool,
}

const WAIT: Duration = Duration::from_secs(2);

impl<S: Read + Write> BlockingRflex<S> {
    /// Send the initialisation on `stream` and wait until the base streams motion reports,
    /// or `timeout`.
    pub fn connect(stream: S, cfg: Config, timeout: Duration) -> Result<Self, DriverError> {
        let clock = MonotonicClock::new();
        let machine = Machine::new(cfg, clock.now());
        let transducers = machine.transducers().iter().copied().collect();
        let mut me = Self {
            stream,
            machine,
            clock,
            odometry: None,
            scan: SonarScan::default(),
            scan_at: None,
            bumpers: None,
            power: None,
            brake: None,
            transducers,
            sonar_wanted: false,
            reinit_at: None,
            link_up: false,
        };
        let deadline = std::time::Instant::now() + timeout;
        while !me.link_up {
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            me.pump_once()?;
        }
        Ok(me)
    }

    /// Session counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        *self.machine.stats()
    }

    /// The driver's clock.
    #[must_use]
    pub fn now(&self) -> Instant {
        self.clock.now()
    }

    /// The brake as last reported (`true` = engaged).
    #[must_use]
    pub fn brake(&self) -> Option<Stamped<bool>> {
        self.brake
    }

    /// Whether the base is streaming motion reports.
    #[must_use]
    pub fn link_up(&self) -> bool {
        self.link_up
    }

    /// Run I/O and timers for `d` (use it to wait while staying connected).
    pub fn pump_for(&mut self, d: Duration) -> Result<(), DriverError> {
        let end = std::time::Instant::now() + d;
        while std::time::Instant::now() < end {
            self.pump_once()?;
        }
        Ok(())
    }

    fn flush_tx(&mut self) -> Result<(), DriverError> {
        let mut tbuf = [0u8; TX_BUF];
        while let Some(n) = self.machine.poll_transmit(&mut tbuf) {
            let frame = tbuf.get(..n).unwrap_or(&[]);
            self.stream
                .write_all(frame)
                .map_err(|e| DriverError::Io(e.kind()))?;
        }
        let _ = self.stream.flush();
        Ok(())
    }

    /// One round: run timers, send what is due, read what is there (up to the stream's
    /// timeout), handle events.
    pub fn pump_once(&mut self) -> Result<(), DriverError> {
        let now = self.clock.now();
        self.machine.handle_timeout(now);
        if let Some(t) = self.reinit_at
            && now >= t
        {
            self.machine.reinitialize(self.sonar_wanted, now);
            self.reinit_at = Some(now + self.machine.config().link_timeout);
        }
        self.flush_tx()?;
        let mut rbuf = [0u8; 512];
        match self.stream.read(&mut rbuf) {
            Ok(0) => return Err(DriverError::Disconnected),
            Ok(n) => {
                let now = self.clock.now();
                self.machine.handle_bytes(rbuf.get(..n).unwrap_or(&[]), now);
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
        self.drain_events();
        Ok(())
    }

    fn drain_events(&mut self) {
        while let Some(ev) = self.machine.poll_event() {
            match ev {
                Event::LinkUp => {}
                Event::LinkLost => {
                    self.link_up = false;
                    self.reinit_at = Some(self.clock.now());
                }
                // Up = motion reports flow (see the async shell's recovery notes).
                Event::Odometry(o) => {
                    self.odometry = Some(o);
                    self.link_up = true;
                    self.reinit_at = None;
                }
                Event::Power(p) => self.power = Some(p),
                Event::Brake(b) => self.brake = Some(b),
                Event::Sonar(r) => {
                    self.scan.upsert(r);
                    self.scan_at = Some(r.at);
                }
                Event::Bumpers(b) => self.bumpers = Some(b),
                Event::Initialized
                | Event::OdometryRejected { .. }
                | Event::UnmappedSonar { .. }
                | Event::Dio { .. }
                | Event::Joystick { .. }
                | Event::Unknown(_)
                | Event::CommandTimeout
                | Event::ShutdownComplete => {}
            }
        }
    }

    fn wait_for<T>(&mut self, mut get: impl FnMut(&Self) -> Option<T>) -> Result<T, DriverError> {
        let deadline = std::time::Instant::now() + WAIT;
        loop {
            if let Some(v) = get(self) {
                return Ok(v);
            }
            if std::time::Instant::now() >= deadline {
                return Err(DriverError::Timeout);
            }
            self.pump_once()?;
        }
    }

    /// Send the shutdown sequence (§6) and give the stream back.
    pub fn close(mut self) -> Result<S, DriverError> {
        self.machine.shutdown(self.clock.now());
        let deadline = std::time::Instant::now() + WAIT;
        while self.machine.phase() != Phase::Closed && std::time::Instant::now() < deadline {
            self.machine.handle_timeout(self.clock.now());
            self.flush_tx()?;
            std::thread::sleep(Duration::from_millis(1));
        }
        Ok(self.stream)
    }
}

impl<S> ErrorType for BlockingRflex<S> {
    type Error = DriverError;
}

impl<S: Read + Write> blocking::DifferentialBase for BlockingRflex<S> {
    fn limits(&self) -> BaseLimits {
        self.machine.config().limits
    }

    fn enable_motors(&mut self, enable: bool) -> Result<(), DriverError> {
        let now = self.clock.now();
        self.machine.enable_motors(enable, now)?;
        self.brake = None;
        self.wait_for(|s| s.brake.filter(|b| b.value != enable).map(|_| ()))
    }

    fn set_velocity(&mut self, cmd: VelocityCommand) -> Result<(), DriverError> {
        let now = self.clock.now();
        self.machine.set_velocity(cmd, now)?;
        self.pump_once()
    }

    fn stop(&mut self) -> Result<(), DriverError> {
        let now = self.clock.now();
        self.machine.stop(now)?;
        self.pump_once()
    }

    fn emergency_stop(&mut self) -> Result<(), DriverError> {
        let now = self.clock.now();
        self.machine.stop(now)?;
        self.machine.enable_motors(false, now)?;
        self.pump_once()
    }
}

impl<S: Read + Write> blocking::Odometer for BlockingRflex<S> {
    fn odometry(&mut self) -> Result<Stamped<Odometry>, DriverError> {
        self.wait_for(|s| s.odometry)
    }

    fn reset_odometry(&mut self) -> Result<(), DriverError> {
        self.machine.reset_odometry();
        self.odometry = Some(Stamped::new(self.clock.now(), self.machine.odometry()));
        Ok(())
    }
}

impl<S: Read + Write> blocking::SonarArray for BlockingRflex<S> {
    fn transducers(&self) -> &[SonarTransducer] {
        &self.transducers
    }

    fn sonar(&mut self) -> Result<Stamped<SonarScan>, DriverError> {
        self.wait_for(|s| s.scan_at.map(|at| Stamped::new(at, s.scan.clone())))
    }
}

impl<S: Read + Write> blocking::Bumpers for BlockingRflex<S> {
    /// The latest DIO bumper report; all clear until the base reports a change.
    fn bumpers(&mut self) -> Result<Stamped<BumperState>, DriverError> {
        Ok(self
            .bumpers
            .unwrap_or_else(|| Stamped::new(self.clock.now(), BumperState::default())))
    }
}

impl<S: Read + Write> blocking::Power for BlockingRflex<S> {
    fn power(&mut self) -> Result<Stamped<PowerState>, DriverError> {
        self.wait_for(|s| s.power)
    }
}
