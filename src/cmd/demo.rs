//! `ima demo`: the mission of the thesis on built-in mock devices, in one process and with no
//! hardware. A simulated world serves every device of both robots on its own pseudo-terminal
//! (and Skeeter's frames on a TCP frame server); Skeeter's and Scooter's stacks open them
//! through their real drivers exactly as on the robots; the three Peer Agents (Skeeter's
//! manager, Scooter's client and manager, the commander) talk over loopback sockets with a
//! random in-memory group key; the commander sends the targets one at a time.
//!
//! Live progress goes to stderr (`--json`: JSON events on stdout). At the end: a summary per
//! target (state, time, distance, performance index `f = (d_min/d)·(t_min/t)` at Scooter's
//! cruise speed) and an SVG of the world with both robots' trajectories.
//!
//! `ima demo square` is the issue-2 demonstration (one P2OS robot driving a square).

use std::path::PathBuf;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use ima_agents::peer::wire::GroupKey;
use ima_mock_devices::served::{ServeOptions, ServedWorld};
use serde_json::json;

use crate::safety::outln;
use ima_agents::runtime::commander::{TargetOutcome, TargetState};
use ima_agents::runtime::events::PeerNote;

use crate::stack::report::{Trajectory, performance_index, svg};
use crate::stack::{EVENT_QUEUE, Event, EventKind, Events};
use crate::wiring;

/// Arguments of `ima demo`.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct DemoArgs {
    /// The issue-2 demonstration instead.
    #[command(subcommand)]
    sub: Option<DemoCommand>,
    /// Time factor, 0.05 to 20: world time runs this many times faster than real time (not a
    /// velocity; Scooter's is `--cruise`).
    #[arg(long, default_value_t = 4.0, value_parser = super::num::time_factor)]
    speed: f64,
    /// Seed for sensor noise.
    #[arg(long, default_value_t = 1, value_parser = crate::cmd::num::seed)]
    seed: u64,
    /// Target colours, in order.
    #[arg(long, value_delimiter = ',', default_value = "red,blue,green", value_parser = super::num::target_colour)]
    targets: Vec<String>,
    /// World file (TOML); the built-in thesis arena when absent.
    #[arg(long)]
    world: Option<PathBuf>,
    /// Scooter's cruise velocity, m/s, in (0, 1].
    #[arg(long, default_value_t = 0.3, value_parser = super::num::cruise_m_s)]
    cruise: f64,
    /// A target not accomplished within this many mission (world) seconds fails.
    #[arg(long, default_value_t = 240.0, value_parser = super::num::mission_seconds)]
    target_timeout: f64,
    /// Where to write the SVG of the world and the trajectories.
    #[arg(long, default_value = "ima-demo.svg")]
    svg: PathBuf,
    /// Machine-readable JSON events on stdout instead of the live display.
    #[arg(long)]
    json: bool,
    /// The base Scooter runs on: its own rFLEX controller, or a Pioneer's P2OS one (the
    /// same runtime drives either).
    #[arg(long, value_enum, default_value_t = BaseChoice::Rflex)]
    scooter_base: BaseChoice,
    /// Recording and live view.
    #[command(flatten)]
    rec: crate::record::RecordArgs,
    /// Serve the commander console in the browser on ADDR (default 127.0.0.1:8080); it
    /// keeps serving after the mission, with the summary, until Ctrl-C.
    #[command(flatten)]
    web: super::WebArgs,
}

/// A base controller for `--scooter-base`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum BaseChoice {
    /// rFLEX (the ATRV-Jr's controller).
    Rflex,
    /// P2OS (the Pioneer 2-AT's controller).
    P2os,
}

/// `ima demo` sub-commands.
#[derive(Debug, Subcommand)]
pub enum DemoCommand {
    /// The issue-2 demonstration: a simulated Pioneer 2-AT drives a square over a pty.
    Square(super::demo_square::SquareArgs),
}

