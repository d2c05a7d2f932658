//! `ima peer …`: Peer Agent tools over IP — a standalone manager serving synthetic sources,
//! a client that prints a source's samples, and a broadcast listener and sender. Every line
//! on stdout is one JSON object.
//!
//! Keys: the group key comes from the key file named by `--key-file` or by `key_file` in the
//! config; without one the tools refuse to run unless `--insecure`, which uses the
//! documented all-zero key (anyone can forge frames under it) and says so loudly.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use ima_agents::peer::data::DataClose;
use ima_agents::peer::manager::{CloseReason, FixedSelfAgent, ManagerEvent, Outcome, TicketError};
use ima_agents::peer::net::{
    BroadcastChannel, BroadcastMode, EndReason, LossReason, ManagerNetEvent, NetError,
    PeerClientHandle, PeerNetConfig, SourcePublisher, SubscriptionEvent, SyntheticSource,
    insecure_key, load_key_file, spawn_manager,
};
use ima_agents::peer::wire::{
    BodyError, DeclineReason, DenyReason, GroupKey, MissionEvent, Msg, RevokeReason, SourceInfo,
    WireError,
};
use serde_json::{Value, json};

use super::num;

/// `ima peer` sub-commands.
#[derive(Debug, Subcommand)]
pub enum PeerCommand {
    /// Run a standalone Peer Agent Manager serving synthetic sources (counter, sine, blob64).
    Manager(ManagerArgs),
    /// Connect to a manager, request a source and print its samples as JSON lines.
    Client(ClientArgs),
    /// Print broadcast traffic (status, emergency, mission) as JSON lines.
    Listen(ListenArgs),
    /// Send one broadcast message.
    Send(SendArgs),
}

/// Key and config options shared by every `ima peer` tool.
#[derive(Debug, Args)]
pub struct Common {
    /// Config file (TOML, see configs/peer-manager.toml); defaults when absent.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Group-key file (hex or raw, at least 32 bytes, mode 600); overrides `key_file`.
    #[arg(long)]
    key_file: Option<PathBuf>,
    /// Run without a key file, with the documented all-zero key: NOT SECURE.
    #[arg(long)]
    insecure: bool,
    /// Robot name (overrides `robot` of the config).
    #[arg(long)]
    robot: Option<String>,
    /// Heartbeat interval in ms, 10–60000 (overrides `heartbeat_ms`).
    #[arg(long, value_parser = num::int_in::<u64, 10, 60_000>)]
    heartbeat_ms: Option<u64>,
}

/// Broadcast-channel overrides.
#[derive(Debug, Args)]
pub struct BroadcastArgs {
    /// Broadcast mode (overrides `broadcast.mode`).
    #[arg(long, value_enum)]
    mode: Option<Mode>,
    /// UDP port (overrides `broadcast.port`). `ima peer listen --port 0` listens on a free
    /// port and prints it; a multicast sender needs the listeners' port.
    #[arg(long, value_parser = num::int_in::<u16, 0, 65_535>)]
    port: Option<u16>,
    /// Multicast group (overrides `broadcast.group`).
    #[arg(long)]
    group: Option<String>,
    /// Multicast interface address, e.g. 127.0.0.1 (overrides `broadcast.interface`).
    #[arg(long)]
    interface: Option<String>,
    /// Unicast peer `ip:port` (repeatable; replaces `broadcast.peers`).
    #[arg(long = "peer")]
    peers: Vec<String>,
}

/// `--mode` values.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Mode {
    /// UDP multicast.
    Multicast,
    /// Unicast to the peer list.
    Unicast,
    /// Both.
    Both,
}

/// Arguments of `ima peer manager`.
#[derive(Debug, Args)]
pub struct ManagerArgs {
    #[command(flatten)]
    common: Common,
    /// Request-channel listen address (overrides `manager.listen`).
    #[arg(long)]
    listen: Option<String>,
    /// Also send a status broadcast at this interval, ms, up to 3600000 (0: no broadcast
    /// channel).
    #[arg(long, default_value_t = 0, value_parser = num::int_in::<u64, 0, 3_600_000>)]
    status_ms: u64,
    #[command(flatten)]
    broadcast: BroadcastArgs,
}

