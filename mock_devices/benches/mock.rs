//! Throughput of the simulation pieces: fault injection, ray casting, sonar, world stepping.
//! Run: `cargo bench -p ima-mock-devices`.

use std::time::Duration;

use divan::{Bencher, black_box, counter::BytesCount};
use ima_hal::{Instant, Isometry2, Point2};
use ima_mock_devices::faults::{Direction, FaultPlan};
use ima_mock_devices::world::{DriveCommand, LaserModel, SonarModel, World};
use rand::SeedableRng;
use rand::rngs::SmallRng;

fn main() {
    divan::main();
}

#[divan::bench(sample_count = 50)]
fn fault_injector_4k(b: Bencher) {
    let plan = FaultPlan::parse("corrupt=0.01,drop=0.001,garbage=0.001,split=0.1,seed=1").unwrap();
    let mut inj = plan.injector(Direction::RobotToHost, Instant::ZERO);
    let input = vec![0x5Au8; 4096];
    let mut out = Vec::new();
    b.counter(BytesCount::new(input.len())).bench_local(|| {
        out.clear();
        inj.process(black_box(&input), Instant::ZERO, &mut out);
    });
}

#[divan::bench(sample_count = 50)]
fn ray_cast_default_world(b: Bencher) {
    let w = World::default_world();
    let sk = w.robot_id("skeeter");
    b.bench_local(|| w.cast_ignoring(black_box(Point2::origin()), black_box(0.3), 10.0, sk));
}

#[divan::bench(sample_count = 50)]
fn sonar_reading_7_rays(b: Bencher) {
    let w = World::default_world();
    let sk = w.robot_id("skeeter").unwrap();
    let m = SonarModel::default();
    let mut rng = SmallRng::seed_from_u64(1);
    let mount = Isometry2::identity();
    b.bench_local(|| m.measure(&w, sk, &mount, &mut rng));
}

#[divan::bench(sample_count = 20)]
fn laser_scan_181(b: Bencher) {
    let w = World::default_world();
    let sk = w.robot_id("skeeter").unwrap();
    let m = LaserModel::default();
    let mut rng = SmallRng::seed_from_u64(1);
    let mount = Isometry2::identity();
    let mut out = Vec::with_capacity(181);
    b.bench_local(|| m.scan(&w, sk, &mount, &mut rng, &mut out));
}

#[divan::bench(sample_count = 50)]
fn world_step_10ms_two_robots(b: Bencher) {
    let mut w = World::default_world();
    for r in 0..2 {
        w.command(
            ima_mock_devices::world::RobotId(r),
            DriveCommand::Twist {
                v_m_s: 0.3,
                omega_rad_s: 0.2,
            },
        );
    }
    b.bench_local(|| w.step(Duration::from_millis(10)));
}
