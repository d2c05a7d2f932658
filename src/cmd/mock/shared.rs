//! What the mock devices share: the world they live in, and serving until interrupted.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, Result};
use ima_mock_devices::faults::FaultPlan;
use ima_mock_devices::world::{SharedWorld, World};

/// Load the world of `--world`, or the built-in arena, with `seed`.
pub fn load_world(path: Option<&PathBuf>, seed: u64) -> Result<SharedWorld> {
    let mut world = match path {
        // The world's own errors name the file when it cannot be read; parse errors do not.
        Some(p) => World::from_toml_path(p).map_err(|e| match e {
            ima_mock_devices::world::WorldError::Io(_) => anyhow::anyhow!(e),
            e => anyhow::anyhow!(e).context(format!("loading {}", p.display())),
        })?,
        None => World::default_world(),
    };
    if let Err(e) = check_starts(&world) {
        return Err(match path {
            Some(p) => e.context(format!("loading {}", p.display())),
            None => e,
        });
    }
    world.set_seed(seed);
    Ok(SharedWorld::new(world))
}

/// A robot that starts overlapping another robot, a round obstacle, a coloured object or a
/// wall is refused (no robot can start inside something; `ima demo` with Scooter 0.20 m from
/// Skeeter failed its mission without a reason, Scooter having driven 0.00 m, and with a
/// target under Scooter's start it ran until Skeeter said "Scooter lost").
///
/// # Errors
/// The first overlap ([`World::start_overlap`]), naming both and the distances.
pub fn check_starts(w: &World) -> Result<()> {
    match w.start_overlap() {
        Some(o) => Err(anyhow::Error::msg(o)),
        None => Ok(()),
    }
}

/// The robot `name` of `world`; the error lists the robots the world has.
pub fn robot_id(world: &SharedWorld, name: &str) -> Result<ima_mock_devices::world::RobotId> {
    world.with(|w| {
        w.robot_id(name).with_context(|| {
            let names: Vec<&str> = w.robots().iter().map(|r| r.name()).collect();
            format!(
                "the world has no robot named {name:?} (it has: {})",
                if names.is_empty() {
                    "none".to_owned()
                } else {
                    names.join(", ")
                }
            )
        })
    })
}

/// Wait for Ctrl-C or SIGTERM.
pub fn wait_for_interrupt() -> Result<()> {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?
        .block_on(wait_for_signal())
}

/// Wait for SIGINT or SIGTERM (inside a runtime).
pub async fn wait_for_signal() -> Result<()> {
    #[cfg(unix)]
    {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
        tokio::select! {
            r = tokio::signal::ctrl_c() => r?,
            _ = term.recv() => {}
        }
    }
    #[cfg(not(unix))]
    tokio::signal::ctrl_c().await?;
    Ok(())
}

/// Print the pty path on stdout's first line, then serve until interrupted.
pub fn announce_and_wait(path: &std::path::Path, what: &str) -> Result<()> {
    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "{}", path.display())?;
        out.flush()?;
    }
    eprintln!(
        "serving a mock {what} on {}; Ctrl-C to stop",
        path.display()
    );
    wait_for_interrupt()
}

/// The fault plan of `--faults` (none when empty); `seed` (the device's `--seed`) seeds it
/// unless the plan names its own `seed=`.
pub fn fault_plan(faults: &str, seed: Option<u64>) -> Result<FaultPlan> {
    if faults.is_empty() {
        return Ok(FaultPlan::none());
    }
    let mut p = FaultPlan::parse(faults).context("parsing --faults")?;
    if let Some(seed) = seed
        && !faults.contains("seed=")
    {
        p.seed = seed;
    }
    Ok(p)
}

/// Serve `dev` on a new pty with the faults of `plan`; with `step_world`, the pty also steps
/// `world` in real time (a mock on its own; in a served world the world has one stepper).
pub fn spawn_on_pty<M: ima_mock_devices::model::DeviceModel + 'static>(
    dev: M,
    plan: FaultPlan,
    world: &SharedWorld,
    step_world: bool,
) -> Result<ima_mock_devices::pty::PtyDevice<M>> {
    let opts = ima_mock_devices::pty::PtyOptions {
        faults: plan,
        step_world: step_world.then(|| world.clone()),
        ..ima_mock_devices::pty::PtyOptions::default()
    };
    ima_mock_devices::pty::PtyDevice::spawn(dev, opts).context("starting the pty")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `--seed` seeds the faults unless the spec names its own seed (the compass and
    /// video-switcher mocks passed none, so their faults were the same whatever `--seed`).
    #[test]
    fn the_seed_seeds_the_faults_unless_the_spec_names_one() {
        assert_eq!(fault_plan("corrupt=0.05", Some(7)).unwrap().seed, 7);
        assert_eq!(fault_plan("corrupt=0.05,seed=3", Some(7)).unwrap().seed, 3);
        assert_ne!(
            fault_plan("corrupt=0.05", Some(1)).unwrap().seed,
            fault_plan("corrupt=0.05", Some(2)).unwrap().seed
        );
    }

    /// Robots that start inside something are refused, naming it; the thesis arena passes.
    #[test]
    fn robots_that_start_inside_something_are_refused() {
        check_starts(&World::default_world()).unwrap();
        let robots = |scooter_x: f64| {
            format!(
                "[[robot]]\nname = \"skeeter\"\nx_m = 0.0\ny_m = 0.0\n\
                 [[robot]]\nname = \"scooter\"\nx_m = {scooter_x}\ny_m = 0.0\n"
            )
        };
        let err = |toml: String| {
            let w = World::from_toml_str(&toml).unwrap();
            check_starts(&w).unwrap_err().to_string()
        };
        check_starts(&World::from_toml_str(&robots(-3.0)).unwrap()).unwrap();
        assert_eq!(
            err(robots(0.2)),
            "skeeter starts at (0.00, 0.00) overlapping scooter at (0.20, 0.00) (0.20 m from \
             it; it needs 0.60 m)"
        );
        let circle = format!(
            "{}[[circle]]\ncenter = [-3.0, 0.5]\nradius_m = 0.3\n",
            robots(-3.0)
        );
        assert_eq!(
            err(circle),
            "scooter starts at (-3.00, 0.00) overlapping the obstacle at (-3.00, 0.50) (0.50 m \
             from it; it needs 0.60 m)"
        );
        let object = format!(
            "{}[[object]]\ncolor = \"red\"\nrgb = [220, 30, 30]\ncenter = [-3.1, 0.2]\n\
             radius_m = 0.15\n",
            robots(-3.0)
        );
        assert_eq!(
            err(object),
            "scooter starts at (-3.00, 0.00) overlapping the red object at (-3.10, 0.20) (0.22 m \
             from it; it needs 0.45 m)"
        );
        let wall = format!(
            "{}[[wall]]\nfrom = [-5.0, 0.1]\nto = [5.0, 0.1]\n",
            robots(-3.0)
        );
        assert_eq!(
            err(wall),
            "skeeter starts at (0.00, 0.00) overlapping the wall from (-5.00, 0.10) to (5.00, \
             0.10) (0.10 m from it; it needs 0.30 m)"
        );
    }
}