/// Arguments of `ima peer client`.
#[derive(Debug, Args)]
pub struct ClientArgs {
    #[command(flatten)]
    common: Common,
    /// Manager address `host:port`.
    #[arg(long)]
    connect: String,
    /// Source to request.
    #[arg(long)]
    request: String,
    /// Request priority, 0–255.
    #[arg(long, default_value_t = 0, value_parser = num::int_in::<u8, 0, 255>)]
    priority: u8,
    /// Stop after this many samples, 1–1000000000 (default: run until the source ends).
    #[arg(long, value_parser = num::int_in::<u64, 1, 1_000_000_000>)]
    count: Option<u64>,
}

/// Arguments of `ima peer listen`.
#[derive(Debug, Args)]
pub struct ListenArgs {
    #[command(flatten)]
    common: Common,
    #[command(flatten)]
    broadcast: BroadcastArgs,
    /// Stop after this many messages, 1–1000000000.
    #[arg(long, value_parser = num::int_in::<u64, 1, 1_000_000_000>)]
    count: Option<u64>,
}

/// Arguments of `ima peer send`.
#[derive(Debug, Args)]
pub struct SendArgs {
    #[command(flatten)]
    common: Common,
    #[command(flatten)]
    broadcast: BroadcastArgs,
    /// What to send.
    #[command(subcommand)]
    what: SendWhat,
}

/// `ima peer send` messages.
#[derive(Debug, Subcommand)]
pub enum SendWhat {
    /// A status message.
    Status {
        /// Current behaviour.
        #[arg(long, value_parser = num::wire_text)]
        behaviour: String,
        /// SAN summary.
        #[arg(long, default_value = "", value_parser = num::wire_text)]
        san: String,
    },
    /// An emergency, e.g. `--kind scooter-lost`.
    Emergency {
        /// Kind.
        #[arg(long, value_parser = num::wire_text)]
        kind: String,
        /// Text.
        #[arg(long, default_value = "", value_parser = num::wire_text)]
        text: String,
    },
    /// A mission event.
    Mission {
        /// accepted, accomplished or failed.
        #[arg(long, value_enum)]
        event: Event,
        /// Target colour.
        #[arg(long, value_parser = num::wire_text)]
        target: String,
    },
}

/// Mission events for `ima peer send mission`.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum Event {
    /// Accepted.
    Accepted,
    /// Accomplished.
    Accomplished,
    /// Failed.
    Failed,
}

/// Runs an `ima peer` tool.
pub fn run(cmd: &PeerCommand) -> Result<()> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(async {
        match cmd {
            PeerCommand::Manager(a) => manager(a).await,
            PeerCommand::Client(a) => client(a).await,
            PeerCommand::Listen(a) => listen(a).await,
            PeerCommand::Send(a) => send(a).await,
        }
    })
}

/// The config file split into the peer config and the CLI's synthetic sources. Errors name
/// the file; a value of the wrong type also its line and column (the document is read with
/// its spans, not through an untyped table), and a value out of range its key.
fn load_config(path: Option<&Path>) -> Result<(PeerNetConfig, Vec<SyntheticSource>)> {
    use serde::Deserialize;
    let Some(path) = path else {
        return Ok((PeerNetConfig::default(), Vec::new()));
    };
    let text =
        ima_hal::file::read_text(path).with_context(|| format!("reading {}", path.display()))?;
    let in_file = |e: &dyn std::fmt::Display| anyhow::anyhow!("in {}: {e}", path.display());
    let spanned =
        |e: toml::de::Error| in_file(&ima_hal::file::located(&text, e.span(), e.message()));
    let mut root = toml::de::DeTable::parse(&text).map_err(spanned)?;
    let synthetic = match root.get_mut().remove("synthetic") {
        Some(v) => Vec::<SyntheticSource>::deserialize(toml::de::ValueDeserializer::from(v))
            .map_err(spanned)?,
        None => Vec::new(),
    };
    let mut cfg =
        PeerNetConfig::deserialize(toml::de::Deserializer::from(root)).map_err(spanned)?;
    cfg.validate().map_err(|e| in_file(&e))?;
    // A relative `key_file` is relative to the config file's directory, not to the
    // working directory.
    if let Some(k) = &cfg.key_file
        && k.is_relative()
        && !k.as_os_str().is_empty()
        && let Some(dir) = path.parent()
    {
        cfg.key_file = Some(dir.join(k));
    }
    Ok((cfg, synthetic))
}

