//! Cost of the mock sensors of issue 5: rendering a camera frame, one compass line.
//! Run: `cargo bench -p ima-mock-devices --bench camera`.

use std::time::Duration;

use divan::{Bencher, black_box};
use ima_hal::Instant;
use ima_mock_devices::camera::{CameraConfig, CameraHead};
use ima_mock_devices::compass::{CompassDevice, CompassModelConfig};
use ima_mock_devices::model::DeviceModel;
use ima_mock_devices::world::{SharedWorld, World};

fn main() {
    divan::main();
}

#[divan::bench(sample_count = 30)]
fn render_320x240(b: Bencher) {
    let world = SharedWorld::new(World::default_world());
    let id = world.with(|w| w.robot_id("skeeter")).unwrap();
    let mut head = CameraHead::new(CameraConfig::default(), world, id);
    b.bench_local(|| head.render(black_box(1), Duration::from_secs(1)));
}

#[divan::bench(sample_count = 30)]
fn compass_line(b: Bencher) {
    let world = SharedWorld::new(World::default_world());
    let id = world.with(|w| w.robot_id("scooter")).unwrap();
    let mut dev = CompassDevice::new(CompassModelConfig::default(), world, id);
    let mut out = Vec::with_capacity(256);
    let mut t = 0u64;
    b.bench_local(|| {
        t += 100;
        dev.handle_timeout(Instant::from_millis(t));
        out.clear();
        dev.poll_tx(&mut out);
    });
}
