//! The commander console in the browser (`ima commander --web`, `ima demo --web`).
//!
//! A [`Console`] holds what the page shows ([`state::ConsoleState`]), fed from the mission
//! runtimes' typed events ([`ima_agents::runtime::Events`], made
//! [`detailed`](ima_agents::runtime::Events::detailed): call [`Console::apply`] for each), and
//! passes the page's commands to the commander as [`Operator`] requests, the same requests
//! the text commander's stdin produces, so both go through the one commander logic.
//!
//! [`start`] serves it on its own thread (an axum server on a current-thread runtime):
//!
//! * `GET /` — the page (HTML, CSS and JS embedded in the binary from `src/web/assets/`);
//! * `GET /api/state` — the state as one JSON object (`type: state`);
//! * `GET /api/events` — server-sent events: the state again (event `state`) whenever it
//!   changes, at most four times a second per client;
//! * `POST /api/command` — one [`msg::Command`] as JSON; answered with a [`msg::Reply`].
//!
//! Bound beyond loopback the console asks for a token: `?token=` in the URL (the page passes it
//! on) or an `x-ima-token` header. The group key stays in the `ima` process: the browser only
//! ever gets the state and the replies.

pub mod feed;
pub mod msg;
pub mod state;

use std::net::SocketAddr;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use anyhow::{Context, Result};
use axum::Router;
use axum::extract::{Request, State};
use axum::http::{StatusCode, header};
use axum::middleware::Next;
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use serde_json::{Value, json};
use tokio::sync::mpsc::UnboundedSender;

use ima_agents::runtime::Event;
use ima_agents::runtime::commander::Operator;
use msg::Reply;
use state::ConsoleState;

const INDEX_HTML: &str = include_str!("assets/index.html");
const APP_JS: &str = include_str!("assets/app.js");
const STYLE_CSS: &str = include_str!("assets/style.css");

/// Event kinds reported for the console only ([`ima_agents::runtime::Events::detailed`]);
/// text displays leave them out.
pub const DETAIL_KINDS: &[&str] = &["queue", "san", "map", "peer-status"];

/// Default address of `--web` without a value.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8080";

/// Shortest time between two state pushes to one client.
const PUSH_EVERY: Duration = Duration::from_millis(250);

/// The console: state, change notification, the commander's request queue and the token.
pub struct Console {
    state: Mutex<ConsoleState>,
    changed: tokio::sync::watch::Sender<u64>,
    ops: Mutex<Option<UnboundedSender<Operator>>>,
    token: Option<String>,
    cache: Mutex<(u64, Arc<str>)>,
}

impl std::fmt::Debug for Console {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Console")
    }
}

impl Console {
    /// A console in `mode` (`commander`, `demo`) offering `colours`, sending requests to
    /// `ops` (none: read-only), asking for `token` when one is given.
    pub fn new(
        mode: &str,
        colours: Vec<String>,
        ops: Option<UnboundedSender<Operator>>,
        token: Option<String>,
    ) -> Arc<Self> {
        let (changed, _) = tokio::sync::watch::channel(0);
        Arc::new(Self {
            state: Mutex::new(ConsoleState::new(mode, colours)),
            changed,
            ops: Mutex::new(ops),
            token,
            cache: Mutex::new((u64::MAX, Arc::from(""))),
        })
    }

    /// Change the state with `f` and tell the clients.
    pub fn update<T>(&self, f: impl FnOnce(&mut ConsoleState) -> T) -> T {
        let (r, v) = {
            let mut s = self.state.lock().unwrap_or_else(PoisonError::into_inner);
            let r = f(&mut s);
            (r, s.version)
        };
        self.changed.send_replace(v);
        r
    }

    /// Take one runtime event.
    pub fn apply(&self, e: &Event) {
        self.update(|s| s.apply(e));
    }

    /// Take one event in its JSON form.
    #[cfg(test)]
    pub fn apply_json(&self, e: &state::JsonEvent) {
        self.update(|s| s.apply_json(e));
    }

    /// The commander no longer takes requests (the mission is over).
    pub fn close_commands(&self) {
        *self.ops.lock().unwrap_or_else(PoisonError::into_inner) = None;
    }

    /// The state as JSON text (serialised once per version).
    pub fn snapshot_text(&self) -> Arc<str> {
        let s = self.state.lock().unwrap_or_else(PoisonError::into_inner);
        let mut c = self.cache.lock().unwrap_or_else(PoisonError::into_inner);
        if c.0 != s.version {
            *c = (s.version, Arc::from(s.snapshot().to_string()));
        }
        Arc::clone(&c.1)
    }