/// Run `ima demo`.
pub fn run(args: &DemoArgs) -> Result<()> {
    if let Some(DemoCommand::Square(a)) = &args.sub {
        return super::demo_square::run(a);
    }
    anyhow::ensure!(
        (0.05..=20.0).contains(&args.speed),
        "--speed must be 0.05 to 20"
    );
    anyhow::ensure!(
        args.cruise.is_finite() && args.cruise > 0.0 && args.cruise <= 1.0,
        "--cruise must be in (0, 1] m/s"
    );
    anyhow::ensure!(
        args.target_timeout.is_finite() && args.target_timeout > 0.0 && args.target_timeout <= 1e5,
        "--target-timeout must be in (0, 100000] s"
    );
    anyhow::ensure!(!args.targets.is_empty(), "--targets is empty");
    super::output::check_file("--svg", &args.svg)?;
    if let Some(r) = &args.rec.record {
        super::output::distinct_outputs(("--svg", &args.svg), ("--record", r))?;
    }
    args.web.check()?;
    let started = std::time::Instant::now();
    let world = super::mock::load_world(args.world.as_ref(), args.seed)?;
    let known: Vec<String> = world.with(|w| w.objects().iter().map(|o| o.color.clone()).collect());
    super::check_colours(&args.targets, &known, "the world's object colours")?;
    world.with(|w| check_world(w, &args.targets))?;
    // The process's one clock: the served devices' models and every driver run on it.
    let clock = ima_hal::time::TokioClock::shared();
    crate::record::start(&args.rec, "ima demo")?; // record
    let served = ServedWorld::start(
        world.clone(),
        &ServeOptions {
            seed: args.seed,
            speed: args.speed,
            clock: Some(clock.clone()),
            scooter_base: match args.scooter_base {
                BaseChoice::Rflex => ima_mock_devices::served::BaseKind::Rflex,
                BaseChoice::P2os => ima_mock_devices::served::BaseKind::P2os,
            },
            ..ServeOptions::default()
        },
    )
    .context("serving the world")?;
    let [mut sk, mut sc, mut cmd] =
        super::mock_world::loopback_configs(served.endpoints(), args.speed, None)?;
    for c in [&mut sk, &mut sc, &mut cmd] {
        c.peer.insecure = false;
        c.agent.cruise_speed_m_s = args.cruise;
        c.agent.target_timeout_s = args.target_timeout;
    }
    // The commander waits a little longer than Skeeter, whose timeout decides.
    cmd.agent.target_timeout_s = args.target_timeout * 1.25 + 30.0;
    if !args.json {
        eprintln!(
            "ima demo: world ×{} (seed {}); {}",
            args.speed,
            args.seed,
            super::mock_world::describe(served.endpoints())
        );
    }
    let key = GroupKey::from_array(super::mock_world::random_key()?);
    let log: Arc<Mutex<Vec<(f64, Event)>>> = Arc::default();
    let json_out = args.json;
    let paths: Arc<Mutex<[Trajectory; 2]>> = Arc::new(Mutex::new([
        Trajectory::new("skeeter"),
        Trajectory::new("scooter"),
    ]));
    // web console (issue 17): fed from the events below, commands into the commander.
    let (op_tx, op_rx) = tokio::sync::mpsc::unbounded_channel();
    let web = args.web.start("demo", known.clone(), Some(op_tx))?;
    let console = web.as_ref().map(|(c, _)| Arc::clone(c));
    if let Some(c) = &console {
        let w = world.with(|w| crate::web::world_json(w));
        c.update(|s| s.world = Some(w));
    }
    let (outcomes, counts) = crate::safety::block_on(async {
        let (events, mut rx) = Events::channel(EVENT_QUEUE);
        // record: the runtimes' detail (SAN, Peer Agents, map, queue) for the state topics.
        let events = events.detailed(console.is_some() || crate::record::active());
        // Events stamped with world time as they arrive; printed live.
        let printer = {
            let log = Arc::clone(&log);
            let world = world.clone();
            let console = console.clone();
            tokio::spawn(async move {
                while let Some(e) = rx.recv().await {
                    crate::record::log_event(&e); // record: events, broadcasts, SES, belief
                    if let Some(c) = &console {
                        c.apply(&e);
                    } else if crate::record::is_detail(&e.kind) {
                        // Asked for by the recording only: the output stays as without it.
                        continue;
                    }
                    let (wt, truth) = world.with(|w| {
                        let p = w
                            .robot_id(&e.robot)
                            .and_then(|id| w.robot(id))
                            .map(|r| r.pose());
                        (w.time().as_secs_f64(), p)
                    });
                    if json_out {
                        let mut v = serde_json::to_value(&e).unwrap_or_default();
                        v["world_t_s"] = json!(wt);
                        if let Some(p) = truth {
                            v["truth"] =
                                json!({"x_m": p.x_m, "y_m": p.y_m, "theta_rad": p.theta_rad});
                        }
                        if crate::safety::out_line(format_args!("{v}")).is_err() {
                            // Nothing more can be shown: the guard ends the demo.
                            break;
                        }
                    } else {
                        print_live(wt, &e);
                    }
                    log.lock()
                        .unwrap_or_else(PoisonError::into_inner)
                        .push((wt, e));
                }
                crate::stack::report_dropped(rx.dropped());
            })
        };
        // Ground-truth trajectories.
        let sampler = {
            let world = world.clone();
            let paths = Arc::clone(&paths);
            let console = console.clone();
            tokio::spawn(async move {
                let mut tick = tokio::time::interval(Duration::from_millis(50));
                let mut n = 0u64;
                // record: where each robot started (its odometry frame's origin in `map`).
                let starts: Vec<(String, ima_record::convert::Pose2)> = world.with(|w| {
                    ["skeeter", "scooter"]
                        .iter()
                        .filter_map(|name| {
                            let p = w.robot_id(name).and_then(|id| w.robot(id))?.pose();
                            Some((
                                (*name).to_owned(),
                                ima_record::convert::Pose2 {
                                    x_m: p.x_m,
                                    y_m: p.y_m,
                                    theta_rad: p.theta_rad,
                                },
                            ))
                        })
                        .collect()
                });
                // record: the belief in `map` (dead reckoning from the start).
                for (name, p) in &starts {
                    crate::record::set_start(name, p.x_m, p.y_m);
                }
                loop {
                    tick.tick().await;
                    n += 1;
                    let mut tr = paths.lock().unwrap_or_else(PoisonError::into_inner);
                    world.with(|w| {
                        let t = w.time().as_secs_f64();
                        for tj in tr.iter_mut() {
                            if let Some(r) = w.robot_id(&tj.robot).and_then(|id| w.robot(id)) {
                                let p = r.pose();
                                tj.push(t, p.x_m, p.y_m);
                                // record: ground truth
                                crate::record::with(|rec| {
                                    rec.log_ground_truth(
                                        &tj.robot,
                                        ima_record::convert::Pose2 {
                                            x_m: p.x_m,
                                            y_m: p.y_m,
                                            theta_rad: p.theta_rad,
                                        },
                                    );
                                });
                                if let Some(c) = &console {
                                    c.update(|s| s.truth(&tj.robot, p.x_m, p.y_m, p.theta_rad));
                                }
                            }
                        }
                    });
                    if n % 20 == 1 {
                        world_markers(&world); // record: targets, once a second
                        crate::record::with(|rec| {
                            for (name, p) in &starts {
                                rec.log_odom_origin(name, *p);
                            }
                            // Scooter carries the laser (Skeeter none: it had a frame too).
                            rec.log_transform(
                                "scooter/base_link",
                                "scooter/laser",
                                ima_record::convert::Pose2::default(),
                            );
                        });
                    }
                }
            })
        };
        let (sk_dev, sc_dev) = tokio::join!(
            wiring::open_skeeter(&sk, &clock),
            wiring::open_scooter(&sc, &clock)
        );
        let sk_dev = sk_dev.context("opening Skeeter's devices")?;
        let sc_dev = sc_dev.context("opening Scooter's devices")?;
        // The peers' ports, picked again now that the devices are open: they are bound
        // milliseconds later, so another process has little time to take one (if it does,
        // the robot's error names the port at once).
        super::mock_world::assign_ports([&mut sk, &mut sc, &mut cmd])?;
        // The drivers' own counters, read once the robots have stopped.
        let counters = [sk_dev.counters(), sc_dev.counters()];
        let (stop_sk, stop_rx_sk) = tokio::sync::watch::channel(false);
        let (stop_sc, stop_rx_sc) = tokio::sync::watch::channel(false);
        let sk_rt = crate::stack::skeeter::runtime_config(&sk)?;
        let mut skeeter = tokio::spawn({
            let (sk, key, clock, events) = (sk.clone(), key.clone(), clock.clone(), events.clone());
            async move { wiring::run_skeeter(&sk, sk_rt, key, sk_dev, clock, events, stop_rx_sk).await }
        });
        let mut scooter = tokio::spawn({
            let (sc, key, clock, events) = (sc.clone(), key.clone(), clock.clone(), events.clone());
            async move { wiring::run_scooter(&sc, key, sc_dev, clock, events, stop_rx_sc).await }
        });
        let robots = ["skeeter".to_owned(), "scooter".to_owned()];
        // A signal (the bases already halted by the guard) ends the mission at once: the
        // robots' runtimes are stopped below as after a normal end, and the recording is
        // closed, well within the guard's grace period.
        // A robot whose runtime ends before the mission (its Peer Agent could not bind, a
        // device failed) ends the mission at once with its error; the commander would
        // otherwise wait out every target's timeout (64 s at ×10, 11 min at ×1) and report
        // only "0/1 targets done".
        let mut ended_early = None;
        let outcomes = crate::safety::until_cancelled(async {
            let mission = async {
                let bus = crate::stack::net::bus(&cmd, key, clock.clone())?;
                let rt = crate::stack::commander::runtime_config(
                    &cmd,
                    (&robots, Duration::from_secs(30)),
                    console
                        .is_some()
                        .then(|| Duration::from_secs_f64(cmd.agent.robot_lost_after_s)),
                );
                let f = ima_agents::runtime::commander::run(
                    rt,
                    &args.targets,
                    bus,
                    clock.clone(),
                    events.clone(),
                    Some(op_rx),
                )
                .await?;
                anyhow::Ok(f.outcomes)
            };
            let robots = [("skeeter", &mut skeeter), ("scooter", &mut scooter)];
            let (r, early) = until_a_robot_ends(mission, robots).await;
            ended_early = early;
            r
        })
        .await
        .and_then(|r| r);
        // Scooter (the client) first, then Skeeter (its manager).
        for (name, stop, h) in [("scooter", stop_sc, scooter), ("skeeter", stop_sk, skeeter)] {
            let _ = stop.send(true);
            if ended_early == Some(name) {
                continue; // its end is the mission's error
            }
            match tokio::time::timeout(Duration::from_secs(5), h).await {
                Ok(Ok(Ok(()))) => {}
                Ok(Ok(Err(e))) => eprintln!("ima demo: {name} stopped with an error: {e:#}"),
                Ok(Err(e)) => eprintln!("ima demo: {name} task failed: {e}"),
                Err(_) => eprintln!("ima demo: {name} did not stop in time"),
            }
        }
        sampler.abort();
        // Closed before the recording ends: the counts then cover exactly the bytes recorded.
        let [sk_counters, sc_counters] = counters;
        let (sk_counts, sc_counts) = tokio::join!(sk_counters.close(), sc_counters.close());
        drop(events);
        let _ = tokio::time::timeout(Duration::from_secs(1), printer).await;
        outcomes.map(|o| (o, [sk_counts, sc_counts]))
    })?;
    let log = log.lock().unwrap_or_else(PoisonError::into_inner).clone();
    let paths = paths.lock().unwrap_or_else(PoisonError::into_inner).clone();
    if let Some(c) = &console {
        c.close_commands();
    }
    // The live lines out before the summary, which may go to the same terminal.
    crate::safety::flush_logs();
    let r = summarise(
        args,
        &served,
        &outcomes,
        &log,
        &paths,
        &counts,
        started.elapsed(),
        console.as_deref(),
    );
    if let Some((_, server)) = &web {
        // web console (issue 17): the page keeps the summary and trajectories until Ctrl-C.
        eprintln!(
            "ima demo: the mission is over; the console stays at http://{}/ until Ctrl-C",
            server.addr
        );
        while crate::safety::signal().is_none() {
            std::thread::sleep(Duration::from_millis(100));
        }
    }
    r
}

