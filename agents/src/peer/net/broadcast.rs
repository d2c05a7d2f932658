//! The broadcast channel over UDP: multicast (socket2 options) and/or a unicast peer list.

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::sync::{Arc, Mutex, PoisonError};

use ima_hal::time::{Clock, SharedClock, TokioClock};
use socket2::{Domain, Protocol, Socket, Type};
use tokio::net::UdpSocket;

use super::config::{BroadcastConfig, BroadcastMode, PeerNetConfig, parse_ip_addr};
use super::{AuthFailure, NetError, random_id, unix_micros};
use crate::peer::broadcast::{BroadcastReceiver, Broadcaster, ReceiverConfig, ReceiverStats};
use crate::peer::wire::{
    GroupKey, HEADER_LEN, MAC_LEN, MissionEvent, Msg, Pose, RejectCounts, WireError,
};

/// Counters of a [`BroadcastChannel`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BroadcastStats {
    /// The receiver core's counters (accepted, wire rejections, duplicates, stale).
    pub receiver: ReceiverStats,
    /// Wire rejections by class (bad MAC, replay, malformed…).
    pub wire: RejectCounts,
    /// Datagrams sent (one per destination).
    pub sent: u64,
    /// Sends that failed.
    pub send_errors: u64,
    /// This robot's own broadcasts skipped by `recv` (see `receive_own`).
    pub own: u64,
}

/// Shortest interval between two [`BroadcastChannel::take_auth_report`]s (the first
/// rejection is reported at once).
pub const AUTH_REPORT_INTERVAL: core::time::Duration = core::time::Duration::from_secs(10);

struct Inner {
    tx: Broadcaster,
    rx: BroadcastReceiver,
    sent: u64,
    send_errors: u64,
    own: u64,
    /// Sender of the last datagram refused for a bad MAC.
    bad_mac_from: Option<SocketAddr>,
    /// Bad-MAC count at the last report.
    bad_mac_reported: u64,
    /// When the last report was taken.
    last_auth_report: Option<ima_hal::Instant>,
}

/// One robot's (or the commander's) end of the broadcast channel. Cheap to clone; `recv`
/// and the senders may be used from different tasks.
#[derive(Clone)]
pub struct BroadcastChannel {
    socket: Arc<UdpSocket>,
    inner: Arc<Mutex<Inner>>,
    dests: Arc<Vec<SocketAddr>>,
    robot: String,
    receive_own: bool,
    clock: SharedClock,
    max_body: usize,
    /// Allowed skew of an unknown sender's first counter, µs (0: off).
    skew_us: u64,
}

impl core::fmt::Debug for BroadcastChannel {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("BroadcastChannel")
            .field("robot", &self.robot)
            .field("dests", &self.dests)
            .finish_non_exhaustive()
    }
}

fn v4(s: &str, what: &str) -> Result<Ipv4Addr, NetError> {
    s.parse()
        .map_err(|e| NetError::Config(format!("{what} {s:?}: {e}")))
}

fn udp_socket(b: &BroadcastConfig) -> Result<Socket, NetError> {
    let group = v4(&b.group, "broadcast.group")?;
    let iface = v4(&b.interface, "broadcast.interface")?;
    let bind = v4(&b.bind, "broadcast.bind")?;
    let s = Socket::new(Domain::IPV4, Type::DGRAM, Some(Protocol::UDP))?;
    // Multicast: every process of a host that listens to the group shares its port, and each
    // gets every datagram. Unicast only: a shared port would give each datagram to one of the
    // sockets (two commanders started from one configuration each heard half the robots'
    // broadcasts, and reported robots that were running as lost): the second bind fails.
    if b.mode != BroadcastMode::Unicast {
        s.set_reuse_address(true)?;
        #[cfg(all(unix, not(any(target_os = "solaris", target_os = "illumos"))))]
        s.set_reuse_port(true)?;
    }
    let at = SocketAddrV4::new(bind, b.bind_port.unwrap_or(b.port));
    s.bind(&at.into())
        .map_err(super::bind_error("the broadcast channel", at))?;
    if b.mode != BroadcastMode::Unicast {
        if !group.is_multicast() {
            return Err(NetError::Config(format!(
                "broadcast.group {group} is not a multicast address"
            )));
        }
        s.join_multicast_v4(&group, &iface).map_err(|e| {
            // "No such device" alone named neither: the interface is an address of this host.
            NetError::Io(std::io::Error::new(
                e.kind(),
                format!(
                    "joining multicast group {group} on interface {iface}: {e} (the interface \
                     is one of this host's addresses, e.g. 127.0.0.1 or the LAN's)"
                ),
            ))
        })?;
        s.set_multicast_if_v4(&iface)?;
        s.set_multicast_ttl_v4(b.ttl)?;
        s.set_multicast_loop_v4(b.loopback)?;
    }
    s.set_nonblocking(true)?;
    Ok(s)
}