    /// Carry out a command body from the page; the reply is also kept as a notice.
    pub fn command(&self, body: &[u8]) -> Reply {
        let reply = self.command_inner(body);
        self.update(|s| {
            s.notice(if reply.ok { "info" } else { "error" }, &reply.message);
        });
        reply
    }

    fn command_inner(&self, body: &[u8]) -> Reply {
        let cmd = match msg::parse_command(body) {
            Ok(c) => c,
            Err(e) => return Reply::refused(e),
        };
        let (op, lost) = {
            let mut s = self.state.lock().unwrap_or_else(PoisonError::into_inner);
            // An add counts the adds sent that the commander has not shown yet (`added` is
            // never below the queue shown).
            let len = match cmd {
                msg::Command::Add { .. } => s.added,
                _ => s.targets.len(),
            };
            let op = msg::to_operator(&cmd, &s.colours, len, |c| s.open_target(c)).and_then(|op| {
                // Only waiting targets move (the commander refuses the rest): say so
                // here, not "moved" and a refusal in the log after it.
                if let Operator::Move { from, to } = op {
                    for p in [from, to] {
                        let t = s.targets.get(p);
                        let state = t.and_then(|t| t["state"].as_str()).unwrap_or("?");
                        if state != "waiting" {
                            let colour = t.and_then(|t| t["target"].as_str()).unwrap_or("?");
                            return Err(format!(
                                "position {} holds {colour}, which is {state}: only waiting \
                                     targets move",
                                p.saturating_add(1)
                            ));
                        }
                    }
                }
                Ok(op)
            });
            if let Ok(Operator::Add(_)) = op {
                s.added = len.saturating_add(1);
            }
            (op, s.lost_robots())
        };
        let op = match op {
            Ok(op) => op,
            Err(e) => return Reply::refused(e),
        };
        let what = match &op {
            Operator::Add(c) => format!("target {c} added to the queue"),
            Operator::Cancel(c) => format!("target {c} cancelled"),
            // Positions as the page shows them, from 1.
            Operator::Move { from, to } => {
                let (from, to) = (from.saturating_add(1), to.saturating_add(1));
                format!("target moved from position {from} to {to}")
            }
            Operator::Stop(_) => "fleet stop sent".to_owned(),
            Operator::Resume => "fleet resume sent".to_owned(),
            Operator::Quit { .. } => "quit".to_owned(),
        };
        let sent = self
            .ops
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .as_ref()
            .is_some_and(|tx| tx.send(op).is_ok());
        if !sent {
            return Reply::refused(
                "the mission is over: the commander takes no more commands (the page only shows it)",
            );
        }
        if lost.is_empty() {
            Reply::ok(what)
        } else {
            Reply::ok(format!(
                "{what}; but {} {} lost and may not hear it",
                lost.join(", "),
                if lost.len() == 1 { "is" } else { "are" }
            ))
        }
    }

    fn authorised(&self, req: &Request) -> bool {
        let Some(want) = &self.token else {
            return true;
        };
        let from_header = req
            .headers()
            .get("x-ima-token")
            .and_then(|v| v.to_str().ok());
        let from_query = req
            .uri()
            .query()
            .and_then(|q| q.split('&').find_map(|kv| kv.strip_prefix("token=")));
        [from_header, from_query]
            .into_iter()
            .flatten()
            .any(|got| same(got.as_bytes(), want.as_bytes()))
    }
}

/// The reason to refuse `req` as one that may come from another web site, which must neither
/// command the robots nor read the console; `None` lets it through.
///
/// Any page the operator's browser opens can send a "simple" cross-site POST (no CORS
/// preflight) to a console on loopback, which has no token: before this check such a page
/// could resume a stopped fleet. So a command must be JSON (`Content-Type:
/// application/json`, which a cross-site page can only send after a preflight this server
/// never grants) and, when the browser names its `Origin`, come from this console's own.
/// Without a token (`loopback`), the `Host` must also be a loopback name, so a page whose
/// domain was re-bound to 127.0.0.1 (DNS rebinding) reads and commands nothing.
fn cross_site(req: &Request, loopback: bool) -> Option<String> {
    let host = req
        .headers()
        .get(header::HOST)
        .and_then(|v| v.to_str().ok())
        .or_else(|| req.uri().authority().map(|a| a.as_str()))
        .unwrap_or("");
    if loopback && !is_loopback_host(host) {
        return Some(format!(
            "Host {host:?} is not a loopback name; open http://127.0.0.1:PORT or \
             http://localhost:PORT"
        ));
    }
    // Only a POST (the commands) or its CORS preflight can change anything; any other method
    // is answered 405 by the routes.
    if !matches!(
        *req.method(),
        axum::http::Method::POST | axum::http::Method::OPTIONS
    ) {
        return None;
    }
    if let Some(origin) = req.headers().get(header::ORIGIN) {
        let origin = origin.to_str().unwrap_or("?");
        let site = origin
            .strip_prefix("http://")
            .or_else(|| origin.strip_prefix("https://"));
        if !site.is_some_and(|s| s.eq_ignore_ascii_case(host)) {
            return Some(format!("a command from another site ({origin})"));
        }
    }
    let json = req
        .headers()
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|t| {
            t.trim_start()
                .to_ascii_lowercase()
                .starts_with("application/json")
        });
    (!json).then(|| "a command must be JSON (Content-Type: application/json)".to_owned())
}