/// record: the world's objects as markers on `/world/objects`.
fn world_markers(world: &ima_mock_devices::world::SharedWorld) {
    crate::record::with(|rec| {
        let marks: Vec<_> = world.with(|w| {
            w.objects()
                .iter()
                .map(|o| ima_record::convert::MapMarker {
                    id: o.color.clone(),
                    x_m: o.center[0],
                    y_m: o.center[1],
                    label: o.color.clone(),
                    colour: o.color.clone(),
                })
                .collect()
        });
        rec.log_markers("/world/objects", &marks);
        // The walls and posts too: what the laser sees and Scooter avoids.
        let (walls, posts): (Vec<_>, Vec<_>) = world.with(|w| {
            (
                w.walls().iter().map(|x| (x.from, x.to)).collect(),
                w.circles().iter().map(|c| (c.center, c.radius_m)).collect(),
            )
        });
        rec.log_arena("/world/arena", &walls, &posts);
    });
}

fn print_live(world_t: f64, e: &Event) {
    if let Some(text) = live_line(e) {
        eprintln!("[{world_t:7.1}s] {text}");
    }
}

/// The live console's line for an event, if it has one.
fn live_line(e: &Event) -> Option<String> {
    Some(match &e.kind {
        EventKind::Target(t) => format!("TARGET {:<7} {}", t.target, t.state),
        EventKind::Behaviour(b) => format!("{:<8} → {b}", e.robot),
        EventKind::Say(said) => {
            let said = said
                .split_once(": ")
                .map_or(said.as_str(), |(_, rest)| rest);
            format!("{:<8} says {said}", e.robot)
        }
        EventKind::Connected { .. } => format!("{:<8} up", e.robot),
        EventKind::Waiting(ima_agents::runtime::events::Waiting::For(r)) => {
            format!("{:<8} waits for {}", e.robot, r.join(", "))
        }
        EventKind::Peer(PeerNote::Granted {
            manager: Some(_), ..
        }) => format!("{:<8} granted Skeeter's ses source", e.robot),
        EventKind::AuthFailure(text) => format!("warning: {text}"),
        _ => return None,
    })
}

