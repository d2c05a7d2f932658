//! How a robot's runtime talks to the others.
//!
//! A runtime never opens a socket itself: its inputs (broadcasts heard, SES samples) and
//! outputs (what it says, SES re-requests) are bounded channels in a link value the caller
//! provides. [`ScooterLink::channels`] makes a bare link whose other ends the caller holds
//! (a simulation wires robots together in-process); [`ScooterLink::network`] runs the
//! Peer Agent network behind it: the broadcast channel ([`Bus`]), Scooter's client of
//! Skeeter's `ses` source with its reconnect and re-request policy, and Scooter's own
//! manager.

use core::time::Duration;

use ima_hal::time::SharedClock;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use super::events::{EventKind, Events, PeerClientView, PeerNote, PeerStatus};
use super::{MissionTime, RuntimeError};
use crate::mission::msg::{Broadcast, SES_SOURCE};
use crate::peer::manager::FixedSelfAgent;
use crate::peer::net::{
    BroadcastChannel, ManagerHandle, NetError, PeerClientHandle, PeerNetConfig, SubscriptionEvent,
    spawn_manager_with_clock,
};
use crate::peer::wire::GroupKey;
use crate::ses::shared::SharedForm;

/// Capacity of a link's queues.
pub const LINK_QUEUE: usize = 64;

/// The mission's broadcast channel: typed [`Broadcast`]s over a [`BroadcastChannel`].
#[derive(Debug, Clone)]
pub struct Bus {
    chan: std::sync::Arc<BroadcastChannel>,
}

impl Bus {
    /// Bind the broadcast channel of `net` as `net.robot`, on the process's `clock`.
    pub fn bind(
        net: &PeerNetConfig,
        key: GroupKey,
        clock: SharedClock,
    ) -> Result<Self, RuntimeError> {
        let chan = BroadcastChannel::bind_with_clock(net, &net.robot, key, clock)
            .map_err(|e| RuntimeError::Net(format!("binding the broadcast channel: {e}")))?;
        Ok(Self {
            chan: std::sync::Arc::new(chan),
        })
    }

    /// The channel underneath.
    #[must_use]
    pub fn channel(&self) -> &BroadcastChannel {
        &self.chan
    }

    /// Send a broadcast once (errors are logged: the broadcast channel is best-effort).
    pub async fn send(&self, b: &Broadcast) {
        let r = match b {
            Broadcast::Status {
                behaviour,
                san,
                pose,
                ..
            } => self.chan.send_status(behaviour, san, *pose).await,
            Broadcast::Emergency { emergency, .. } => {
                self.chan
                    .send_emergency(emergency.kind(), &emergency.text())
                    .await
            }
            Broadcast::Mission { event, target, .. } => {
                self.chan.send_mission(*event, target).await
            }
        };
        if let Err(e) = r {
            tracing::warn!("broadcast not sent: {e}");
        }
    }

    /// The next mission broadcast from another robot (unknown or malformed ones are skipped
    /// with a debug log).
    pub async fn recv(&self) -> Result<Broadcast, RuntimeError> {
        loop {
            let (msg, from) = self
                .chan
                .recv()
                .await
                .map_err(|e| RuntimeError::Net(format!("receiving broadcasts: {e}")))?;
            match Broadcast::from_wire(&msg) {
                Ok(b) => return Ok(b),
                Err(e) => tracing::debug!("ignoring a broadcast from {from}: {e}"),
            }
        }
    }

    /// Frames refused for a bad MAC since the last report (rate-limited, see
    /// [`BroadcastChannel::take_auth_report`]).
    pub fn take_auth_report(&self) -> Option<crate::peer::net::AuthFailure> {
        self.chan.take_auth_report()
    }

    /// Send what a robot's brain says: a status once; every other message (mission events,
    /// emergencies, target notices — the ones that must not be lost) three times 30 ms
    /// apart. Receivers drop duplicates by sequence number only, so the copies are new
    /// messages and the receivers are idempotent.
    pub async fn say(&self, b: &Broadcast) {
        let copies = if matches!(b, Broadcast::Status { .. }) {
            1
        } else {
            3
        };
        for i in 0..copies {
            if i > 0 {
                tokio::time::sleep(Duration::from_millis(30)).await;
            }
            self.send(b).await;
        }
    }