/// `localhost`, `127.x.x.x` or `[::1]`, with or without a port (digits after a colon).
fn is_loopback_host(host: &str) -> bool {
    let (name, port) = match host.strip_prefix('[') {
        Some(v6) => v6.split_once(']').unwrap_or(("", "")),
        None => host.rfind(':').map_or((host, ""), |i| host.split_at(i)),
    };
    let port_ok = port.is_empty()
        || port
            .strip_prefix(':')
            .is_some_and(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()));
    let name = name.strip_suffix('.').unwrap_or(name);
    let loopback = name.eq_ignore_ascii_case("localhost")
        || name
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback());
    port_ok && loopback
}

/// Compares without stopping at the first difference.
fn same(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// A fresh random token (128 bits, hex).
pub fn random_token() -> String {
    use ima_agents::peer::net::random_u64;
    format!("{:016x}{:016x}", random_u64(), random_u64())
}

/// Parses a `--web` address; a host of `localhost` means 127.0.0.1.
pub fn parse_addr(s: &str) -> Result<SocketAddr> {
    socket_addr(s).with_context(|| {
        format!(
            "--web {:?}: not an address such as {DEFAULT_ADDR}, 0.0.0.0:8080 or a port alone",
            s.trim()
        )
    })
}

/// `ip:port`, `localhost:port` or a port alone (both on 127.0.0.1), surrounding blanks
/// ignored: the addresses `--web` and `--foxglove` take (`--web 0` was refused, though its
/// help says port 0 picks a free one).
pub fn socket_addr(s: &str) -> Option<SocketAddr> {
    let s = s.trim();
    let port_alone = !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    let s = if port_alone {
        format!("localhost:{s}")
    } else {
        s.to_owned()
    };
    match s.strip_prefix("localhost:") {
        Some(port) => port
            .parse()
            .ok()
            .map(|p| SocketAddr::from(([127, 0, 0, 1], p))),
        None => s.parse().ok(),
    }
}

/// The ground-truth world for the map: walls, round obstacles and the coloured objects.
pub fn world_json(w: &ima_mock_devices::world::World) -> Value {
    let walls: Vec<Value> = w.walls().iter().map(|x| json!([x.from, x.to])).collect();
    let circles: Vec<Value> = w
        .circles()
        .iter()
        .map(|c| json!({"center": c.center, "radius_m": c.radius_m}))
        .collect();
    let objects: Vec<Value> = w
        .objects()
        .iter()
        .map(
            |o| json!({"color": o.color, "rgb": o.rgb, "center": o.center, "radius_m": o.radius_m}),
        )
        .collect();
    json!({"walls": walls, "circles": circles, "objects": objects})
}

/// The running server; dropped, it ends (and its thread is joined).
#[derive(Debug)]
pub struct WebServer {
    /// The address it is bound to (the port chosen when 0 was asked).
    pub addr: SocketAddr,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl WebServer {
    fn end(&mut self) {
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(());
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for WebServer {
    fn drop(&mut self) {
        self.end();
    }
}

/// The URL to open (with the token when there is one). A console bound to every address
/// (`0.0.0.0`, `[::]`) is named by its loopback address, which a browser can open.
pub fn url(addr: SocketAddr, token: Option<&str>) -> String {
    let mut addr = addr;
    if addr.ip().is_unspecified() {
        addr.set_ip(match addr.ip() {
            std::net::IpAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
            std::net::IpAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
        });
    }
    match token {
        Some(t) => format!("http://{addr}/?token={t}"),
        None => format!("http://{addr}/"),
    }
}

/// Serve `console` on `addr` from a thread of its own. Bound beyond loopback, the console
/// must have a token ([`Console::new`]).
pub fn start(console: Arc<Console>, addr: SocketAddr) -> Result<WebServer> {
    anyhow::ensure!(
        addr.ip().is_loopback() || console.token.is_some(),
        "--web {addr}: beyond loopback the console needs a token"
    );
    let listener = std::net::TcpListener::bind(addr)
        .with_context(|| format!("--web {addr}: binding the console's address"))?;
    listener.set_nonblocking(true)?;
    let addr = listener.local_addr()?;
    let (tx, rx) = tokio::sync::oneshot::channel::<()>();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the console's runtime")?;
    let thread = std::thread::Builder::new()
        .name("ima-web".into())
        .spawn(move || {
            rt.block_on(async move {
                let listener = match tokio::net::TcpListener::from_std(listener) {
                    Ok(l) => l,
                    Err(e) => {
                        eprintln!("ima: web console: {e}");
                        return;
                    }
                };
                tokio::select! {
                    () = serve(listener, router(console), HEADER_TIMEOUT) => {}
                    _ = rx => {}
                }
            });
        })
        .context("starting the console's thread")?;
    Ok(WebServer {
        addr,
        shutdown: Some(tx),
        thread: Some(thread),
    })
}

/// Most connections served at once; more are closed as they come (a page and its event
/// stream take two, so this is many operators).
pub const MAX_CONNECTIONS: usize = 64;

/// Longest a client may take to send a request's headers: a connection that sends them
/// slowly or not at all is closed after this, so it does not hold a place for ever.
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);

/// How long a write to a client may wait for it to read (an event stream nobody reads).
pub const WRITE_STALL: Duration = Duration::from_secs(30);

/// A client's connection whose writes may not wait longer than a limit for the client to
/// read: an event stream its client stopped reading is closed then, and its place freed.
struct WriteDeadline<S> {
    io: S,
    limit: Duration,
    /// Running while a write waits.
    waiting: Option<std::pin::Pin<Box<tokio::time::Sleep>>>,
}

impl<S> WriteDeadline<S> {
    fn new(io: S, limit: Duration) -> Self {
        Self {
            io,
            limit,
            waiting: None,
        }
    }

    /// What a write that returned `p` means: ready resets the clock; pending starts it, or
    /// is an error once the limit has passed.
    fn after<T>(
        &mut self,
        p: std::task::Poll<std::io::Result<T>>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<T>> {
        use std::future::Future as _;
        if p.is_ready() {
            self.waiting = None;
            return p;
        }
        let limit = self.limit;
        let clock = self
            .waiting
            .get_or_insert_with(|| Box::pin(tokio::time::sleep(limit)));
        match clock.as_mut().poll(cx) {
            std::task::Poll::Ready(()) => std::task::Poll::Ready(Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "the client has not read what was sent to it",
            ))),
            std::task::Poll::Pending => std::task::Poll::Pending,
        }
    }
}

impl<S: tokio::io::AsyncRead + Unpin> tokio::io::AsyncRead for WriteDeadline<S> {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.io).poll_read(cx, buf)
    }
}

