//! Real-time stepping of a shared world.
//!
//! For the pty demo and driver ↔ mock tests the world must advance while devices are served.
//! A [`WorldStepper`] is a thread that steps a [`SharedWorld`] by the real elapsed time every
//! `period` (10 ms by default). Run exactly one per world: models never step it themselves.
//! A virtual-time simulation does not use this; it calls [`crate::world::World::step`] itself.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::Duration;

use crate::world::SharedWorld;

/// A thread stepping a world in real time. Stops when dropped.
#[derive(Debug)]
pub struct WorldStepper {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl WorldStepper {
    /// The default period: 10 ms.
    pub const DEFAULT_PERIOD: Duration = Duration::from_millis(10);

    /// Start stepping `world` every `period` (at least 1 ms) by the real elapsed time.
    pub fn spawn(world: SharedWorld, period: Duration) -> std::io::Result<Self> {
        let period = period.max(Duration::from_millis(1));
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("ima-world-stepper".into())
            .spawn(move || {
                let mut last = std::time::Instant::now();
                while !flag.load(Ordering::Relaxed) {
                    std::thread::sleep(period);
                    let now = std::time::Instant::now();
                    let dt = now.saturating_duration_since(last);
                    last = now;
                    world.with(|w| w.step(dt));
                }
            })?;
        Ok(Self {
            stop,
            thread: Some(thread),
        })
    }

    /// Stop the thread and wait for it.
    pub fn stop(mut self) {
        self.halt();
    }

    fn halt(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for WorldStepper {
    fn drop(&mut self) {
        self.halt();
    }
}

/// A tokio task stepping a world by tokio's clock every `period`. Under a paused tokio clock
/// (`#[tokio::test(start_paused = true)]`, or `tokio::time::pause()`) this is **virtual
/// time**: together with [`crate::duplex`] devices a whole mission runs much faster than real
/// time and exactly reproducibly. Aborts the task when dropped.
#[derive(Debug)]
pub struct TokioWorldStepper {
    task: tokio::task::JoinHandle<()>,
}

impl TokioWorldStepper {
    /// Start stepping (inside a tokio runtime); `period` is at least 1 ms.
    #[must_use]
    pub fn spawn(world: SharedWorld, period: Duration) -> Self {
        let period = period.max(Duration::from_millis(1));
        let task = tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            let mut last = tokio::time::Instant::now();
            loop {
                tick.tick().await;
                let now = tokio::time::Instant::now();
                let dt = now.saturating_duration_since(last);
                last = now;
                world.with(|w| w.step(dt));
            }
        });
        Self { task }
    }

    /// Stop stepping.
    pub fn stop(self) {
        self.task.abort();
    }
}

impl Drop for TokioWorldStepper {
    fn drop(&mut self) {
        self.task.abort();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::{DriveCommand, World};

    #[test]
    fn stepper_advances_world_time_and_robots() {
        let world = SharedWorld::new(World::default_world());
        let sk = world.lock().robot_id("skeeter").unwrap();
        world.with(|w| {
            w.command(
                sk,
                DriveCommand::Twist {
                    v_m_s: 0.5,
                    omega_rad_s: 0.0,
                },
            )
        });
        let s = WorldStepper::spawn(world.clone(), Duration::from_millis(5)).unwrap();
        std::thread::sleep(Duration::from_millis(100));
        s.stop();
        let w = world.lock();
        // Only that it moved: no timing assertions.
        assert!(w.time() > ima_hal::Instant::ZERO);
        assert!(w.robot(sk).unwrap().pose().x_m > 0.0);
    }

    #[tokio::test(start_paused = true)]
    async fn tokio_stepper_runs_in_virtual_time() {
        let world = SharedWorld::new(World::default_world());
        let sk = world.lock().robot_id("skeeter").unwrap();
        world.with(|w| {
            w.command(
                sk,
                DriveCommand::Twist {
                    v_m_s: 0.05,
                    omega_rad_s: 0.0,
                },
            )
        });
        let s = TokioWorldStepper::spawn(world.clone(), Duration::from_millis(10));
        // 40 s of the thesis's 0.05 m/s, instantly; skeeter accelerates at 1 m/s² (0.05 s ramp).
        tokio::time::sleep(Duration::from_secs(40)).await;
        s.stop();
        let w = world.lock();
        let x = w.robot(sk).unwrap().pose().x_m;
        assert!((x - 2.0).abs() < 0.01, "{x}");
        assert!(w.time() >= ima_hal::Instant::from_millis(39_990));
    }
}