    /// A task handing every mission broadcast heard to `tx` (a socket error is logged and
    /// listening goes on; frames under another group key are reported through `on_auth`,
    /// checked once a second and rate-limited by the channel). It ends when `tx`'s receiver
    /// is dropped.
    pub fn spawn_reader(
        &self,
        tx: mpsc::Sender<Broadcast>,
        on_auth: impl Fn(crate::peer::net::AuthFailure) + Send + 'static,
    ) -> JoinHandle<()> {
        let bus = self.clone();
        tokio::spawn(async move {
            let mut check = tokio::time::interval(Duration::from_secs(1));
            check.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
            loop {
                let r = tokio::select! {
                    r = bus.recv() => r,
                    () = tx.closed() => return,
                    _ = check.tick() => {
                        if let Some(a) = bus.take_auth_report() {
                            on_auth(a);
                        }
                        continue;
                    }
                };
                match r {
                    Ok(b) => {
                        if tx.send(b).await.is_err() {
                            return;
                        }
                    }
                    Err(e) => {
                        tracing::warn!("broadcast channel: {e}");
                        tokio::time::sleep(Duration::from_millis(200)).await;
                    }
                }
            }
        })
    }

    /// A task saying every broadcast queued on `rx` ([`Bus::say`]); ends when every sender
    /// is dropped.
    pub fn spawn_sayer(&self, mut rx: mpsc::Receiver<Broadcast>) -> JoinHandle<()> {
        let bus = self.clone();
        tokio::spawn(async move {
            while let Some(b) = rx.recv().await {
                bus.say(&b).await;
            }
        })
    }
}

/// Reports refused frames as [`EventKind::AuthFailure`] events.
fn auth_reporter(
    events: &Events,
    time: &MissionTime,
    robot: &str,
) -> impl Fn(crate::peer::net::AuthFailure) + Send + 'static {
    let (events, time, robot) = (events.clone(), time.clone(), robot.to_owned());
    move |a| events.emit(&time, &robot, EventKind::AuthFailure(a.to_string()))
}

/// Scooter's request for Skeeter's `ses` source over the Peer Agent network.
#[derive(Debug, Clone)]
pub struct SesRequest {
    /// Skeeter's manager, `host:port`.
    pub manager: String,
    /// The request's priority.
    pub priority: u8,
    /// Wait between reconnection attempts.
    pub retry_after: Duration,
}

/// Scooter's side of its link to the other robots (see the [module docs](self)).
#[derive(Debug)]
pub struct ScooterLink {
    /// SES samples from Skeeter.
    pub ses: mpsc::Receiver<SharedForm>,
    /// Mission broadcasts heard from the other robots.
    pub heard: mpsc::Receiver<Broadcast>,
    /// Asks for a fresh SES sample (over the network: a new request of Skeeter's source,
    /// which Skeeter answers by scanning). Sent with `try_send`: a pending ask is enough.
    pub rerequest: mpsc::Sender<()>,
    /// What Scooter says (over the network: statuses once, the others three times).
    /// Sent with `try_send`: a full queue loses the message (logged), never the robot's time.
    pub say: mpsc::Sender<Broadcast>,
    tasks: Vec<JoinHandle<()>>,
    manager: Option<ManagerHandle>,
    bus: Option<Bus>,
    client: Option<ClientSlot>,
}

/// The `ses` client's view and its current session, shared between [`ses_loop`] and
/// [`ScooterLink::peer_status`]. Weak: the status never keeps a session open.
#[derive(Debug, Default)]
struct ClientShared {
    view: PeerClientView,
    session: std::sync::Weak<PeerClientHandle>,
}

type ClientSlot = std::sync::Arc<std::sync::Mutex<ClientShared>>;