impl<S: tokio::io::AsyncWrite + Unpin> tokio::io::AsyncWrite for WriteDeadline<S> {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        let p = std::pin::Pin::new(&mut self.io).poll_write(cx, buf);
        self.after(p, cx)
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        let p = std::pin::Pin::new(&mut self.io).poll_flush(cx);
        self.after(p, cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.io).poll_shutdown(cx)
    }
}

/// Accept connections and serve `app` on each (HTTP/1.1), at most [`MAX_CONNECTIONS`] at
/// once, each closed when its next request's headers take over `header_timeout`
/// ([`HEADER_TIMEOUT`]), when a request's response does not start within it (a body that
/// trickles in), or when a write waits over [`WRITE_STALL`] for the client to read.
/// `axum::serve` sets none of these, so a few thousand half-sent requests used to exhaust the
/// process's file descriptors and lock the operator out.
async fn serve(listener: tokio::net::TcpListener, app: Router, header_timeout: Duration) {
    use hyper_util::rt::{TokioIo, TokioTimer};
    let places = Arc::new(tokio::sync::Semaphore::new(MAX_CONNECTIONS));
    let mut turned_away = 0u64;
    loop {
        let stream = match listener.accept().await {
            Ok((stream, _)) => stream,
            // Out of descriptors, a connection reset before it was taken…: try again soon.
            Err(e) => {
                tracing::debug!("web console: accept: {e}");
                tokio::time::sleep(Duration::from_millis(50)).await;
                continue;
            }
        };
        let Ok(place) = Arc::clone(&places).try_acquire_owned() else {
            turned_away += 1;
            // Warned at the 1st, 2nd, 4th, 8th… (a flood cannot flood the log).
            if turned_away.is_power_of_two() {
                tracing::warn!(
                    "web console: {turned_away} connection(s) closed at once so far: \
                     {MAX_CONNECTIONS} are open"
                );
            }
            drop(stream);
            continue;
        };
        let service = hyper_util::service::TowerToHyperService::new(app.clone());
        tokio::spawn(async move {
            let served = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(header_timeout)
                .serve_connection(
                    TokioIo::new(WriteDeadline::new(stream, WRITE_STALL)),
                    service,
                )
                .await;
            if let Err(e) = served {
                tracing::debug!("web console: connection: {e}");
            }
            drop(place);
        });
    }
}