fn setup(c: &Common) -> Result<(PeerNetConfig, Vec<SyntheticSource>, GroupKey)> {
    let (mut cfg, synthetic) = load_config(c.config.as_deref())?;
    if let Some(r) = &c.robot {
        cfg.robot.clone_from(r);
    }
    if let Some(h) = c.heartbeat_ms {
        cfg.heartbeat_ms = h;
    }
    let key = if let Some(path) = c.key_file.as_ref().or(cfg.key_file.as_ref()) {
        let key = load_key_file(path).map_err(|e| anyhow::anyhow!("{e}"))?;
        if key.is_insecure() {
            eprintln!("ima: WARNING: {}", zero_key_warning(path));
        }
        key
    } else if c.insecure {
        eprintln!(
            "ima: WARNING: --insecure: using the all-zero group key. Anyone on the network can \
             register, request, read and inject. Never use this outside a test bench."
        );
        insecure_key()
    } else {
        bail!(
            "no group key: name a key file with `key_file` in the config or --key-file \
             (generate one: {}), or pass --insecure for a test bench",
            ima_agents::peer::net::make_key_command("group.key")
        );
    };
    Ok((cfg, synthetic, key))
}

/// The warning for a key file that holds the all-zero key (as loud as `--insecure`'s).
pub fn zero_key_warning(path: &Path) -> String {
    format!(
        "the key file {} holds the all-zero key, the documented insecure key: anyone on the \
         network can register, request, read and inject. Generate a real key: {}",
        path.display(),
        ima_agents::peer::net::make_key_command("group.key")
    )
}

fn apply_broadcast(cfg: &mut PeerNetConfig, b: &BroadcastArgs) {
    if let Some(m) = b.mode {
        cfg.broadcast.mode = match m {
            Mode::Multicast => BroadcastMode::Multicast,
            Mode::Unicast => BroadcastMode::Unicast,
            Mode::Both => BroadcastMode::Both,
        };
    }
    if let Some(p) = b.port {
        cfg.broadcast.port = p;
    }
    if let Some(g) = &b.group {
        cfg.broadcast.group.clone_from(g);
    }
    if let Some(i) = &b.interface {
        cfg.broadcast.interface.clone_from(i);
    }
    if !b.peers.is_empty() {
        cfg.broadcast.peers.clone_from(&b.peers);
    }
}

fn line(v: &Value) -> Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{v}")?;
    out.flush()?;
    Ok(())
}

fn hex(b: &[u8]) -> String {
    use std::fmt::Write as _;
    let mut s = String::with_capacity(b.len() * 2);
    for x in b {
        let _ = write!(s, "{x:02x}");
    }
    s
}

fn default_synthetic() -> Vec<SyntheticSource> {
    vec![
        SyntheticSource {
            name: "counter".into(),
            generator: "counter".into(),
            rate_hz: 10.0,
        },
        SyntheticSource {
            name: "sine".into(),
            generator: "sine".into(),
            rate_hz: 10.0,
        },
        SyntheticSource {
            name: "blob64".into(),
            generator: "blob64".into(),
            rate_hz: 100.0,
        },
    ]
}

/// One synthetic sample: `counter` u64 LE, `sine` f64 LE (0.2 Hz), `blobN` N bytes.
fn synth(generator: &str, i: u64, t: f64) -> Result<Vec<u8>> {
    Ok(match generator {
        "counter" => i.to_le_bytes().to_vec(),
        "sine" => (2.0 * std::f64::consts::PI * 0.2 * t)
            .sin()
            .to_le_bytes()
            .to_vec(),
        g => match g.strip_prefix("blob").and_then(|n| n.parse::<usize>().ok()) {
            Some(n) => (0..n).map(|k| (i as usize).wrapping_add(k) as u8).collect(),
            None => bail!("unknown synthetic generator {g:?} (counter, sine, blobN)"),
        },
    })
}

/// The rates a synthetic source may have, Hz: its period is at most 1000 s, at least 10 µs,
/// and the rate is advertised in mHz.
const SYNTHETIC_RATES: std::ops::RangeInclusive<f64> = 0.001..=100_000.0;