fn slot(s: &ClientSlot) -> std::sync::MutexGuard<'_, ClientShared> {
    s.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The caller's ends of [`ScooterLink::channels`].
#[derive(Debug)]
pub struct ScooterLinkEnds {
    /// Feeds SES samples to Scooter.
    pub ses: mpsc::Sender<SharedForm>,
    /// Feeds broadcasts heard to Scooter.
    pub heard: mpsc::Sender<Broadcast>,
    /// Scooter's requests for a fresh SES.
    pub rerequest: mpsc::Receiver<()>,
    /// What Scooter says.
    pub say: mpsc::Receiver<Broadcast>,
}

impl ScooterLink {
    /// A link of bare channels ([`LINK_QUEUE`] each) and the caller's ends.
    #[must_use]
    pub fn channels() -> (Self, ScooterLinkEnds) {
        let (ses_tx, ses) = mpsc::channel(LINK_QUEUE);
        let (heard_tx, heard) = mpsc::channel(LINK_QUEUE);
        let (rerequest, rerequest_rx) = mpsc::channel(1);
        let (say, say_rx) = mpsc::channel(LINK_QUEUE);
        (
            Self {
                ses,
                heard,
                rerequest,
                say,
                tasks: Vec::new(),
                manager: None,
                bus: None,
                client: None,
            },
            ScooterLinkEnds {
                ses: ses_tx,
                heard: heard_tx,
                rerequest: rerequest_rx,
                say: say_rx,
            },
        )
    }

    /// The link over the Peer Agent network: binds the broadcast channel of `net`, starts
    /// Scooter's own manager when `net.manager.listen` is set, and (with `ses`) a client
    /// that requests Skeeter's `ses` source, reconnecting after `retry_after` whenever the
    /// connection or the subscription ends, and requesting again when asked through
    /// [`ScooterLink::rerequest`]. Link news goes to `events` as [`EventKind::Peer`].
    /// The tasks end when the link is dropped.
    pub async fn network(
        net: &PeerNetConfig,
        key: GroupKey,
        ses: Option<SesRequest>,
        events: Events,
        time: MissionTime,
    ) -> Result<Self, RuntimeError> {
        let bus = Bus::bind(net, key.clone(), time.clock().clone())?;
        let manager = if net.manager.listen.is_empty() {
            None
        } else {
            Some(
                spawn_manager_with_clock(
                    net,
                    key.clone(),
                    FixedSelfAgent::default(),
                    time.clock().clone(),
                )
                .await
                .map_err(|e| RuntimeError::Net(format!("starting Scooter's manager: {e}")))?,
            )
        };
        let (mut link, ends) = Self::channels();
        let ScooterLinkEnds {
            ses: ses_tx,
            heard: heard_tx,
            rerequest,
            say,
        } = ends;
        link.tasks
            .push(bus.spawn_reader(heard_tx, auth_reporter(&events, &time, &net.robot)));
        link.tasks.push(bus.spawn_sayer(say));
        if let Some(req) = ses {
            let shared = ClientSlot::default();
            {
                let mut s = slot(&shared);
                s.view.manager.clone_from(&req.manager);
                SES_SOURCE.clone_into(&mut s.view.source);
                s.view.priority = req.priority;
                "connecting".clone_into(&mut s.view.outcome);
            }
            link.client = Some(std::sync::Arc::clone(&shared));
            link.tasks.push(tokio::spawn(ses_loop(
                req,
                (rerequest, shared),
                net.clone(),
                key,
                ses_tx,
                events,
                time,
            )));
        }
        link.manager = manager;
        link.bus = Some(bus);
        Ok(link)
    }

    /// The link's Peer Agent counters and status (network links only), with its `ses`
    /// client's view.
    pub async fn peer_status(&self) -> Option<PeerStatus> {
        let mut p = peer_status(self.bus.as_ref(), self.manager.as_ref()).await?;
        if let Some(c) = &self.client {
            let (mut view, session) = {
                let s = slot(c);
                (s.view.clone(), s.session.upgrade())
            };
            if let Some(h) = session {
                view.link = h.link_status().await.ok();
            }
            p.client = Some(view);
        }
        Some(p)
    }
}

