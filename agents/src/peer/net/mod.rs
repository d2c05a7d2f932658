//! The tokio TCP/UDP shell of the Peer Agent (feature `net`).
//!
//! Thin shells around the sans-IO cores of [`super`]: one task per socket or session owns a
//! core state machine, feeds it frames and timeouts on [`ima_hal::time::TokioClock`] (so tests
//! can run in paused time) and writes what it transmits.
//!
//! * [`spawn_manager`] → [`ManagerHandle`]: the manager's request-channel TCP listener and its
//!   data server (TCP) that redeems tickets through the core; [`SourcePublisher`]s feed
//!   samples in without ever blocking.
//! * [`PeerClientHandle`]: a client session with `register`, `request` → [`Subscription`],
//!   `disconnect`, `unregister`.
//! * [`BroadcastChannel`]: UDP multicast (via `socket2`) and/or a unicast peer list.
//! * [`PeerNetConfig`]: the serde configuration (TOML), [`load_key_file`] the group key.
//!
//! Details, defaults and the key-file format are in the [module docs](super) of `peer`.
//!
//! ```no_run
//! use ima_agents::peer::manager::FixedSelfAgent;
//! use ima_agents::peer::net::{
//!     PeerClientHandle, PeerNetConfig, SubscriptionEvent, load_key_file, spawn_manager,
//! };
//! use ima_agents::peer::wire::SourceInfo;
//!
//! # async fn demo() -> Result<(), ima_agents::peer::net::NetError> {
//! let key = load_key_file("group.key".as_ref())?;
//! // Skeeter: a manager with one source.
//! let cfg = PeerNetConfig::loopback("skeeter");
//! let manager = spawn_manager(&cfg, key.clone(), FixedSelfAgent::default()).await?;
//! let ses = manager.publisher(SourceInfo::new("ses", "ses", 1, 0.2))?;
//! ses.publish(0, b"one full scan")?;
//! // Scooter: a client of Skeeter's manager.
//! let client =
//!     PeerClientHandle::connect(manager.local_addr(), &PeerNetConfig::loopback("scooter"), key)
//!         .await?;
//! client.register().await?;
//! let mut sub = client.request("ses", 1).await?;
//! while let Some(event) = sub.next().await {
//!     match event {
//!         SubscriptionEvent::Sample { payload, .. } => println!("{} bytes", payload.len()),
//!         SubscriptionEvent::Lost { reason } => println!("paused: {reason}"),
//!         SubscriptionEvent::Closed { reason } => println!("gone: {reason}"),
//!     }
//! }
//! # Ok(())
//! # }
//! ```

mod broadcast;
mod client;
mod config;
mod frames;
mod key;
mod manager;

pub use broadcast::{AUTH_REPORT_INTERVAL, BroadcastChannel, BroadcastStats};
pub use client::{EndReason, LossReason, PeerClientHandle, Subscription, SubscriptionEvent};
pub use config::{
    BroadcastConfig, BroadcastMode, MAX_QUEUE, ManagerNetConfig, PeerNetConfig, SyntheticSource,
    is_host_port, split_host_port,
};
pub use key::{
    INSECURE_KEY, KEY_FILE_MIN_LEN, insecure_key, load_key_file, make_key_command, parse_key,
};
pub use manager::{
    ManagerHandle, ManagerNetEvent, ManagerNetStats, SessionLink, SourcePublisher, spawn_manager,
    spawn_manager_with_clock,
};

use super::client::ClientError;
use super::wire::{DeclineReason, DenyReason, RevokeReason};