/// Checks a synthetic source before it is published: a rate in [`SYNTHETIC_RATES`], a known
/// generator, and a sample that fits in one data frame (`max_payload`).
fn check_synthetic(s: &SyntheticSource, max_payload: usize) -> Result<()> {
    if !SYNTHETIC_RATES.contains(&s.rate_hz) {
        bail!(
            "synthetic source {:?}: rate_hz = {} must be a number from {} to {}",
            s.name,
            crate::config::shown(s.rate_hz),
            SYNTHETIC_RATES.start(),
            SYNTHETIC_RATES.end()
        );
    }
    if let Some(n) = s
        .generator
        .strip_prefix("blob")
        .and_then(|n| n.parse::<usize>().ok())
        && n > max_payload
    {
        bail!(
            "synthetic source {:?}: {} bytes per sample, above the payload limit of {max_payload} \
             (raise max_body)",
            s.name,
            n
        );
    }
    synth(&s.generator, 0, 0.0).map(|_| ())
}

fn run_source(s: &SyntheticSource, p: SourcePublisher) -> Result<tokio::task::JoinHandle<()>> {
    let generator = s.generator.clone();
    check_synthetic(s, p.max_payload())?;
    let period = Duration::from_secs_f64(
        1.0 / s
            .rate_hz
            .clamp(*SYNTHETIC_RATES.start(), *SYNTHETIC_RATES.end()),
    );
    Ok(tokio::spawn(async move {
        let start = std::time::Instant::now();
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut i: u64 = 0;
        loop {
            tick.tick().await;
            i = i.wrapping_add(1);
            let t = start.elapsed();
            if let Ok(b) = synth(&generator, i, t.as_secs_f64()) {
                let _ = p.publish(u64::try_from(t.as_micros()).unwrap_or(u64::MAX), &b);
            }
        }
    }))
}

async fn manager(a: &ManagerArgs) -> Result<()> {
    let (mut cfg, mut synthetic, key) = setup(&a.common)?;
    if let Some(l) = &a.listen {
        cfg.manager.listen.clone_from(l);
    } else if a.common.insecure && a.common.key_file.is_none() && cfg.key_file.is_none() {
        // The all-zero key lets anyone in: stay on loopback unless told otherwise.
        cfg.manager.listen = crate::stack::net::loopback(&cfg.manager.listen);
        eprintln!(
            "ima: --insecure: listening on 127.0.0.1 only (pass --listen to choose the address)"
        );
    }
    crate::stack::net::place_data_server(&mut cfg.manager);
    apply_broadcast(&mut cfg, &a.broadcast);
    if synthetic.is_empty() {
        synthetic = default_synthetic();
    }
    // Every source checked before the manager starts: a bad one is the config's mistake.
    for (i, s) in synthetic.iter().enumerate() {
        check_synthetic(s, cfg.max_body.saturating_sub(18))?;
        if synthetic[..i].iter().any(|o| o.name == s.name) {
            bail!(
                "two [[synthetic]] sources are named {:?}: a client asks for a source by its \
                 name, so each needs its own",
                s.name
            );
        }
    }
    // The status channel first: a bad group or interface is refused before the manager says
    // it listens (it printed "listening", then failed).
    let status = if a.status_ms > 0 {
        // The status channel only sends: it binds any free port, not the shared one.
        let mut bcfg = cfg.clone();
        bcfg.broadcast.bind_port = Some(0);
        let ch = BroadcastChannel::bind(&bcfg, &cfg.robot, key.clone())
            .map_err(|e| anyhow::anyhow!("{e}"))
            .context(
                "binding the status channel (--status-ms; its group, interface, mode and \
                 peers come from --group, --interface, --mode, --peer or [broadcast])",
            )?;
        Some(ch)
    } else {
        None
    };
    let agent = FixedSelfAgent::new(cfg.manager.task_priority, Vec::new());
    let m = spawn_manager(&cfg, key.clone(), agent)
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let mut events = m.events();
    let mut tasks = Vec::new();
    for s in &synthetic {
        let p = m
            .publisher(SourceInfo::new(&s.name, &s.generator, 1, s.rate_hz))
            .map_err(|e| anyhow::anyhow!("source {:?}: {e}", s.name))?;
        tasks.push(run_source(s, p)?);
    }
    line(&json!({
        "event": "listening",
        "robot": cfg.robot,
        "addr": m.local_addr().to_string(),
        "data_addr": m.data_addr().to_string(),
        "sources": synthetic.iter().map(|s| s.name.clone()).collect::<Vec<_>>(),
    }))?;
    if let Some(ch) = status {
        let period = Duration::from_millis(a.status_ms);
        tasks.push(tokio::spawn(async move {
            let mut tick = tokio::time::interval(period);
            loop {
                tick.tick().await;
                let _ = ch.send_status("serving", "manager", None).await;
            }
        }));
    }
    loop {
        tokio::select! {
            // SIGINT, SIGTERM (`systemctl stop`), SIGHUP or SIGQUIT: shut down in order (the
            // clients are told), not after the signal's grace period.
            () = crate::safety::cancelled() => break,
            e = events.recv() => match e {
                Ok(e) => line(&json!({ "event": "manager", "detail": manager_event_json(&e) }))?,
                Err(tokio::sync::broadcast::error::RecvError::Lagged(n)) => {
                    line(&json!({ "event": "lagged", "dropped": n }))?;
                }
                Err(_) => break,
            },
        }
    }
    // The manager first, so that its clients are told "shutdown": a source task ended first
    // drops its publisher, and a client could hear "source-gone" before it.
    m.shutdown().await;
    for t in tasks {
        t.abort();
    }
    Ok(())
}

