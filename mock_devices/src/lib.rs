//! `ima-mock-devices`: robot-side protocol models on a simulated world, served on
//! pseudo-terminals or in-memory pipes, with seeded fault injection.
//!
//! # Pieces
//!
//! * [`world`] — the 2-D world: differential-drive [`world::Robot`]s, walls, round obstacles,
//!   coloured objects; ray casting ([`world::World::cast`]); a sonar model
//!   ([`world::SonarModel`]); TOML world files ([`world::World::from_toml_str`]) and the
//!   thesis arena ([`world::World::default_world`]). Virtual time: the caller steps it.
//! * [`faults`] — the seeded byte-stream fault injector and its spec-string grammar
//!   (`corrupt=0.01,drop=0.001,split=1,stall=0.0005:300ms,hangup=5s,seed=42`).
//! * [`model`] — the [`model::DeviceModel`] trait a protocol model implements (sans-IO, like a
//!   driver's `machine` in the device role), and [`model::EchoModel`] for tests.
//! * [`link`] — the sans-IO core of every runner: model + faults in both directions +
//!   hang-up state, drivable in virtual time.
//! * [`pty`] — serve a model on a pseudo-terminal; a driver opens [`pty::PtyDevice::path`]
//!   like `/dev/ttyS0`.
//! * [`duplex`] — serve a model on a `tokio::io::duplex` pipe for fast tests.
//! * [`body`] — the differential-drive body both base models move ([`body::DiffDriveBody`])
//!   and [`body::WorldBody`], a robot of the simulated world.
//! * [`p2os`] — the Pioneer 2-AT's P2OS firmware as a device model.
//! * [`rflex`] — the ATRV-Jr's rFLEX controller as a device model.
//! * [`sick_lms`] — a SICK LMS 200/291 laser scanner as a device model.
//! * [`stepper`] — advance a [`world::SharedWorld`] in real time.
//! * [`hal`] — in-process HAL devices (base + odometry, laser, compass) on a world stepped in
//!   tokio's (virtual) time, every reading stamped on one clock: no protocol, no port.
//! * [`compass`] — a KVH C100 (NMEA) or PNI TCM2 compass reporting its robot's heading.
//! * [`video_mux`] — an Extron SIS / Kramer video switcher and the [`video_mux::VideoBus`]
//!   it shares with [`camera`], the 7-camera head rendering the world's coloured objects.
//!
//! # Quick start
//!
//! ```no_run
//! use ima_mock_devices::{faults::FaultPlan, model::EchoModel, pty::{PtyDevice, PtyOptions}};
//! let opts = PtyOptions { faults: FaultPlan::parse("corrupt=0.001,seed=1")?, ..PtyOptions::default() };
//! let dev = PtyDevice::spawn(EchoModel::new(), opts)?;
//! println!("serving on {}", dev.path().display()); // e.g. /dev/pts/7
//! dev.hang_up_for(std::time::Duration::from_secs(2)); // silent for 2 s, same path after
//! let model = dev.stop()?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! Protocol models (P2OS robot, rFLEX, SICK LMS, compass, video mux) live in their own modules
//! and reuse their driver crate's `wire` module for framing.
#![warn(missing_docs)]
#![cfg_attr(
    not(test),
    deny(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::unreachable
    )
)]

pub mod body;
pub mod camera;
pub mod compass;
pub mod duplex;
pub mod faults;
pub mod hal;
pub mod link;
pub mod model;
pub mod p2os;
pub mod pty;
pub mod rflex;
pub mod served;
pub mod sick_lms;
pub mod stepper;
pub mod video_mux;
pub mod world;
