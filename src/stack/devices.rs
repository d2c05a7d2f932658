//! Device wiring: the hal handles of a robot, built from its configuration (tokio shells over
//! tokio-serial ports). Every error names the device and the port.

use std::time::Duration;

use anyhow::{Context, Result};
use ima_compass::machine::{Config as CompassConfig, Dialect as CompassWireDialect};
use ima_compass::shell::CompassDriver;
use ima_hal::base::DifferentialBase;
use ima_p2os::shell::P2os;
use ima_rflex::shell::Rflex;
use ima_sick_lms::shell::SickLms;
use ima_sick_lms::wire::BaudRate;
use ima_video_mux::machine::{Config as MuxConfig, Dialect as MuxWireDialect};
use ima_video_mux::net_frames::NetFrames;
use ima_video_mux::shell::VideoMux;
use ima_video_mux::wire::TieKind;

use crate::config::{
    BaseDevice, BaseKind, CompassDeviceConfig, CompassDialect, FramesSource, LaserDevice,
    MuxDevice, MuxDialect, RobotConfig, Role,
};

fn secs(s: f64) -> Duration {
    Duration::try_from_secs_f64(s).unwrap_or(Duration::from_secs(10))
}

/// Connect to a P2OS base (trying the configured rate first, then the robot's others).
pub async fn open_p2os(d: &BaseDevice) -> Result<P2os> {
    anyhow::ensure!(
        d.kind == BaseKind::P2os,
        "the base on {} is not configured as p2os",
        d.port
    );
    let port = ima_p2os::shell::open_port(&d.port, d.baud)
        .with_context(|| format!("opening the P2OS base port {}", d.port))?;
    let port = crate::record::tap(port, "base", &d.port, d.baud, "p2os"); // record: raw bytes
    let mut cfg = ima_p2os::Config::default();
    let mut bauds: heapless::Vec<u32, 8> = heapless::Vec::new();
    let _ = bauds.push(d.baud);
    for b in &cfg.bauds {
        if *b != d.baud {
            let _ = bauds.push(*b);
        }
    }
    cfg.bauds = bauds;
    P2os::connect(port, cfg, secs(d.connect_timeout_s))
        .await
        .with_context(|| format!("connecting to the P2OS base on {}", d.port))
}

/// Connect to an rFLEX base and release its brake. `time_scale` > 1 (a sped-up simulated
/// world) widens the driver's odometry plausibility limits by that factor, since the world
/// moves that much faster per real second, asks for motion reports that much more often, and
/// multiplies the accelerations by it (the controller ramps in real time).
pub async fn open_rflex(d: &BaseDevice, time_scale: f64) -> Result<Rflex> {
    anyhow::ensure!(
        d.kind == BaseKind::Rflex,
        "the base on {} is not configured as rflex",
        d.port
    );
    let port = ima_rflex::shell::open_port(&d.port, d.baud)
        .with_context(|| format!("opening the rFLEX base port {}", d.port))?;
    let port = crate::record::tap(port, "base", &d.port, d.baud, "rflex"); // record: raw bytes
    let mut cfg = ima_rflex::machine::Config::default();
    let k = if time_scale.is_finite() {
        time_scale.max(1.0)
    } else {
        1.0
    };
    cfg.limits.max_v_m_s *= k;
    cfg.limits.max_omega_rad_s *= k;
    // Motion reports as often in world time as at real speed (at most 50 per second).
    cfg.report_period_us = ((f64::from(cfg.report_period_us) / k) as u32).max(20_000);
    // The controller ramps velocities in its own (real) time: accelerations × k give the
    // configured ramps in world time, so Scooter stops and turns as at real speed.
    cfg.trans_accel_m_s2 *= k;
    cfg.rot_accel = (f64::from(cfg.rot_accel) * k).min(f64::from(u32::MAX)) as u32;
    let mut base = Rflex::connect(port, cfg, secs(d.connect_timeout_s))
        .await
        .with_context(|| format!("connecting to the rFLEX base on {}", d.port))?;
    base.enable_motors(true)
        .await
        .with_context(|| format!("releasing the brake of the rFLEX base on {}", d.port))?;
    Ok(base)
}