async fn client(a: &ClientArgs) -> Result<()> {
    let (cfg, _, key) = setup(&a.common)?;
    let c = PeerClientHandle::connect(a.connect.as_str(), &cfg, key)
        .await
        .with_context(|| format!("connecting to {}", a.connect))?;
    let sources = c.register().await.map_err(|e| anyhow::anyhow!("{e}"))?;
    line(&json!({
        "event": "registered",
        "sources": sources.iter().map(|s| json!({
            "name": s.name, "kind": s.kind, "schema": s.schema, "rate_mhz": s.rate_mhz,
        })).collect::<Vec<_>>(),
    }))?;
    let mut sub = c.request(&a.request, a.priority).await.map_err(|e| {
        if matches!(e, NetError::Denied(DenyReason::UnknownSource)) {
            let names: Vec<&str> = sources.iter().map(|s| s.name.as_str()).collect();
            anyhow::anyhow!(
                "the manager has no source `{}` (it serves: {})",
                a.request,
                if names.is_empty() {
                    "none".to_owned()
                } else {
                    names.join(", ")
                }
            )
        } else {
            anyhow::anyhow!("{e}")
        }
    })?;
    line(&json!({ "event": "granted", "source": a.request }))?;
    let mut n: u64 = 0;
    loop {
        if a.count.is_some_and(|c| n >= c) {
            let _ = c.disconnect(&a.request).await;
            let _ = c.unregister().await;
            return Ok(());
        }
        let next = tokio::select! {
            e = sub.next() => e,
            () = crate::safety::cancelled() => return Ok(()),
        };
        match next {
            Some(SubscriptionEvent::Sample {
                seq,
                stamp_us,
                payload,
            }) => {
                n += 1;
                line(&json!({
                    "source": a.request,
                    "seq": seq,
                    "stamp_us": stamp_us,
                    "len": payload.len(),
                    "payload": hex(&payload),
                }))?;
            }
            Some(SubscriptionEvent::Lost { reason }) => {
                line(&json!({ "event": "lost", "reason": loss_reason_json(&reason) }))?;
            }
            Some(SubscriptionEvent::Closed { reason }) => {
                let r = end_reason_json(&reason);
                line(&json!({ "event": "closed", "reason": r }))?;
                bail!("source {} ended: {reason}", a.request);
            }
            None => bail!("source {} ended", a.request),
        }
    }
}

fn msg_json(m: &Msg, from: std::net::SocketAddr) -> Value {
    match m {
        Msg::Status {
            robot,
            seq,
            behaviour,
            san,
            pose,
        } => json!({
            "type": "status", "from": from.to_string(), "robot": robot, "seq": seq,
            "behaviour": behaviour, "san": san,
            "pose": pose.map(|p| json!({"x_mm": p.x_mm, "y_mm": p.y_mm, "theta_mrad": p.theta_mrad})),
        }),
        Msg::Emergency {
            robot,
            seq,
            kind,
            text,
        } => json!({
            "type": "emergency", "from": from.to_string(), "robot": robot, "seq": seq,
            "kind": kind, "text": text,
        }),
        Msg::Mission {
            robot,
            seq,
            event,
            target,
        } => json!({
            "type": "mission", "from": from.to_string(), "robot": robot, "seq": seq,
            "mission_event": event.as_str(), "target": target,
        }),
        other => json!({ "type": "other", "code": other.code() }),
    }
}