impl BroadcastChannel {
    /// Binds the channel for `robot` (the sender name of its messages) as `cfg.broadcast`
    /// says: UDP port shared through `SO_REUSEADDR`/`SO_REUSEPORT`, the multicast group
    /// joined on `interface` with `IP_MULTICAST_IF`, TTL and loop set, and the unicast
    /// peers as extra destinations. Sequence numbers and frame counters start from the
    /// UNIX time in µs. Must be called inside a tokio runtime.
    ///
    /// # Errors
    /// [`NetError::Config`] (bad addresses), [`NetError::Io`] (socket options, bind).
    pub fn bind(cfg: &PeerNetConfig, robot: &str, key: GroupKey) -> Result<Self, NetError> {
        Self::bind_with_clock(cfg, robot, key, TokioClock::shared())
    }

    /// [`BroadcastChannel::bind`] on the process's one clock (the receiver's replay window
    /// and authentication reports run on `clock`; [`BroadcastChannel::bind`] makes a
    /// [`TokioClock`] of its own).
    ///
    /// # Errors
    /// As [`BroadcastChannel::bind`].
    pub fn bind_with_clock(
        cfg: &PeerNetConfig,
        robot: &str,
        key: GroupKey,
        clock: SharedClock,
    ) -> Result<Self, NetError> {
        cfg.validate()?;
        let b = &cfg.broadcast;
        let sock = udp_socket(b)?;
        let socket = UdpSocket::from_std(sock.into())?;
        let mut dests = Vec::new();
        if b.mode != BroadcastMode::Unicast {
            dests.push(SocketAddr::V4(SocketAddrV4::new(
                v4(&b.group, "broadcast.group")?,
                b.port,
            )));
        }
        if b.mode != BroadcastMode::Multicast {
            for p in &b.peers {
                // IP literals only: `bind` is synchronous and must not block on DNS.
                dests.push(parse_ip_addr(p, "broadcast.peers")?);
            }
        }
        let start = unix_micros();
        let rcfg = ReceiverConfig {
            max_body: cfg.max_body,
            ..ReceiverConfig::default()
        };
        Ok(Self {
            socket: Arc::new(socket),
            inner: Arc::new(Mutex::new(Inner {
                tx: Broadcaster::new(robot, key.clone(), random_id(), start, start),
                rx: BroadcastReceiver::new(key, rcfg),
                sent: 0,
                send_errors: 0,
                own: 0,
                bad_mac_from: None,
                bad_mac_reported: 0,
                last_auth_report: None,
            })),
            dests: Arc::new(dests),
            robot: robot.to_owned(),
            receive_own: b.receive_own,
            clock,
            max_body: cfg.max_body,
            skew_us: cfg.max_clock_skew_ms.saturating_mul(1000),
        })
    }

    /// The bound local address (its port is the channel's port).
    ///
    /// # Errors
    /// [`NetError::Io`].
    pub fn local_addr(&self) -> Result<SocketAddr, NetError> {
        Ok(self.socket.local_addr()?)
    }

    /// Where sends go (multicast group and/or unicast peers).
    #[must_use]
    pub fn destinations(&self) -> &[SocketAddr] {
        &self.dests
    }

