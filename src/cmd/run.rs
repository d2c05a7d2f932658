//! `ima run --config FILE.toml`: run one robot's stack (Skeeter or Scooter) on the configured
//! serial ports, or on an in-process simulated world when the configuration says `mock = true`.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;

use crate::config::{RobotConfig, Role};
use crate::safety::outln;
use crate::stack::{EVENT_QUEUE, EventKind, Events, net};
use crate::wiring;

/// Arguments of `ima run`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Configuration file (see `configs/skeeter.toml`, `configs/scooter.toml`).
    #[arg(long)]
    config: PathBuf,
    /// Print events as JSON lines on stdout (else as text on stderr).
    #[arg(long)]
    json: bool,
    /// Use the documented insecure all-zero key when the configuration names no key file.
    #[arg(long)]
    insecure: bool,
    /// Recording and live view.
    #[command(flatten)]
    rec: crate::record::RecordArgs,
}

/// Point the devices of `cfg` at a world served in this process (`mock = true`).
fn serve_mock(cfg: &mut RobotConfig) -> Result<ima_mock_devices::served::ServedWorld> {
    let served = super::mock_world::serve(&super::mock_world::WorldOptions {
        world: cfg.mock_world.world.clone(),
        seed: cfg.mock_world.seed,
        speed: cfg.mock_world.speed,
        frames_addr: "127.0.0.1:0".parse()?,
        write_configs: None,
        faults: ima_mock_devices::faults::FaultPlan::none(),
    })?;
    let [sk, sc, _] = super::mock_world::loopback_configs(served.endpoints(), 1.0, None)?;
    cfg.devices = match cfg.role {
        Role::Skeeter => sk.devices,
        Role::Scooter => sc.devices,
        Role::Commander => bail!("a commander has no devices; use `ima commander`"),
    };
    cfg.agent.time_scale = cfg.mock_world.speed;
    Ok(served)
}

