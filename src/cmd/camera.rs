//! `ima camera grab`: grab one frame from the mock camera head (through the mock switcher and
//! the real switcher driver) and save it as PNG (the mock switcher alone is
//! `crate::cmd::mock::video_mux`).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use ima_hal::camera::{CameraMux, Frame, FrameSource};
use ima_mock_devices::camera::{CameraConfig, MockCameraHead};
use ima_mock_devices::pty::{PtyDevice, PtyOptions};
use ima_mock_devices::video_mux::{MuxDevice, MuxModelConfig, VideoBus};
use ima_video_mux::machine::Config as MuxConfig;
use ima_video_mux::shell::Driver as _;
use ima_video_mux::shell::{VideoMux, open_port};

/// `ima camera` sub-commands.
#[derive(Debug, Subcommand)]
pub enum CameraCommand {
    /// Grab one frame of the mock camera head and write it as PNG.
    Grab(GrabArgs),
}

/// Arguments of `ima camera grab`.
#[derive(Debug, Args)]
pub struct GrabArgs {
    /// Camera channel, 1 (forward) to 7, counter-clockwise.
    #[arg(long, value_parser = super::num::int_in::<u8, 1, 7>)]
    channel: u8,
    /// Output PNG file.
    #[arg(long)]
    out: PathBuf,
    /// World file (TOML); the built-in thesis arena when absent.
    #[arg(long)]
    world: Option<PathBuf>,
    /// Seed for pixel noise.
    #[arg(long, default_value_t = 1, value_parser = crate::cmd::num::seed)]
    seed: u64,
    /// The robot carrying the head.
    #[arg(long, default_value = "skeeter")]
    robot: String,
    /// Horizontal field of view of each camera, degrees.
    #[arg(long, default_value_t = 60.0, value_parser = super::num::fov_degrees)]
    fov: f64,
    /// Frame width, pixels.
    #[arg(long, default_value_t = 320, value_parser = super::num::int_in::<u32, 1, 4096>)]
    width: u32,
    /// Frame height, pixels.
    #[arg(long, default_value_t = 240, value_parser = super::num::int_in::<u32, 1, 4096>)]
    height: u32,
    /// Grab right after the switch, before the picture settles (shows the garbage frame).
    #[arg(long)]
    no_settle: bool,
    /// Tell the head the channel directly instead of selecting it on the mock switcher.
    #[arg(long)]
    direct: bool,
}

/// Write an RGB frame as an 8-bit PNG.
pub fn write_png(path: &Path, frame: &Frame) -> Result<()> {
    if !frame.is_consistent() {
        bail!("frame buffer does not match its size");
    }
    let file =
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), frame.width, frame.height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().context("writing the PNG header")?;
    w.write_image_data(&frame.pixels)
        .context("writing the PNG data")?;
    w.finish().context("finishing the PNG")?;
    Ok(())
}

/// Run `ima camera …`.
pub fn run(cmd: &CameraCommand) -> Result<()> {
    match cmd {
        CameraCommand::Grab(a) => grab(a),
    }
}

fn grab(args: &GrabArgs) -> Result<()> {
    crate::cmd::output::check_file("--out", &args.out)?;
    let world = crate::cmd::mock::shared::load_world(args.world.as_ref(), args.seed)?;
    let id = crate::cmd::mock::shared::robot_id(&world, &args.robot)?;
    let cfg = CameraConfig {
        fov_deg: args.fov,
        width: args.width,
        height: args.height,
        seed: args.seed,
        ..CameraConfig::default()
    };
    if args.channel == 0 || args.channel > cfg.cameras {
        bail!("channel must be 1..={}", cfg.cameras);
    }
    if !(args.fov > 0.0 && args.fov < 180.0) || args.width == 0 || args.height == 0 {
        bail!("field of view must be in (0, 180) degrees and the size non-zero");
    }
    let bus = VideoBus::new(None);
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let frame = rt.block_on(async {
        let mut cam = MockCameraHead::new(cfg, world.clone(), id, bus.clone());
        // Keep the switcher alive until the frame is taken.
        let mut _switcher = None;
        let settled_in = if args.direct {
            bus.switch(args.channel);
            cfg.settle_time
        } else {
            let dev = PtyDevice::spawn(
                MuxDevice::new(MuxModelConfig::default(), bus.clone()),
                PtyOptions::default(),
            )
            .context("starting the mock switcher")?;
            let port = open_port(&dev.path().to_string_lossy(), 9600)
                .context("opening the switcher pty")?;
            _switcher = Some(dev);
            let mut mux = VideoMux::spawn(
                port,
                MuxConfig::default(),
                ima_hal::time::TokioClock::shared(),
            );
            let sel = mux
                .select(args.channel)
                .await
                .context("selecting the camera")?;
            let settle = if args.no_settle {
                "grabbing before the picture settles (--no-settle)".to_owned()
            } else {
                format!("the picture settles in {:?}", mux.settle_time())
            };
            eprintln!("switcher confirmed channel {}; {settle}", sel.channel);
            if let Err(e) = mux.close().await {
                eprintln!("ima: warning: closing the switcher: {e}");
            }
            sel.settled_at.saturating_duration_since(mux.now())
        };
        if !args.no_settle {
            tokio::time::sleep(settled_in).await;
        }
        let f = cam.grab().await.context("grabbing")?;
        anyhow::Ok(f.value)
    })?;
    write_png(&args.out, &frame).context("--out")?;
    eprintln!(
        "wrote {} ({}×{}, channel {})",
        args.out.display(),
        frame.width,
        frame.height,
        args.channel
    );
    Ok(())
}