/// Connect to a SICK LMS and start its scan stream.
pub async fn open_laser(d: &LaserDevice) -> Result<SickLms> {
    let baud = BaudRate::from_bps(d.baud).with_context(|| {
        format!(
            "laser on {}: a SICK LMS runs at 9600, 19200, 38400 or 500000, not {}",
            d.port, d.baud
        )
    })?;
    let port = ima_sick_lms::shell::open_port(&d.port, 9600)
        .with_context(|| format!("opening the SICK LMS port {}", d.port))?;
    let port = crate::record::tap(port, "laser", &d.port, 9600, "sick-lms"); // record: raw bytes
    let wait = secs(d.power_up_wait_s.max(0.0));
    let cfg = ima_sick_lms::machine::Config {
        baud,
        rs422: d.rs422,
        stream: true,
        power_up_wait: (d.power_up_wait_s > 0.0).then_some(wait),
        ..ima_sick_lms::machine::Config::default()
    };
    let lms = SickLms::connect(port, cfg, wait + Duration::from_secs(60))
        .await
        .with_context(|| format!("initialising the SICK LMS on {}", d.port))?
        .with_scan_timeout(Duration::from_secs(5));
    Ok(lms)
}

/// Connect to a serial compass and wait for headings.
pub async fn open_compass(d: &CompassDeviceConfig) -> Result<CompassDriver> {
    let dialect = match d.dialect {
        CompassDialect::Kvh => CompassWireDialect::KvhC100 {
            rate_per_minute: 600,
        },
        CompassDialect::Nmea => CompassWireDialect::Nmea,
        CompassDialect::Tcm2 => CompassWireDialect::Tcm2 {
            sample_rate_hz: 8,
            output: ima_compass::wire::Tcm2Format::Standard,
        },
    };
    let port = ima_compass::shell::open_port(&d.port, d.baud)
        .with_context(|| format!("opening the compass port {}", d.port))?;
    let protocol = match d.dialect {
        CompassDialect::Kvh => "compass-kvh",
        CompassDialect::Nmea => "compass-nmea",
        CompassDialect::Tcm2 => "compass-tcm2",
    };
    let port = crate::record::tap(port, "compass", &d.port, d.baud, protocol); // record: raw bytes
    CompassDriver::connect(
        port,
        CompassConfig::for_dialect(dialect),
        Duration::from_secs(10),
    )
    .await
    .with_context(|| format!("configuring the compass on {}", d.port))
}

/// Open the video switcher (the driver task starts at once; the first selection proves the
/// link).
pub fn open_mux(d: &MuxDevice) -> Result<VideoMux> {
    let port = ima_video_mux::shell::open_port(&d.port, d.baud)
        .with_context(|| format!("opening the video switcher port {}", d.port))?;
    let protocol = match d.dialect {
        MuxDialect::Extron => "video-mux-extron",
        MuxDialect::Kramer => "video-mux-kramer",
    };
    let port = crate::record::tap(port, "video_mux", &d.port, d.baud, protocol); // record: raw bytes
    let dialect = match d.dialect {
        MuxDialect::Extron => MuxWireDialect::Extron {
            kind: TieKind::All,
            output: None,
        },
        MuxDialect::Kramer => MuxWireDialect::Kramer {
            output: 1,
            machine: 1,
            expect_reply: true,
        },
    };
    Ok(VideoMux::spawn(
        port,
        MuxConfig {
            dialect,
            channel_count: d.cameras,
            ..MuxConfig::default()
        },
    ))
}

/// Connect to the frame server.
pub async fn open_frames(f: &FramesSource) -> Result<NetFrames> {
    let mut frames = NetFrames::new(f.addr.clone(), Duration::from_millis(f.timeout_ms));
    frames
        .connect()
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))
        .with_context(|| format!("connecting to the frame server {}", f.addr))?;
    Ok(frames)
}

/// Skeeter's devices.
#[derive(Debug)]
pub struct SkeeterDevices {
    /// The P2OS base.
    pub base: P2os,
    /// The video switcher.
    pub mux: VideoMux,
    /// The frame grabber.
    pub frames: NetFrames,
}

/// Scooter's devices.
#[derive(Debug)]
pub struct ScooterDevices {
    /// The rFLEX base (brake released).
    pub base: Rflex,
    /// The laser (streaming).
    pub laser: SickLms,
    /// The compass (absent when the heading source is odometry and none is configured).
    pub compass: Option<CompassDriver>,
}