/// Run `ima run`.
pub fn run(args: &RunArgs) -> Result<()> {
    let mut cfg = RobotConfig::load_with(&args.config, args.insecure)?;
    // Said first: a commander's configuration has no devices to open (it used to warn about
    // its insecure key before saying so).
    if cfg.role == Role::Commander {
        bail!(
            "{} is a commander's configuration: run it with `ima commander --config {}`",
            args.config.display(),
            args.config.display()
        );
    }
    // The addresses this robot listens on, looked up before any device opens (a name that
    // does not resolve failed only after the devices had connected and waited out their
    // timeout). The config's own checks take names without a lookup, so that a robot's
    // configuration can be checked on another machine. A live view on one of them failed
    // only once the devices had connected, blaming "another program" (the live view itself).
    let fox = args.rec.foxglove.filter(|f| f.port() != 0);
    for (key, a) in [
        ("peer.listen", &cfg.peer.listen),
        ("peer.data_listen", &cfg.peer.data_listen),
    ] {
        if a.is_empty() {
            continue;
        }
        let addrs = std::net::ToSocketAddrs::to_socket_addrs(a.as_str()).map_err(|e| {
            anyhow::anyhow!("{key} {a:?}: the name does not resolve on this machine ({e})")
        })?;
        for l in addrs {
            if let Some(fox) = fox
                && l.port() == fox.port()
                && (l.ip() == fox.ip() || l.ip().is_unspecified() || fox.ip().is_unspecified())
            {
                bail!(
                    "--foxglove {fox}: that is this robot's {key} ({a}); give the live view another port"
                );
            }
        }
    }
    // Skeeter's SAN network and colour database, read and checked before any device opens.
    let skeeter_rt = match cfg.role {
        Role::Skeeter => Some(
            crate::stack::skeeter::runtime_config(&cfg)
                .with_context(|| format!("in {}", args.config.display()))?,
        ),
        Role::Scooter | Role::Commander => None,
    };
    let _served = if cfg.mock {
        Some(serve_mock(&mut cfg)?)
    } else {
        None
    };
    crate::record::start(&args.rec, "ima run")?; // record
    crate::safety::block_on(async {
        let key = net::group_key(&cfg, None)?;
        let (events, mut rx) = Events::channel(EVENT_QUEUE);
        // record: the runtime's detail (SAN, Peer Agents, map) for the state topics.
        let events = events.detailed(crate::record::active());
        let json = args.json;
        let (stop_tx, stop_rx) = tokio::sync::watch::channel(false);
        let stop_tx = std::sync::Arc::new(stop_tx);
        // The printer: a closed stdout ends the robot's run (the guard then stops the base).
        let printer = {
            let stop_tx = std::sync::Arc::clone(&stop_tx);
            tokio::spawn(async move {
                while let Some(e) = rx.recv().await {
                    crate::record::log_event(&e); // record: events, broadcasts, SES, belief
                    if crate::record::is_detail(&e.kind) {
                        continue; // asked for by the recording only
                    }
                    let written = if let EventKind::AuthFailure(text) = &e.kind {
                        // Frames under another group key: a warning, on stderr in either mode.
                        eprintln!("ima: warning: {text}");
                        Ok(())
                    } else if json {
                        serde_json::to_string(&e)
                            .map_err(anyhow::Error::from)
                            .and_then(|l| outln!("{l}"))
                    } else {
                        let v = serde_json::to_value(&e).unwrap_or_default();
                        eprintln!("[{:7.1}s] {} {} {}", e.t_s, e.robot, e.name(), v["detail"]);
                        Ok(())
                    };
                    if let Err(err) = written {
                        let _ = stop_tx.send(true);
                        return Err(err);
                    }
                }
                crate::stack::report_dropped(rx.dropped());
                anyhow::Ok(())
            })
        };
        // A signal has already halted the bases (the safety guard); the stack winds down.
        let signal = {
            let stop_tx = std::sync::Arc::clone(&stop_tx);
            tokio::spawn(async move {
                crate::safety::cancelled().await;
                let _ = stop_tx.send(true);
            })
        };
        // record: the fixed frames that place the robot under `map` (the layout follows it),
        // every second: `map` is this robot's start here (no world says otherwise).
        let _frames = crate::record::active().then(|| {
            let (robot, laser) = (cfg.robot.clone(), cfg.role == Role::Scooter);
            crate::wiring::AbortOnDrop(Some(tokio::spawn(async move {
                let mut tick = tokio::time::interval(std::time::Duration::from_secs(1));
                loop {
                    tick.tick().await;
                    crate::record::with(|r| {
                        crate::record::log_fixed_frames(r, &robot, true, laser);
                    });
                }
            })))
        });
        // The process's one clock: every device of this robot stamps on it.
        let clock = ima_hal::time::TokioClock::shared();
        let r = match cfg.role {
            Role::Scooter => {
                let hw = crate::safety::until_cancelled(wiring::open_scooter(&cfg, &clock))
                    .await?
                    .context("opening Scooter's devices")?;
                wiring::run_scooter(&cfg, key, hw, clock, events, stop_rx).await
            }
            Role::Skeeter => {
                let rt = skeeter_rt.context("Skeeter's runtime configuration was not read")?;
                let hw = crate::safety::until_cancelled(wiring::open_skeeter(&cfg, &clock))
                    .await?
                    .context("opening Skeeter's devices")?;
                wiring::run_skeeter(&cfg, rt, key, hw, clock, events, stop_rx).await
            }
            Role::Commander => bail!("role commander: use `ima commander --config …`"),
        };
        signal.abort();
        let printed = tokio::time::timeout(std::time::Duration::from_secs(1), printer).await;
        if let Ok(Ok(Err(e))) = printed {
            return Err(e);
        }
        // A signal, or a closed stdout or stderr (text events) found by a print.
        if crate::safety::asked_to_end() {
            return Err(crate::safety::Interrupted(crate::safety::cause()).into());
        }
        r
    })
}