/// The counters of `bus` and the status of `manager`, if there is either.
async fn peer_status(bus: Option<&Bus>, manager: Option<&ManagerHandle>) -> Option<PeerStatus> {
    if bus.is_none() && manager.is_none() {
        return None;
    }
    let (stats, clients, address) = match manager {
        Some(m) => match m.snapshot().await {
            Ok((s, c)) => (Some(s), c, Some(m.local_addr().to_string())),
            Err(_) => (None, Vec::new(), Some(m.local_addr().to_string())),
        },
        None => (None, Vec::new(), None),
    };
    Some(PeerStatus {
        broadcast: bus.map(|b| b.channel().stats()),
        manager: stats,
        clients,
        address,
        client: None,
    })
}

impl Drop for ScooterLink {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

/// Scooter's subscription to Skeeter's `ses` source: connect, register, request; forward
/// samples; on a re-request disconnect and request again (Skeeter answers a fresh grant
/// with its latest SES); on any failure wait and start over.
async fn ses_loop(
    req: SesRequest,
    (mut rerequest, shared): (mpsc::Receiver<()>, ClientSlot),
    net: PeerNetConfig,
    key: GroupKey,
    tx: mpsc::Sender<SharedForm>,
    events: Events,
    time: MissionTime,
) {
    let me = net.robot.clone();
    let note = |n: PeerNote| {
        {
            let mut s = slot(&shared);
            match &n {
                PeerNote::Granted { .. } => {
                    s.view.grants = s.view.grants.saturating_add(1);
                    "granted".clone_into(&mut s.view.outcome);
                }
                PeerNote::Lost { lost } => s.view.outcome = format!("lost: {lost}"),
                PeerNote::Retry { retry } => {
                    s.view.retries = s.view.retries.saturating_add(1);
                    s.view.outcome = format!("retrying: {retry}");
                }
            }
        }
        events.emit(&time, &me, EventKind::Peer(n));
    };
    loop {
        let r: Result<(), String> = async {
            let client = std::sync::Arc::new(
                PeerClientHandle::connect_with_clock(
                    req.manager.as_str(),
                    &net,
                    key.clone(),
                    time.clock().clone(),
                )
                .await
                .map_err(|e| connect_failed(&req.manager, &e))?,
            );
            slot(&shared).session = std::sync::Arc::downgrade(&client);
            "requesting".clone_into(&mut slot(&shared).view.outcome);
            client.register().await.map_err(|e| e.to_string())?;
            let mut sub = client
                .request(SES_SOURCE, req.priority)
                .await
                .map_err(|e| e.to_string())?;
            note(PeerNote::Granted {
                granted: SES_SOURCE.to_owned(),
                priority: Some(req.priority),
                manager: Some(req.manager.clone()),
                again: None,
                to: None,
            });
            loop {
                let ev = tokio::select! {
                    ev = sub.next() => ev,
                    Some(()) = rerequest.recv() => {
                        let _ = client.disconnect(SES_SOURCE).await;
                        sub = client
                            .request(SES_SOURCE, req.priority)
                            .await
                            .map_err(|e| e.to_string())?;
                        note(PeerNote::Granted {
                            granted: SES_SOURCE.to_owned(),
                            priority: Some(req.priority),
                            manager: None,
                            again: Some(true),
                            to: None,
                        });
                        continue;
                    }
                };
                let Some(ev) = ev else { break };
                match ev {
                    SubscriptionEvent::Sample { payload, .. } => {
                        {
                            let mut s = slot(&shared);
                            s.view.samples = s.view.samples.saturating_add(1);
                        }
                        match SharedForm::decode(&payload) {
                            Ok(f) => {
                                if tx.send(f).await.is_err() {
                                    return Ok(());
                                }
                            }
                            Err(e) => tracing::warn!("bad SES sample: {e}"),
                        }
                    }
                    SubscriptionEvent::Lost { reason } => note(PeerNote::Lost {
                        lost: reason.to_string(),
                    }),
                    SubscriptionEvent::Closed { reason } => {
                        return Err(format!("subscription closed: {reason}"));
                    }
                }
            }
            Err("subscription ended".to_owned())
        }
        .await;
        if let Err(e) = r {
            note(PeerNote::Retry { retry: e });
        }
        if tx.is_closed() {
            return;
        }
        tokio::time::sleep(req.retry_after).await;
    }
}

/// A grant of Skeeter's `ses` source as its runtime sees it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SesGrant {
    /// The source was granted to `to`: Skeeter answers with a fresh heading.
    Granted {
        /// The robot it was granted to.
        to: String,
    },
    /// `missed` manager events were lost (the queue lagged); a grant may be among them.
    Lagged {
        /// How many.
        missed: u64,
    },
}