async fn listen(a: &ListenArgs) -> Result<()> {
    let (mut cfg, _, key) = setup(&a.common)?;
    apply_broadcast(&mut cfg, &a.broadcast);
    // A listener sends nothing: every robot's messages are shown, whatever its own name.
    cfg.broadcast.receive_own = true;
    let robot = a.common.robot.clone().unwrap_or_else(|| "commander".into());
    let ch = BroadcastChannel::bind(&cfg, &robot, key).map_err(|e| anyhow::anyhow!("{e}"))?;
    line(&json!({
        "event": "listening",
        "addr": ch.local_addr().map_err(|e| anyhow::anyhow!("{e}"))?.to_string(),
    }))?;
    let mut n = 0;
    // Frames under another key are refused silently by the channel: say so (rate-limited).
    let mut check = tokio::time::interval(Duration::from_secs(1));
    check.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    // What was heard and refused, by class: at `--count`, and on Ctrl-C or SIGTERM.
    let stats = || {
        let s = ch.stats();
        let w = s.wire;
        line(&json!({
            "event": "stats", "accepted": s.receiver.accepted,
            "duplicate": s.receiver.duplicate, "stale": s.receiver.stale,
            "bad_mac": w.bad_mac, "replay": w.replay, "truncated": w.truncated,
            "bad_magic": w.bad_magic, "bad_version": w.bad_version, "oversize": w.oversize,
            "malformed": w.malformed,
        }))
    };
    loop {
        if let Some(report) = ch.take_auth_report() {
            eprintln!("ima: warning: {report}");
        }
        if a.count.is_some_and(|c| n >= c) {
            return stats();
        }
        let r = tokio::select! {
            r = ch.recv() => r,
            _ = check.tick() => continue,
            // The counts, then the signal's status (130, 143), as every command ends.
            () = crate::safety::cancelled() => {
                stats()?;
                return Err(crate::safety::Interrupted(crate::safety::cause()).into());
            }
        };
        let (m, from) = r.map_err(|e| anyhow::anyhow!("{e}"))?;
        n += 1;
        line(&msg_json(&m, from))?;
    }
}

async fn send(a: &SendArgs) -> Result<()> {
    let (mut cfg, _, key) = setup(&a.common)?;
    apply_broadcast(&mut cfg, &a.broadcast);
    // The sender needs no fixed port: bind any, send to the group/peers.
    cfg.broadcast.bind_port = Some(0);
    let robot = a.common.robot.clone().unwrap_or_else(|| cfg.robot.clone());
    let ch = BroadcastChannel::bind(&cfg, &robot, key).map_err(|e| anyhow::anyhow!("{e}"))?;
    if ch.destinations().is_empty() {
        bail!("nowhere to send: unicast mode with no --peer (or broadcast.peers)");
    }
    if cfg.broadcast.mode != BroadcastMode::Unicast && cfg.broadcast.port == 0 {
        // Sending to port 0 failed with "Invalid argument (os error 22)".
        bail!(
            "broadcast port 0 (--port or broadcast.port): the multicast group needs the port \
             its listeners use"
        );
    }
    let r = match &a.what {
        SendWhat::Status { behaviour, san } => ch.send_status(behaviour, san, None).await,
        SendWhat::Emergency { kind, text } => ch.send_emergency(kind, text).await,
        SendWhat::Mission { event, target } => {
            let e = match event {
                Event::Accepted => MissionEvent::Accepted,
                Event::Accomplished => MissionEvent::Accomplished,
                Event::Failed => MissionEvent::Failed,
            };
            ch.send_mission(e, target).await
        }
    };
    let n = r.map_err(|e| anyhow::anyhow!("{e}"))?;
    if n == 0 {
        bail!("the message reached no destination");
    }
    line(&json!({ "event": "sent", "destinations": n }))?;
    Ok(())
}

// ---- JSON forms of the Peer Agent's events (never `Debug` text in machine output) ----