/// Errors of the network shell.
#[derive(Debug)]
pub enum NetError {
    /// A socket operation failed.
    Io(std::io::Error),
    /// The key file is missing, unreadable or too short.
    Key(String),
    /// The configuration is invalid (bad address, bad TOML…).
    Config(String),
    /// The registration was declined.
    Declined(DeclineReason),
    /// The request was denied.
    Denied(DenyReason),
    /// The client core refused the procedure.
    Client(ClientError),
    /// A request for a source this client already subscribes to (or is requesting).
    AlreadySubscribed,
    /// A pending request was revoked (e.g. its source was removed).
    Revoked(RevokeReason),
    /// The manager session is lost (no heartbeat for the loss window, a bad frame, or closed).
    ManagerLost,
    /// The task behind this handle has ended.
    Closed,
    /// The manager did not answer within `call_timeout_ms` (the procedure is withdrawn).
    Timeout,
    /// The session ended for want of authentication: most likely the two ends hold
    /// different group keys.
    Unauthenticated(AuthFailure),
    /// The other end does not speak the Peer Agent protocol: it sent bytes that are no Peer
    /// frame, or nothing at all until the session was declared lost.
    NotAPeer(NotAPeer),
}

/// A manager address whose other end never spoke the Peer Agent protocol. Its `Display` is
/// the sentence shown to the operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NotAPeer {
    /// The address connected to.
    pub from: std::net::SocketAddr,
    /// Bytes received from it (0: it stayed silent and kept the connection open).
    pub bytes: u64,
    /// The first bytes received (the first `head_len` of them are valid).
    pub head: [u8; 8],
    /// How many of `head` are valid.
    pub head_len: u8,
}

impl core::fmt::Display for NotAPeer {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let head = self
            .head
            .get(..usize::from(self.head_len))
            .unwrap_or_default();
        if let [m0, m1, version, ..] = head
            && [*m0, *m1] == crate::peer::wire::MAGIC
            && *version != crate::peer::wire::VERSION
        {
            return write!(
                f,
                "{} speaks version {version} of the Peer Agent protocol; this program speaks \
                 version {} — are both ends the same release of ima?",
                self.from,
                crate::peer::wire::VERSION
            );
        }
        if self.bytes == 0 {
            write!(
                f,
                "{} accepted the connection but sent nothing, not even an answer to the \
                 registration",
                self.from
            )?;
        } else {
            write!(
                f,
                "{} sent {} byte(s) that are not Peer Agent frames (they begin",
                self.from, self.bytes
            )?;
            for b in head {
                write!(f, " {b:02x}")?;
            }
            let text: String = head
                .iter()
                .map(|&b| {
                    if b.is_ascii_graphic() {
                        char::from(b)
                    } else {
                        '.'
                    }
                })
                .collect();
            write!(f, ", {text:?})")?;
        }
        f.write_str(" — is a Peer Agent manager listening at that address?")
    }
}

/// Frames that failed authentication (their MAC does not verify under this process's group
/// key), or a peer that closed the session before sending one authenticated frame. Its
/// `Display` is the sentence shown to the operator.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AuthFailure {
    /// Where the frames came from (the manager, or a broadcast sender).
    pub from: std::net::SocketAddr,
    /// Frames refused for a bad MAC (0: the peer closed the session before sending any).
    pub frames: u64,
}

impl core::fmt::Display for AuthFailure {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self.frames {
            0 => write!(
                f,
                "{} closed the session before sending one authenticated frame (a Peer Agent \
                 closes a session whose frames fail authentication)",
                self.from
            )?,
            1 => write!(f, "1 frame from {} failed authentication", self.from)?,
            n => write!(f, "{n} frames from {} failed authentication", self.from)?,
        }
        f.write_str(" — is the key file the same on every robot?")
    }
}

impl core::fmt::Display for NetError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            NetError::Io(e) => write!(f, "I/O error: {e}"),
            NetError::Key(s) => write!(f, "group key: {s}"),
            NetError::Config(s) => write!(f, "configuration: {s}"),
            NetError::Declined(r) => write!(f, "registration declined: {r}"),
            NetError::Denied(r) => write!(f, "request denied: {r}"),
            NetError::Client(e) => write!(f, "client: {e}"),
            NetError::AlreadySubscribed => f.write_str("already subscribed to this source"),
            NetError::Revoked(r) => write!(f, "request revoked: {r}"),
            NetError::ManagerLost => f.write_str("manager lost"),
            NetError::Closed => f.write_str("the peer task has ended"),
            NetError::Timeout => f.write_str("the manager did not answer in time"),
            NetError::Unauthenticated(a) => write!(f, "manager lost: {a}"),
            NetError::NotAPeer(a) => write!(f, "manager lost: {a}"),
        }
    }
}