/// The drivers' counters in words.
fn describe_counts(c: &wiring::DriverCounts) -> String {
    let mut parts = Vec::new();
    if let (Some(kind), Some(n)) = (c.base, c.base_frames) {
        parts.push(format!("{n} {kind} frames from the base"));
    }
    if let Some(n) = c.base_sips {
        parts.push(format!("{n} SIPs"));
    }
    if let Some(n) = c.laser_scans {
        parts.push(format!("{n} scans decoded"));
    }
    if let Some(n) = c.laser_scans_read {
        parts.push(format!("{n} read by the runtime"));
    }
    if let Some(n) = c.laser_decode_errors.filter(|n| *n > 0) {
        parts.push(format!("{n} scans undecodable"));
    }
    for (n, what) in [
        (c.base_framer_drops, "base frames"),
        (c.laser_framer_drops, "laser telegrams"),
    ] {
        if let Some(n) = n.filter(|n| *n > 0) {
            parts.push(format!("{n} {what} lost by the framer"));
        }
    }
    if let Some(n) = c.camera_frames {
        parts.push(format!("{n} camera frames"));
    }
    parts.join(", ")
}

/// Scooter's reach distance (target centre to Scooter's centre), as configured.
fn reach_m() -> f64 {
    crate::config::AgentConfig::default().reach_distance_m
}