/// record: name the robot whose ports these are (raw channels `/<robot>/serial/<device>`).
fn label_ports(cfg: &RobotConfig) {
    let d = &cfg.devices;
    let ports = [
        d.base.as_ref().map(|b| b.port.as_str()),
        d.laser.as_ref().map(|l| l.port.as_str()),
        d.compass.as_ref().map(|c| c.port.as_str()),
        d.video_mux.as_ref().map(|m| m.port.as_str()),
    ];
    crate::record::label_ports(&cfg.robot, ports.into_iter().flatten());
}

fn missing(what: &str) -> anyhow::Error {
    anyhow::anyhow!("the configuration has no [devices.{what}]")
}

/// Open Skeeter's devices.
pub async fn open_skeeter(cfg: &RobotConfig) -> Result<SkeeterDevices> {
    anyhow::ensure!(cfg.role == Role::Skeeter, "not a Skeeter configuration");
    let d = &cfg.devices;
    label_ports(cfg); // record: raw channels named by robot
    let frames = open_frames(d.frames.as_ref().ok_or_else(|| missing("frames"))?).await?;
    let mux = open_mux(d.video_mux.as_ref().ok_or_else(|| missing("video_mux"))?)?;
    let base = open_p2os(d.base.as_ref().ok_or_else(|| missing("base"))?).await?;
    Ok(SkeeterDevices { base, mux, frames })
}

/// Open Scooter's devices (all three at once).
pub async fn open_scooter(cfg: &RobotConfig) -> Result<ScooterDevices> {
    anyhow::ensure!(cfg.role == Role::Scooter, "not a Scooter configuration");
    let d = &cfg.devices;
    label_ports(cfg); // record: raw channels named by robot
    let base = d.base.as_ref().ok_or_else(|| missing("base"))?;
    let laser = d.laser.as_ref().ok_or_else(|| missing("laser"))?;
    let compass = async {
        match &d.compass {
            Some(c) => open_compass(c).await.map(Some),
            None => Ok(None),
        }
    };
    let (base, laser, compass) = tokio::join!(
        open_rflex(base, cfg.agent.time_scale),
        open_laser(laser),
        compass
    );
    Ok(ScooterDevices {
        base: base?,
        laser: laser?,
        compass: compass?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ima_hal::base::Odometer;
    use ima_hal::camera::{CameraMux, FrameSource};
    use ima_hal::compass::Compass;
    use ima_hal::laser::LaserScanner;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn every_device_opens_on_a_served_world() {
        let served = crate::cmd::mock_world::serve(&crate::cmd::mock_world::WorldOptions {
            world: None,
            seed: 3,
            speed: 1.0,
            frames_addr: "127.0.0.1:0".parse().unwrap(),
            write_configs: None,
        })
        .unwrap();
        let [sk, sc, _] =
            crate::cmd::mock_world::loopback_configs(served.endpoints(), 1.0, None).unwrap();
        let (a, b) = tokio::join!(open_skeeter(&sk), open_scooter(&sc));
        let mut sk = a.unwrap();
        let mut sc = b.unwrap();
        sk.base.odometry().await.unwrap();
        let sel = sk.mux.select(1).await.unwrap();
        assert_eq!(sel.channel, 1);
        tokio::time::sleep(sk.mux.settle_time() + Duration::from_millis(50)).await;
        let f = sk.frames.grab().await.unwrap();
        assert_eq!(f.value.channel, Some(1));
        // Red is straight ahead of Skeeter in the default world.
        let red = ima_mock_devices::camera::find_color(&f.value, [220, 30, 30], 12);
        assert!(red.is_some());
        let s = sc.laser.scan().await.unwrap();
        assert!(!s.value.is_empty());
        let h = sc.compass.as_mut().unwrap().heading().await.unwrap();
        // Scooter faces 30° ENU = 60° compass.
        assert!((h.value.heading_rad.to_degrees() - 60.0).abs() < 5.0);
        sc.base.odometry().await.unwrap();
    }

    #[tokio::test]
    async fn errors_name_the_port() {
        let d = BaseDevice {
            kind: BaseKind::P2os,
            port: "/dev/ima-no-such-port".into(),
            baud: 9600,
            connect_timeout_s: 1.0,
        };
        let e = open_p2os(&d).await.unwrap_err();
        assert!(format!("{e:#}").contains("/dev/ima-no-such-port"), "{e:#}");
        let f = FramesSource {
            addr: "127.0.0.1:1".into(),
            timeout_ms: 500,
        };
        let e = open_frames(&f).await.unwrap_err();
        assert!(format!("{e:#}").contains("127.0.0.1:1"), "{e:#}");
    }
}