impl std::error::Error for NetError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            NetError::Io(e) => Some(e),
            _ => None,
        }
    }
}

impl From<std::io::Error> for NetError {
    fn from(e: std::io::Error) -> Self {
        NetError::Io(e)
    }
}

impl From<ClientError> for NetError {
    fn from(e: ClientError) -> Self {
        match e {
            ClientError::Lost => NetError::ManagerLost,
            other => NetError::Client(other),
        }
    }
}

/// The error of binding `what` (e.g. "the manager's data server") to `addr`: the I/O error
/// with the address named, so that "address already in use" says which one.
pub(crate) fn bind_error(
    what: &str,
    addr: impl core::fmt::Display,
) -> impl FnOnce(std::io::Error) -> NetError {
    let context = format!("binding {what} to {addr}");
    move |e| {
        // The usual cause on a robot: the same robot (or configuration) started twice.
        let hint = if e.kind() == std::io::ErrorKind::AddrInUse {
            " (another program listens there: is this robot already running? `ss -lntup` \
             names it)"
        } else {
            ""
        };
        NetError::Io(std::io::Error::new(
            e.kind(),
            format!("{context}: {e}{hint}"),
        ))
    }
}

/// A random `u64` from the operating system (sender IDs, client-ID seeds); falls back to a
/// hash of the time and the process ID if the OS source fails.
#[must_use]
pub fn random_u64() -> u64 {
    let mut b = [0u8; 8];
    if getrandom::fill(&mut b).is_ok() {
        return u64::from_le_bytes(b);
    }
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(unix_micros());
    h.write_u32(std::process::id());
    h.finish()
}

pub use crate::peer::client::MAX_ID;

/// A random ID of at most [`MAX_ID`] (sender IDs, shown in status and logs as JSON numbers).
#[must_use]
pub fn random_id() -> u64 {
    random_u64() & MAX_ID
}

/// 32 random bytes from the operating system (the manager's ticket key).
///
/// # Errors
/// [`NetError::Io`] when the OS random source fails.
pub fn random_key32() -> Result<[u8; 32], NetError> {
    let mut k = [0u8; 32];
    getrandom::fill(&mut k).map_err(|e| NetError::Io(std::io::Error::other(e.to_string())))?;
    Ok(k)
}

/// Microseconds since the UNIX epoch: the first frame counter and broadcast sequence number
/// of every sender, so a restarted process is never taken for a replayer.
#[must_use]
pub fn unix_micros() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX))
        .unwrap_or(1)
        .max(1)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A port in use (the robot started twice) names the address and says what to check;
    /// other bind errors only name the address.
    #[test]
    fn a_bind_error_names_the_address_and_a_port_in_use_says_why() {
        let in_use = std::io::Error::from(std::io::ErrorKind::AddrInUse);
        let e = bind_error("the manager's request channel", "127.0.0.1:7600")(in_use);
        let text = e.to_string();
        assert!(
            text.contains("binding the manager's request channel to 127.0.0.1:7600: "),
            "{text}"
        );
        assert!(
            text.ends_with(
                " (another program listens there: is this robot already running? `ss -lntup` \
                 names it)"
            ),
            "{text}"
        );
        let denied = std::io::Error::from(std::io::ErrorKind::PermissionDenied);
        let text = bind_error("the broadcast channel", "0.0.0.0:80")(denied).to_string();
        assert!(
            text.contains("binding the broadcast channel to 0.0.0.0:80"),
            "{text}"
        );
        assert!(!text.contains("already running"), "{text}");
    }
}