/// Each target's mission in world seconds, (sent, ended), from the commander's events in
/// `log`; `None` for a target without both. From the send, not the acceptance: Scooter may
/// start on the commander's request before Skeeter's acceptance reaches the commander. A
/// colour named twice (`red,blue,red`) is two missions: the n-th one sent starts at the n-th
/// send of the colour and ends at the first outcome after that send; one never sent
/// (cancelled while it waited) has no span.
fn mission_spans(outcomes: &[TargetOutcome], log: &[(f64, Event)]) -> Vec<Option<(f64, f64)>> {
    // The commander's events about `target` in `states`, as (log index, world time).
    let events = |target: &str, states: &[&str]| -> Vec<(usize, f64)> {
        log.iter()
            .enumerate()
            .filter(|(_, (_, e))| {
                matches!(&e.kind, EventKind::Target(ev)
                    if ev.target == target && states.contains(&ev.state.as_str()))
            })
            .map(|(i, (t, _))| (i, *t))
            .collect()
    };
    outcomes
        .iter()
        .enumerate()
        .map(|(k, o)| {
            if !o.sent {
                return None;
            }
            // Earlier sends of the colour (a copy cancelled while it waited was never sent).
            let repeat = outcomes[..k]
                .iter()
                .filter(|p| p.sent && p.target == o.target)
                .count();
            let (i0, t0) = *events(&o.target, &["sent"]).get(repeat)?;
            let (_, t1) = events(&o.target, &["done", "failed"])
                .into_iter()
                .find(|&(i, _)| i > i0)?;
            Some((t0, t1))
        })
        .collect()
}