/// Skeeter's side of its link to the other robots (see the [module docs](self)).
#[derive(Debug)]
pub struct SkeeterLink {
    /// Mission broadcasts heard from the other robots.
    pub heard: mpsc::Receiver<Broadcast>,
    /// What Skeeter says (over the network: statuses once, the others three times).
    pub say: mpsc::Sender<Broadcast>,
    /// Grants of its `ses` source. Closed: the manager stopped, which ends the runtime.
    pub grants: mpsc::Receiver<SesGrant>,
    /// SES forms to publish on its `ses` source (sent with `try_send`).
    pub publish: mpsc::Sender<SharedForm>,
    manager: Option<ManagerHandle>,
    bus: Option<Bus>,
    tasks: Vec<JoinHandle<()>>,
}

/// The caller's ends of [`SkeeterLink::channels`].
#[derive(Debug)]
pub struct SkeeterLinkEnds {
    /// Feeds broadcasts heard to Skeeter.
    pub heard: mpsc::Sender<Broadcast>,
    /// What Skeeter says.
    pub say: mpsc::Receiver<Broadcast>,
    /// Feeds grants of its `ses` source.
    pub grants: mpsc::Sender<SesGrant>,
    /// The SES forms Skeeter publishes.
    pub publish: mpsc::Receiver<SharedForm>,
}

impl SkeeterLink {
    /// A link of bare channels ([`LINK_QUEUE`] each) and the caller's ends.
    #[must_use]
    pub fn channels() -> (Self, SkeeterLinkEnds) {
        let (heard_tx, heard) = mpsc::channel(LINK_QUEUE);
        let (say, say_rx) = mpsc::channel(LINK_QUEUE);
        let (grants_tx, grants) = mpsc::channel(LINK_QUEUE);
        let (publish, publish_rx) = mpsc::channel(LINK_QUEUE);
        (
            Self {
                heard,
                say,
                grants,
                publish,
                manager: None,
                bus: None,
                tasks: Vec::new(),
            },
            SkeeterLinkEnds {
                heard: heard_tx,
                say: say_rx,
                grants: grants_tx,
                publish: publish_rx,
            },
        )
    }

