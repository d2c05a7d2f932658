//! Test data shared by the `mix` benchmark and the `cost` example: camera frames that
//! compress like the simulated cameras' and serial ports named like the demo's.

use ima_hal::camera::Frame;
use ima_record::raw::PortInfo;

/// A 320×240 camera frame that compresses like the simulated cameras' (noisy: ≈50 % at zstd
/// level 1).
pub fn frame(seed: u32, channel: u8) -> Frame {
    let mut x = seed.wrapping_mul(2_654_435_761).max(1);
    let mut f = Frame::black(320, 240, Some(channel)).expect("frame size");
    for (i, p) in f.pixels.iter_mut().enumerate() {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        let base = if (i / 3) % 320 < 160 { 90 } else { 170 };
        *p = base + (x & 0x0f) as u8;
    }
    f
}

/// The raw port of `robot`'s `device` at `baud`.
pub fn port(robot: &str, device: &str, baud: u32) -> PortInfo {
    PortInfo {
        robot: robot.into(),
        device: device.into(),
        port: format!("/dev/pts/{device}"),
        baud,
        protocol: device.into(),
        params: Default::default(),
    }
}