/// A wire error as a JSON object: `{"kind": "bad-mac"}`, `{"kind": "truncated", "need": 12,
/// "got": 3}`, ….
pub fn wire_error_json(e: &WireError) -> Value {
    match e {
        WireError::Truncated { need, got } => {
            json!({"kind": "truncated", "need": need, "got": got})
        }
        WireError::BadMagic(m) => json!({"kind": "bad-magic", "magic": hex(m)}),
        WireError::BadVersion(v) => json!({"kind": "bad-version", "version": v}),
        WireError::Oversize { len, max } => json!({"kind": "oversize", "len": len, "max": max}),
        WireError::BadMac => json!({"kind": "bad-mac"}),
        WireError::Replay { sender, last, got } => {
            json!({"kind": "replay", "sender": sender, "last": last, "got": got})
        }
        WireError::TrailingBytes(n) => json!({"kind": "trailing-bytes", "bytes": n}),
        WireError::UnknownType(t) => json!({"kind": "unknown-type", "code": t}),
        WireError::Body(b) => json!({"kind": "body", "body": match b {
            BodyError::Truncated => json!({"kind": "truncated"}),
            BodyError::BadUtf8 => json!({"kind": "bad-utf8"}),
            BodyError::BadCode(c) => json!({"kind": "bad-code", "code": c}),
            BodyError::TrailingBytes(n) => json!({"kind": "trailing-bytes", "bytes": n}),
        }}),
        WireError::BufferTooSmall => json!({"kind": "buffer-too-small"}),
        WireError::FieldTooLong => json!({"kind": "field-too-long"}),
    }
}

fn decline_str(r: DeclineReason) -> &'static str {
    match r {
        DeclineReason::DuplicateId => "duplicate-id",
        DeclineReason::Full => "full",
    }
}

fn deny_str(r: DenyReason) -> &'static str {
    match r {
        DenyReason::NotRegistered => "not-registered",
        DenyReason::UnknownSource => "unknown-source",
        DenyReason::QueueFull => "queue-full",
    }
}

fn revoke_str(r: RevokeReason) -> &'static str {
    match r {
        RevokeReason::TaskPriority => "task-priority",
        RevokeReason::SourceGone => "source-gone",
        RevokeReason::Shutdown => "shutdown",
        RevokeReason::BadTicket => "bad-ticket",
    }
}

/// Why a data session closed, as a JSON object (`{"kind": "revoked", "reason":
/// "source-gone"}`, …).
pub fn data_close_json(c: &DataClose) -> Value {
    match c {
        DataClose::Ticket(t) => json!({"kind": "ticket", "reason": match t {
            TicketError::Forged => "forged",
            TicketError::Expired => "expired",
            TicketError::NotGranted => "not-granted",
            TicketError::AlreadyUsed => "already-used",
        }}),
        DataClose::Revoked(r) => json!({"kind": "revoked", "reason": revoke_str(*r)}),
        DataClose::Wire(e) => json!({"kind": "wire", "error": wire_error_json(e)}),
        DataClose::Unexpected(code) => json!({"kind": "unexpected", "code": code}),
        DataClose::Lost => json!({"kind": "lost"}),
        DataClose::Local => json!({"kind": "local"}),
    }
}

/// Why a subscription paused, as a JSON object.
pub fn loss_reason_json(r: &LossReason) -> Value {
    match r {
        LossReason::Revoked(r) => json!({"kind": "revoked", "reason": revoke_str(*r)}),
    }
}

/// Why a subscription ended, as a JSON object.
pub fn end_reason_json(r: &EndReason) -> Value {
    match r {
        EndReason::ManagerLost => json!({"kind": "manager-lost"}),
        EndReason::Revoked(r) => json!({"kind": "revoked", "reason": revoke_str(*r)}),
        EndReason::Data(c) => json!({"kind": "data", "close": data_close_json(c)}),
        EndReason::Disconnected => json!({"kind": "disconnected"}),
        EndReason::Unregistered => json!({"kind": "unregistered"}),
        EndReason::Denied(r) => json!({"kind": "denied", "reason": deny_str(*r)}),
    }
}

fn outcome_json(o: &Outcome) -> Value {
    match o {
        Outcome::Granted => json!({"kind": "granted"}),
        Outcome::Pending => json!({"kind": "pending"}),
        Outcome::Denied(r) => json!({"kind": "denied", "reason": deny_str(*r)}),
        Outcome::Revoked(r) => json!({"kind": "revoked", "reason": revoke_str(*r)}),
        Outcome::Withdrawn => json!({"kind": "withdrawn"}),
    }
}

fn source_json(s: &SourceInfo) -> Value {
    json!({"name": s.name, "kind": s.kind, "schema": s.schema, "rate_mhz": s.rate_mhz})
}