    /// The link over the Peer Agent network: binds the broadcast channel of `net`, starts
    /// Skeeter's manager with its `ses` source (`publish` stamps samples with mission
    /// time), and turns the manager's grant decisions of that source into
    /// [`SesGrant`]s.
    pub async fn network(
        net: &PeerNetConfig,
        key: GroupKey,
        events: Events,
        time: MissionTime,
    ) -> Result<Self, RuntimeError> {
        use crate::mission::msg::{SES_SOURCE_KIND, SES_SOURCE_SCHEMA};
        use crate::peer::manager::{ManagerEvent, Outcome};
        use crate::peer::net::ManagerNetEvent;
        use crate::peer::wire::SourceInfo;

        let bus = Bus::bind(net, key.clone(), time.clock().clone())?;
        let manager =
            spawn_manager_with_clock(net, key, FixedSelfAgent::default(), time.clock().clone())
                .await
                .map_err(|e| RuntimeError::Net(format!("starting Skeeter's manager: {e}")))?;
        let mut decisions = manager.events();
        let ses = manager
            .publisher(SourceInfo {
                name: SES_SOURCE.to_owned(),
                kind: SES_SOURCE_KIND.to_owned(),
                schema: SES_SOURCE_SCHEMA,
                rate_mhz: 300,
            })
            .map_err(|e| RuntimeError::Net(format!("registering the `ses` source: {e}")))?;
        let (mut link, ends) = Self::channels();
        let SkeeterLinkEnds {
            heard,
            say,
            grants,
            mut publish,
        } = ends;
        link.tasks
            .push(bus.spawn_reader(heard, auth_reporter(&events, &time, &net.robot)));
        link.tasks.push(bus.spawn_sayer(say));
        link.tasks.push(tokio::spawn(async move {
            use tokio::sync::broadcast::error::RecvError;
            loop {
                let g = match decisions.recv().await {
                    Ok(ManagerNetEvent::Core(ManagerEvent::Decision(d)))
                        if d.source == SES_SOURCE && d.outcome == Outcome::Granted =>
                    {
                        SesGrant::Granted { to: d.robot }
                    }
                    Ok(_) => continue,
                    Err(RecvError::Lagged(n)) => SesGrant::Lagged { missed: n },
                    // The manager stopped: dropping `grants` tells the runtime.
                    Err(RecvError::Closed) => return,
                };
                if grants.send(g).await.is_err() {
                    return;
                }
            }
        }));
        link.tasks.push(tokio::spawn(async move {
            while let Some(form) = publish.recv().await {
                match form.to_bytes() {
                    Ok(bytes) => {
                        if let Err(e) = ses.publish(time.now().as_micros(), &bytes) {
                            tracing::warn!("publishing the SES: {e}");
                        }
                    }
                    Err(e) => tracing::warn!("encoding the SES: {e}"),
                }
            }
        }));
        link.manager = Some(manager);
        link.bus = Some(bus);
        Ok(link)
    }

    /// The link's Peer Agent counters and status (network links only).
    pub async fn peer_status(&self) -> Option<PeerStatus> {
        peer_status(self.bus.as_ref(), self.manager.as_ref()).await
    }

    /// Where the link's manager listens (network links only).
    #[must_use]
    pub fn manager_addr(&self) -> Option<String> {
        self.manager.as_ref().map(|m| m.local_addr().to_string())
    }

    /// End the link: its tasks stop and its manager (if any) closes its sessions cleanly.
    pub async fn shutdown(mut self) {
        for t in &self.tasks {
            t.abort();
        }
        if let Some(m) = self.manager.take() {
            m.shutdown().await;
        }
    }
}

impl Drop for SkeeterLink {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

/// Why the subscriber could not reach the manager at `manager`, naming it; a refused
/// connection (nothing listens there) asks whether that robot runs yet: the usual case when
/// the robots are started one after the other.
fn connect_failed(manager: &str, e: &NetError) -> String {
    let refused =
        matches!(e, NetError::Io(io) if io.kind() == std::io::ErrorKind::ConnectionRefused);
    let hint = if refused {
        " (nothing listens there: is that robot running yet?)"
    } else {
        ""
    };
    format!("reaching the manager at {manager}: {e}{hint}")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Scooter started before Skeeter said "I/O error: Connection refused (os error 111)"
    /// every 5 s, naming neither the address nor why.
    #[test]
    fn a_manager_not_reached_is_named() {
        let refused = NetError::Io(std::io::Error::from(std::io::ErrorKind::ConnectionRefused));
        let text = connect_failed("10.0.0.5:7400", &refused);
        assert!(
            text.starts_with("reaching the manager at 10.0.0.5:7400: I/O error: "),
            "{text}"
        );
        assert!(
            text.ends_with("(nothing listens there: is that robot running yet?)"),
            "{text}"
        );
        let other = connect_failed("10.0.0.5:7400", &NetError::Timeout);
        assert_eq!(
            other,
            "reaching the manager at 10.0.0.5:7400: the manager did not answer in time"
        );
    }
}