    fn first_window(&self) -> Option<(u64, u64)> {
        (self.skew_us > 0).then(|| {
            let now = unix_micros();
            (
                now.saturating_sub(self.skew_us),
                now.saturating_add(self.skew_us),
            )
        })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    async fn send_sealed(
        &self,
        seal: impl FnOnce(&mut Broadcaster, &mut [u8]) -> Result<usize, WireError>,
    ) -> Result<usize, NetError> {
        let mut buf = vec![0u8; HEADER_LEN + self.max_body + MAC_LEN];
        let n = {
            let mut g = self.lock();
            // Counters are UNIX µs: a receiver that never heard us checks them against
            // its clock.
            g.tx.advance_counter(unix_micros());
            seal(&mut g.tx, &mut buf)
                .map_err(|e| NetError::Config(format!("cannot encode broadcast: {e}")))?
        };
        let frame = buf.get(..n).unwrap_or_default();
        let (mut ok, mut bad) = (0u64, 0u64);
        let mut last_err = None;
        for d in self.dests.iter() {
            match self.socket.send_to(frame, d).await {
                Ok(_) => ok += 1,
                Err(e) => {
                    bad += 1;
                    last_err = Some(e);
                }
            }
        }
        {
            let mut g = self.lock();
            g.sent = g.sent.saturating_add(ok);
            g.send_errors = g.send_errors.saturating_add(bad);
        }
        match last_err {
            Some(e) if ok == 0 && !self.dests.is_empty() => Err(e.into()),
            _ => Ok(usize::try_from(ok).unwrap_or(usize::MAX)),
        }
    }

    /// Sends a status message; returns the number of destinations reached.
    ///
    /// # Errors
    /// [`NetError::Io`] when every destination failed; [`NetError::Config`] when a field
    /// is too long.
    pub async fn send_status(
        &self,
        behaviour: &str,
        san: &str,
        pose: Option<Pose>,
    ) -> Result<usize, NetError> {
        self.send_sealed(|b, out| b.status(behaviour, san, pose, out))
            .await
    }

    /// Sends an emergency (e.g. kind `scooter-lost`).
    ///
    /// # Errors
    /// As [`BroadcastChannel::send_status`].
    pub async fn send_emergency(&self, kind: &str, text: &str) -> Result<usize, NetError> {
        self.send_sealed(|b, out| b.emergency(kind, text, out))
            .await
    }

    /// Sends a mission event.
    ///
    /// # Errors
    /// As [`BroadcastChannel::send_status`].
    pub async fn send_mission(&self, event: MissionEvent, target: &str) -> Result<usize, NetError> {
        self.send_sealed(|b, out| b.mission(event, target, out))
            .await
    }

    /// Sends raw bytes to every destination (tests of the rejection paths).
    ///
    /// # Errors
    /// [`NetError::Io`].
    pub async fn send_raw(&self, bytes: &[u8]) -> Result<(), NetError> {
        for d in self.dests.iter() {
            self.socket.send_to(bytes, d).await?;
        }
        Ok(())
    }

    /// The next new broadcast and who sent it. Rejected datagrams (bad MAC, replay,
    /// malformed, duplicate, stale) are counted in [`BroadcastChannel::stats`] and skipped.
    ///
    /// # Errors
    /// [`NetError::Io`] when the socket fails.
    pub async fn recv(&self) -> Result<(Msg, SocketAddr), NetError> {
        let mut buf = vec![0u8; HEADER_LEN + self.max_body + MAC_LEN + 1];
        loop {
            let (n, from) = self.socket.recv_from(&mut buf).await?;
            let frame = buf.get(..n).unwrap_or_default();
            let now = self.clock.now();
            let mut g = self.lock();
            g.rx.set_first_counter_window(self.first_window());
            let bad_mac = g.rx.wire_rejects().bad_mac;
            let r = g.rx.handle_datagram(frame, now);
            if g.rx.wire_rejects().bad_mac != bad_mac {
                g.bad_mac_from = Some(from);
            }
            if let Ok(msg) = r {
                // Own messages (looped back by multicast) are recognised by this channel's
                // node ID: another process may use the same robot name.
                if !self.receive_own && g.rx.last_sender() == Some(g.tx.node()) {
                    g.own = g.own.saturating_add(1);
                    continue;
                }
                return Ok((msg, from));
            }
        }
    }

    /// Datagrams refused for a bad MAC since the last report, and the sender of the last
    /// one — for the operator: `Some` at the first refusal, then at most once per
    /// [`AUTH_REPORT_INTERVAL`] while more arrive (`None` otherwise). Call it now and then
    /// (e.g. once a second); refusals are counted by [`BroadcastChannel::recv`].
    #[must_use]
    pub fn take_auth_report(&self) -> Option<AuthFailure> {
        let now = self.clock.now();
        let mut g = self.lock();
        let total = g.rx.wire_rejects().bad_mac;
        let due = g
            .last_auth_report
            .is_none_or(|t| now.saturating_duration_since(t) >= AUTH_REPORT_INTERVAL);
        if total <= g.bad_mac_reported || !due {
            return None;
        }
        let from = g.bad_mac_from?;
        let frames = total - g.bad_mac_reported;
        g.bad_mac_reported = total;
        g.last_auth_report = Some(now);
        Some(AuthFailure { from, frames })
    }

    /// Counters.
    #[must_use]
    pub fn stats(&self) -> BroadcastStats {
        let g = self.lock();
        BroadcastStats {
            receiver: g.rx.stats(),
            wire: g.rx.wire_rejects(),
            sent: g.sent,
            send_errors: g.send_errors,
            own: g.own,
        }
    }
}