/// A manager event as a JSON object with a `type` (`session-opened`, `registered`,
/// `decision`, `sources-changed`, `close-peer`, `data-closed`, …) and its fields.
pub fn manager_event_json(e: &ManagerNetEvent) -> Value {
    match e {
        ManagerNetEvent::SessionOpened { peer, addr } => {
            json!({"type": "session-opened", "peer": peer, "addr": addr.to_string()})
        }
        ManagerNetEvent::SessionEnded { peer, slow } => {
            json!({"type": "session-ended", "peer": peer, "slow": slow})
        }
        ManagerNetEvent::DataOpened { client, source } => {
            json!({"type": "data-opened", "client": client, "source": source})
        }
        ManagerNetEvent::DataClosed { source, reason } => {
            json!({"type": "data-closed", "source": source, "reason": data_close_json(reason)})
        }
        ManagerNetEvent::Core(c) => match c {
            ManagerEvent::Registered { peer, client } => {
                json!({"type": "registered", "peer": peer, "client": client})
            }
            ManagerEvent::Declined {
                peer,
                client,
                reason,
            } => json!({"type": "declined", "peer": peer, "client": client,
                "reason": decline_str(*reason)}),
            ManagerEvent::Unregistered { peer, client } => {
                json!({"type": "unregistered", "peer": peer, "client": client})
            }
            ManagerEvent::Decision(d) => json!({
                "type": "decision", "client": d.client, "robot": d.robot, "source": d.source,
                "priority": {"robot": d.priority.robot, "request": d.priority.request},
                "task_priority": d.task_priority, "outcome": outcome_json(&d.outcome),
                "at_s": d.at.as_secs_f64(),
            }),
            ManagerEvent::SourcesChanged { added, removed } => json!({
                "type": "sources-changed",
                "added": added.iter().map(source_json).collect::<Vec<_>>(),
                "removed": removed,
            }),
            ManagerEvent::ClosePeer {
                peer,
                reason,
                clients,
            } => json!({"type": "close-peer", "peer": peer, "clients": clients,
            "reason": match reason {
                CloseReason::Wire(e) => json!({"kind": "wire", "error": wire_error_json(e)}),
                CloseReason::Unexpected(code) => json!({"kind": "unexpected", "code": code}),
                CloseReason::Lost => json!({"kind": "lost"}),
                CloseReason::SlowConsumer => json!({"kind": "slow-consumer"}),
            }}),
        },
    }
}

#[cfg(test)]
mod json_tests {
    use super::*;

    /// No `Debug` text (`Name { … }`, `Name(…)`) in any string of a JSON value.
    fn no_debug_text(v: &Value) {
        match v {
            Value::String(s) => assert!(
                !s.contains('{') && !s.contains('(') && !s.contains("::"),
                "Debug-looking text {s:?}"
            ),
            Value::Array(a) => a.iter().for_each(no_debug_text),
            Value::Object(o) => o.values().for_each(no_debug_text),
            _ => {}
        }
    }

    #[test]
    fn manager_events_are_json_objects_not_debug_text() {
        let events = [
            ManagerNetEvent::Core(ManagerEvent::SourcesChanged {
                added: vec![SourceInfo::new("counter", "counter", 1, 10.0)],
                removed: vec!["old".into()],
            }),
            ManagerNetEvent::Core(ManagerEvent::ClosePeer {
                peer: 3,
                reason: CloseReason::Wire(WireError::BadMac),
                clients: vec![7],
            }),
            ManagerNetEvent::DataClosed {
                source: Some("ses".into()),
                reason: DataClose::Revoked(RevokeReason::SourceGone),
            },
            ManagerNetEvent::SessionOpened {
                peer: 1,
                addr: "127.0.0.1:9".parse().unwrap(),
            },
        ];
        for e in &events {
            let v = manager_event_json(e);
            assert!(v["type"].is_string(), "{v}");
            no_debug_text(&v);
        }
        let v = manager_event_json(&events[0]);
        assert_eq!(v["type"], "sources-changed");
        assert_eq!(v["added"][0]["name"], "counter");
        assert_eq!(v["added"][0]["rate_mhz"], 10_000);
        let v = manager_event_json(&events[1]);
        assert_eq!(v["reason"]["error"]["kind"], "bad-mac");
        let v = end_reason_json(&EndReason::Data(DataClose::Wire(WireError::Truncated {
            need: 4,
            got: 1,
        })));
        assert_eq!(
            v["close"]["error"],
            json!({"kind": "truncated", "need": 4, "got": 1})
        );
        no_debug_text(&loss_reason_json(&LossReason::Revoked(
            RevokeReason::TaskPriority,
        )));
    }
}