fn router(console: Arc<Console>) -> Router {
    Router::new()
        .route(
            "/",
            get(|| async { asset("text/html; charset=utf-8", INDEX_HTML) }),
        )
        .route(
            "/app.js",
            get(|| async { asset("text/javascript; charset=utf-8", APP_JS) }),
        )
        .route(
            "/style.css",
            get(|| async { asset("text/css; charset=utf-8", STYLE_CSS) }),
        )
        .route("/api/state", get(state_handler))
        .route("/api/events", get(events_handler))
        .route(
            "/api/command",
            post(command_handler).fallback(|| async {
                let how = "use POST with a JSON command such as {\"cmd\":\"stop\"}\n";
                (
                    StatusCode::METHOD_NOT_ALLOWED,
                    [(header::ALLOW, "POST")],
                    how,
                )
            }),
        )
        .layer(axum::middleware::from_fn_with_state(
            Arc::clone(&console),
            guard,
        ))
        .with_state(console)
}

fn asset(kind: &'static str, body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, kind),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}

async fn guard(State(c): State<Arc<Console>>, req: Request, next: Next) -> Response {
    if let Some(why) = cross_site(&req, c.token.is_none()) {
        // Warned at the 1st, 2nd, 4th, 8th… refusal: a hostile page cannot flood the log.
        static REFUSED: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = REFUSED.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
        if n.is_power_of_two() {
            tracing::warn!("web console: refused {n} request(s) so far; the last: {why}");
        }
        return (StatusCode::FORBIDDEN, format!("refused: {why}\n")).into_response();
    }
    // The page's script and style sheet hold no state and no secret, and the page loads them
    // without its token (a console beyond loopback served them only with 401, so its page
    // had no script: no live state, no fleet-stop key).
    let asset = matches!(req.uri().path(), "/app.js" | "/style.css");
    if asset || c.authorised(&req) {
        // The response's head within the deadline: a command's body that trickles in does
        // not hold a place for ever (an event stream's head goes at once).
        match tokio::time::timeout(HEADER_TIMEOUT, next.run(req)).await {
            Ok(r) => r,
            Err(_) => (
                StatusCode::REQUEST_TIMEOUT,
                format!(
                    "the request did not arrive within {} s\n",
                    HEADER_TIMEOUT.as_secs()
                ),
            )
                .into_response(),
        }
    } else {
        (
            StatusCode::UNAUTHORIZED,
            "this console needs its token: open the URL that ima printed (…/?token=…)\n",
        )
            .into_response()
    }
}

async fn state_handler(State(c): State<Arc<Console>>) -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        c.snapshot_text().to_string(),
    )
        .into_response()
}

async fn command_handler(State(c): State<Arc<Console>>, body: axum::body::Bytes) -> Response {
    let reply = c.command(&body);
    let status = if reply.ok {
        StatusCode::OK
    } else {
        StatusCode::BAD_REQUEST
    };
    (status, axum::Json(reply)).into_response()
}

async fn events_handler(State(c): State<Arc<Console>>) -> impl IntoResponse {
    let rx = c.changed.subscribe();
    let stream = futures_util::stream::unfold((c, rx, true), |(c, mut rx, first)| async move {
        if !first {
            tokio::time::sleep(PUSH_EVERY).await;
            // The console is gone (never while serving): end the stream.
            rx.changed().await.ok()?;
        }
        rx.borrow_and_update();
        let text = c.snapshot_text();
        let ev = SseEvent::default().event("state").data(&*text);
        Some((Ok::<_, std::convert::Infallible>(ev), (c, rx, false)))
    });
    Sse::new(stream).keep_alive(KeepAlive::default())
}

#[cfg(test)]
mod tests;