/// A target two objects of the world share is refused before anything starts: Skeeter's
/// cameras cannot tell them apart, and the mission ran to its timeout and ended with "1
/// target(s) failed". (A target under a robot's start, and robots that start inside
/// anything, are refused when the world is loaded: [`super::mock::shared::check_starts`].)
fn check_world(w: &ima_mock_devices::world::World, targets: &[String]) -> Result<()> {
    use ima_mock_devices::world::point_text;
    for t in targets {
        let objects: Vec<_> = w.objects().iter().filter(|o| &o.color == t).collect();
        anyhow::ensure!(
            objects.len() == 1,
            "target {t:?}: the world has {} objects of that colour, at {}; a target must be \
             the only object of its colour (Skeeter's cameras cannot tell them apart)",
            objects.len(),
            objects
                .iter()
                .map(|o| point_text(o.center))
                .collect::<Vec<_>>()
                .join(" and ")
        );
    }
    Ok(())
}

/// A robot's runtime task in the demo.
type RobotTask = tokio::task::JoinHandle<Result<()>>;

/// Run `mission` until it ends, or until one of `robots`' tasks ends first: then the mission
/// is dropped and its error is that robot's. Returns the result and which robot ended early
/// (its task is done and must not be awaited again).
async fn until_a_robot_ends<T>(
    mission: impl Future<Output = Result<T>>,
    [(a, ta), (b, tb)]: [(&'static str, &mut RobotTask); 2],
) -> (Result<T>, Option<&'static str>) {
    let (name, ended) = tokio::select! {
        r = mission => return (r, None),
        r = ta => (a, r),
        r = tb => (b, r),
    };
    let e = match ended {
        Ok(Err(e)) => e.context(format!("{name} stopped before the mission ended")),
        Ok(Ok(())) => anyhow::anyhow!("{name}'s runtime ended before the mission did"),
        Err(e) => anyhow::anyhow!("{name}'s task failed before the mission ended: {e}"),
    };
    (Err(e), Some(name))
}

/// The summary: per target, the drivers' counters, the recording, and the SVG.
#[allow(clippy::too_many_arguments)] // one call site; each argument is a different result
fn summarise(
    args: &DemoArgs,
    served: &ServedWorld,
    outcomes: &[TargetOutcome],
    log: &[(f64, Event)],
    paths: &[Trajectory; 2],
    counts: &[wiring::DriverCounts; 2],
    wall: Duration,
    console: Option<&crate::web::Console>,
) -> Result<()> {
    let scooter = &paths[1];
    let position_at = |t: f64| {
        scooter
            .points
            .iter()
            .take_while(|p| p.0 <= t)
            .last()
            .or(scooter.points.first())
            .map(|p| (p.1, p.2))
    };
    let objects = served.world().with(|w| w.objects().to_vec());
    let mut rows = Vec::new();
    for (o, span) in outcomes.iter().zip(mission_spans(outcomes, log)) {
        let Some((t0, t1)) = span else {
            rows.push(json!({"target": o.target, "state": o.state, "time_s": null,
                "distance_m": null, "d_min_m": null, "performance": 0.0, "reason": o.reason}));
            continue;
        };
        let d = scooter.length_between(t0, t1);
        // Ground truth: Scooter's centre to the target's centre at mission time `t`, metres.
        let gap_at = |t: f64| {
            let (x, y) = position_at(t)?;
            let obj = objects.iter().find(|ob| ob.color == o.target)?;
            Some((obj.center[0] - x).hypot(obj.center[1] - y))
        };
        let d_min = gap_at(t0).map_or(0.0, |g| (g - reach_m()).max(0.0));
        let f = if o.state == TargetState::Done {
            performance_index(d_min, d, t1 - t0, args.cruise)
        } else {
            0.0
        };
        let end_gap = gap_at(t1);
        rows.push(
            json!({"target": o.target, "state": o.state, "time_s": t1 - t0,
            "distance_m": d, "d_min_m": d_min, "performance": f, "end_gap_m": end_gap,
            "reason": o.reason}),
        );
    }
    let done = outcomes
        .iter()
        .filter(|o| o.state == TargetState::Done)
        .count();
    let failed = outcomes.len() - done;
    let world_s = served.world().with(|w| w.time()).as_secs_f64();
    let title = format!(
        "ima demo, seed {}: {done}/{} targets done ({}); mission {world_s:.0} s",
        args.seed,
        outcomes.len(),
        args.targets.join(", ")
    );
    let picture = served.world().with(|w| svg(w, paths, &title));
    let recording = crate::record::last_report();
    // The results are printed first: a failed write loses only the picture.
    let written = std::fs::write(&args.svg, picture)
        .with_context(|| format!("--svg {}: writing the picture", args.svg.display()));
    let summary = json!({
        "kind": "summary",
        "seed": args.seed,
        "speed": args.speed,
        "done": done,
        "failed": failed,
        "targets": rows,
        "mission_time_s": world_s,
        "wall_time_s": wall.as_secs_f64(),
        "scooter_distance_m": scooter.length(),
        // Paths as text (a path that is not UTF-8 made serde_json fail: a panic here).
        "svg": args.svg.display().to_string(),
        // What the drivers counted (not the recorder): a recording's counts check against it.
        "drivers": {"skeeter": counts[0], "scooter": counts[1]},
        // record: what the recording wrote (null without --record/--foxglove).
        "recording": recording.as_ref().map(|r| json!({
            "path": r.path.as_ref().map(|p| p.display().to_string()), "written": r.written, "dropped": r.dropped, "unwritten": r.unwritten,
            "bytes": r.bytes, "error": r.error, "uncounted": r.uncounted,
            "thread_cpu_s": r.thread_cpu.map(|d| d.as_secs_f64()),
            "calls_s": r.calls_time.as_secs_f64(),
        })),
    });
    if let Some(c) = console {
        c.update(|s| {
            for (i, r) in rows.iter().enumerate() {
                if let Some(f) = r["performance"].as_f64() {
                    s.set_performance(i, f);
                }
            }
            s.finish(summary.clone());
        });
    }
    if args.json {
        outln!("{summary}")?;
    } else {
        outln!("\nima demo summary (seed {}, ×{}):", args.seed, args.speed)?;
        outln!(
            "{:<8} {:>7} {:>9} {:>10} {:>9} {:>6}",
            "target",
            "state",
            "time s",
            "distance m",
            "d_min m",
            "f"
        )?;
        for r in &rows {
            let num = |k: &str| r[k].as_f64().map_or("-".to_owned(), |v| format!("{v:.2}"));
            outln!(
                "{:<8} {:>7} {:>9} {:>10} {:>9} {:>6}",
                r["target"].as_str().unwrap_or("?"),
                r["state"].as_str().unwrap_or("?"),
                num("time_s"),
                num("distance_m"),
                num("d_min_m"),
                num("performance")
            )?;
        }
        outln!(
            "{done} done, {failed} failed; mission time {world_s:.1} s, wall time {:.1} s; Scooter drove {:.2} m{}",
            wall.as_secs_f64(),
            scooter.length(),
            if written.is_ok() {
                format!("; trajectories in {}", args.svg.display())
            } else {
                String::new()
            }
        )?;
        // Why a target failed, where the commander knows (it gave up, or was cancelled).
        for line in super::failure_lines(outcomes) {
            outln!("{line}")?;
        }
        for (robot, c) in ["skeeter", "scooter"].iter().zip(counts) {
            outln!("{robot:<8} drivers: {}", describe_counts(c))?;
        }
        if let Some(r) = &recording {
            outln!("recording: {}", r.summary())?;
            let topics: Vec<String> = r.written.iter().map(|(t, n)| format!("{t} {n}")).collect();
            outln!("  per topic: {}", topics.join(", "))?;
        }
    }
    written?;
    anyhow::ensure!(failed == 0, "{failed} target(s) failed");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ima_agents::runtime::events::TargetChange;

    fn target(t: f64, colour: &str, state: &str) -> (f64, Event) {
        let kind = EventKind::Target(TargetChange {
            target: colour.into(),
            state: state.into(),
            time_s: None,
            given_up: None,
            cancelled: None,
        });
        (
            t,
            Event {
                t_s: t,
                robot: "commander".into(),
                kind,
            },
        )
    }

    fn outcome(colour: &str) -> TargetOutcome {
        TargetOutcome {
            target: colour.into(),
            state: TargetState::Done,
            sent: true,
            sent_s: 0.0,
            accepted_s: None,
            ended_s: 0.0,
            reason: None,
        }
    }

    /// The console said `commander waits for ["skeeter"]` (a Rust list): names, in words.
    #[test]
    fn the_live_console_names_whom_the_commander_waits_for() {
        use ima_agents::runtime::events::Waiting;
        let e = Event {
            t_s: 1.0,
            robot: "commander".into(),
            kind: EventKind::Waiting(Waiting::For(vec!["skeeter".into(), "scooter".into()])),
        };
        assert_eq!(
            live_line(&e).as_deref(),
            Some("commander waits for skeeter, scooter")
        );
        let (_, t) = target(2.0, "red", "sent");
        assert_eq!(live_line(&t).as_deref(), Some("TARGET red     sent"));
    }

    /// A target colour two objects share is refused, naming both; the thesis arena passes.
    #[test]
    fn a_target_two_objects_share_is_refused() {
        use ima_mock_devices::world::World;
        let all = ["red".to_owned(), "blue".into(), "green".into()];
        check_world(&World::default_world(), &all).unwrap();
        let toml = "[[robot]]\nname = \"skeeter\"\nx_m = 0.0\ny_m = 0.0\n\
                    [[object]]\ncolor = \"red\"\nrgb = [220, 30, 30]\ncenter = [3.0, 2.0]\n\
                    radius_m = 0.15\n\
                    [[object]]\ncolor = \"red\"\nrgb = [200, 40, 40]\ncenter = [-3.0, 2.0]\n\
                    radius_m = 0.15\n";
        let w = World::from_toml_str(toml).unwrap();
        check_world(&w, &[]).unwrap();
        assert!(
            check_world(&w, &["red".to_owned()])
                .unwrap_err()
                .to_string()
                .starts_with(
                    "target \"red\": the world has 2 objects of that colour, at (3.00, 2.00) and \
                     (-3.00, 2.00)"
                )
        );
    }

    /// A robot whose runtime fails (its Peer Agent could not bind) ends the mission at once
    /// with its error; the other robot's task is left to be stopped.
    #[tokio::test(start_paused = true)]
    async fn a_robot_that_fails_ends_the_mission_with_its_error() {
        let mut skeeter: RobotTask = tokio::spawn(async {
            tokio::time::sleep(Duration::from_secs(1)).await;
            Err(anyhow::anyhow!("binding 127.0.0.1:7600: Address in use"))
        });
        let mut scooter: RobotTask = tokio::spawn(std::future::pending());
        let started = tokio::time::Instant::now();
        // The commander waits for ever (its target timeouts) for a robot that is gone.
        let mission = std::future::pending::<Result<()>>();
        let robots = [("skeeter", &mut skeeter), ("scooter", &mut scooter)];
        let (r, early) = until_a_robot_ends(mission, robots).await;
        assert_eq!(started.elapsed(), Duration::from_secs(1));
        assert_eq!(early, Some("skeeter"));
        assert_eq!(
            format!("{:#}", r.unwrap_err()),
            "skeeter stopped before the mission ended: binding 127.0.0.1:7600: Address in use"
        );
        assert!(!scooter.is_finished());
        // A runtime that ends without an error before the mission is an error too; a
        // mission that ends first is the result.
        let mut quiet: RobotTask = tokio::spawn(async { Ok(()) });
        let robots = [("skeeter", &mut scooter), ("scooter", &mut quiet)];
        let (r, early) = until_a_robot_ends(std::future::pending::<Result<()>>(), robots).await;
        assert_eq!(early, Some("scooter"));
        assert!(format!("{:#}", r.unwrap_err()).contains("scooter's runtime ended before"));
        let mut other: RobotTask = tokio::spawn(std::future::pending());
        let robots = [("skeeter", &mut scooter), ("scooter", &mut other)];
        let (r, early) = until_a_robot_ends(async { Ok(7) }, robots).await;
        assert_eq!((r.unwrap(), early), (7, None));
        scooter.abort();
        other.abort();
    }

    #[test]
    fn a_colour_named_twice_is_two_missions_each_with_its_own_span() {
        // `--targets red,red,blue` where the second red is answered at once (Skeeter's
        // outcome memory) and blue never ends.
        let log = [
            target(5.0, "red", "sent"),
            target(5.1, "red", "processing"),
            target(40.0, "red", "done"),
            target(40.0, "red", "sent"),
            target(40.3, "red", "done"),
            target(40.3, "blue", "sent"),
        ];
        let outcomes = [outcome("red"), outcome("red"), outcome("blue")];
        assert_eq!(
            mission_spans(&outcomes, &log),
            [Some((5.0, 40.0)), Some((40.0, 40.3)), None]
        );
        // A red cancelled while it waited, before the two that ran: never sent, no span;
        // the two sent ones keep theirs.
        let cancelled = TargetOutcome {
            sent: false,
            state: TargetState::Failed,
            ..outcome("red")
        };
        let outcomes = [cancelled, outcome("red"), outcome("red")];
        assert_eq!(
            mission_spans(&outcomes, &log),
            [None, Some((5.0, 40.0)), Some((40.0, 40.3))]
        );
    }
}
