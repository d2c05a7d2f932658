//! Rules of PEER.md as unit tests of the cores, in virtual time.

use std::time::Duration;

use ima_hal::Instant;

use super::broadcast::{BroadcastReceiver, Broadcaster, ReceiverConfig, Rejection};
use super::client::{
    ClientConfig, ClientError, ClientEvent, PeerClient, Registration, SourceState,
};
use super::manager::{
    CloseReason, FixedSelfAgent, ManagerConfig, ManagerEvent, Outcome, PeerManager,
    RECENT_DECISIONS, TicketError,
};
use super::wire::{
    BodyError, DeclineReason, DenyReason, GroupKey, HEADER_LEN, MAC_LEN, Msg, RejectCounts,
    RevokeReason, Signer, SourceInfo, Verifier, WireError,
};

const KEY: &[u8] = b"group key of the test fleet, 32b";
const ADDR: &str = "10.0.0.7:7401";

fn key() -> GroupKey {
    GroupKey::new(KEY).unwrap()
}

fn ms(t: u64) -> Instant {
    Instant::from_millis(t)
}

fn src(name: &str, kind: &str) -> SourceInfo {
    SourceInfo {
        name: name.into(),
        kind: kind.into(),
        schema: 1,
        rate_mhz: 10_000,
    }
}

fn sources() -> Vec<SourceInfo> {
    vec![
        src("ses", "ses"),
        src("sonar", "sonar"),
        src("heading", "heading"),
    ]
}

struct Net {
    m: PeerManager<FixedSelfAgent>,
    clients: Vec<PeerClient>,
    buf: Vec<u8>,
}

impl Net {
    fn new(task: u8, tweak: impl FnOnce(&mut ManagerConfig)) -> Self {
        let mut cfg = ManagerConfig::new("skeeter", 1, ADDR);
        cfg.robot_priorities = vec![("leader".into(), 9), ("scout".into(), 1)];
        tweak(&mut cfg);
        let m = PeerManager::new(
            cfg,
            key(),
            [7; 32],
            FixedSelfAgent::new(task, sources()),
            ms(0),
        );
        Self {
            m,
            clients: Vec::new(),
            buf: vec![0; 70_000],
        }
    }

    /// Adds a client (peer id = index) with this robot and ID seed.
    fn add(&mut self, robot: &str, seed: u64, now: Instant) -> usize {
        let i = self.clients.len();
        let node = 100 + i as u64;
        self.clients.push(PeerClient::new(
            ClientConfig::new(robot, node, seed),
            key(),
            now,
        ));
        self.m.connect(i as u64, now);
        i
    }

    /// Moves frames both ways until nothing is left.
    fn pump(&mut self, now: Instant) {
        loop {
            let mut moved = false;
            for i in 0..self.clients.len() {
                while let Some(n) = self.clients[i].poll_transmit(&mut self.buf) {
                    let f = self.buf[..n].to_vec();
                    self.m.handle_frame(i as u64, &f, now);
                    moved = true;
                }
            }
            while let Some((p, n)) = self.m.poll_transmit(&mut self.buf) {
                let f = self.buf[..n].to_vec();
                if let Some(c) = self.clients.get_mut(p as usize) {
                    c.handle_frame(&f, now);
                }
                moved = true;
            }
            if !moved {
                break;
            }
        }
    }

    fn events(&mut self, i: usize) -> Vec<ClientEvent> {
        std::iter::from_fn(|| self.clients[i].poll_event()).collect()
    }

    fn mevents(&mut self) -> Vec<ManagerEvent> {
        std::iter::from_fn(|| self.m.poll_event()).collect()
    }

    fn register(&mut self, i: usize, now: Instant) {
        self.clients[i].register().unwrap();
        self.pump(now);
        assert_eq!(self.clients[i].registration(), Registration::Registered);
    }

    fn grants(&mut self) -> Vec<(u64, String)> {
        self.mevents()
            .into_iter()
            .filter_map(|e| match e {
                ManagerEvent::Decision(d) if d.outcome == Outcome::Granted => {
                    Some((d.client, d.source))
                }
                _ => None,
            })
            .collect()
    }
}

#[test]
fn registration_sends_the_competency_list() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    let ev = n.events(a);
    let mut expect = sources();
    expect.sort();
    assert_eq!(
        ev,
        vec![ClientEvent::Registered {
            client: n.clients[a].id(),
            sources: expect.clone()
        }]
    );
    assert_eq!(n.clients[a].sources(), &expect[..]);
}

#[test]
fn duplicate_id_is_declined_then_the_retry_is_accepted() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 42, ms(0));
    let b = n.add("scout", 42, ms(0)); // same seed: same first ID
    assert_eq!(n.clients[a].id(), n.clients[b].id());
    let dup = n.clients[a].id();
    n.register(a, ms(0));
    n.clients[b].register().unwrap();
    n.pump(ms(1));
    let ev = n.events(b);
    let new_id = n.clients[b].id();
    assert_ne!(new_id, dup);
    assert_eq!(
        ev[0],
        ClientEvent::Declined {
            client: dup,
            reason: DeclineReason::DuplicateId,
            retry_with: Some(new_id)
        }
    );
    assert!(matches!(ev[1], ClientEvent::Registered { client, .. } if client == new_id));
    assert_eq!(n.clients[b].registration(), Registration::Registered);
    assert!(n.mevents().iter().any(|e| matches!(
        e,
        ManagerEvent::Declined { reason: DeclineReason::DuplicateId, client, .. } if *client == dup
    )));
    assert_eq!(n.m.status().len(), 2);
}

#[test]
fn full_manager_declines_without_retry() {
    let mut n = Net::new(0, |c| c.max_clients = 1);
    let a = n.add("scout", 1, ms(0));
    let b = n.add("scout", 2, ms(0));
    n.register(a, ms(0));
    n.clients[b].register().unwrap();
    n.pump(ms(0));
    assert!(matches!(
        n.events(b)[..],
        [ClientEvent::Declined {
            reason: DeclineReason::Full,
            retry_with: None,
            ..
        }]
    ));
    assert_eq!(n.clients[b].registration(), Registration::Unregistered);
}

#[test]
fn procedures_return_typed_results() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    assert_eq!(
        n.clients[a].request("ses", 1),
        Err(ClientError::NotRegistered)
    );
    assert_eq!(n.clients[a].unregister(), Err(ClientError::NotRegistered));
    n.register(a, ms(0));
    assert_eq!(n.clients[a].register(), Err(ClientError::AlreadyRegistered));
    assert_eq!(
        n.clients[a].disconnect("ses"),
        Err(ClientError::NotRequested)
    );
}

#[test]
fn grant_carries_the_source_address_and_a_bound_ticket() {
    let mut n = Net::new(0, |c| c.ticket_lifetime = Duration::from_secs(2));
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.events(a);
    n.clients[a].request("sonar", 3).unwrap();
    n.pump(ms(10));
    let ev = n.events(a);
    let [
        ClientEvent::Granted {
            source,
            address,
            ticket,
        },
    ] = &ev[..]
    else {
        panic!("{ev:?}")
    };
    assert_eq!((source.as_str(), address.as_str()), ("sonar", ADDR));
    assert!(matches!(
        n.clients[a].requests().get("sonar"),
        Some(SourceState::Granted { .. })
    ));
    let id = n.clients[a].id();
    assert_eq!(n.m.check_ticket(id, "sonar", ticket, ms(500)), Ok(()));
    // Bound to client and source; unguessable; expires.
    assert_eq!(
        n.m.check_ticket(id ^ 1, "sonar", ticket, ms(500)),
        Err(TicketError::Forged)
    );
    assert_eq!(
        n.m.check_ticket(id, "ses", ticket, ms(500)),
        Err(TicketError::Forged)
    );
    let mut forged = *ticket;
    forged[20] ^= 1;
    assert_eq!(
        n.m.check_ticket(id, "sonar", &forged, ms(500)),
        Err(TicketError::Forged)
    );
    assert_eq!(
        n.m.check_ticket(id, "sonar", ticket, ms(2010)),
        Err(TicketError::Expired)
    );
    // Revoked by disconnect.
    n.clients[a].disconnect("sonar").unwrap();
    n.pump(ms(20));
    assert_eq!(
        n.m.check_ticket(id, "sonar", ticket, ms(30)),
        Err(TicketError::NotGranted)
    );
    assert_eq!(
        n.events(a),
        vec![ClientEvent::SourceGone {
            source: "sonar".into()
        }]
    );
}

#[test]
fn unknown_source_and_unregistered_client_are_denied() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.events(a);
    n.clients[a].request("lidar", 3).unwrap();
    n.pump(ms(1));
    assert_eq!(
        n.events(a),
        vec![ClientEvent::Denied {
            source: "lidar".into(),
            reason: DenyReason::UnknownSource
        }]
    );
    // A client ID registered on another session is not usable from this one.
    let b = n.add("scout", 2, ms(0));
    let mut s = Signer::new(key(), 555, 1);
    let f = s
        .seal_vec(&Msg::Request {
            client: n.clients[a].id(),
            source: "ses".into(),
            priority: 1,
        })
        .unwrap();
    n.m.handle_frame(b as u64, &f, ms(2));
    let (p, len) = n.m.poll_transmit(&mut n.buf).unwrap();
    assert_eq!(p, b as u64);
    let mut v = Verifier::new(key());
    assert!(matches!(
        v.open(&n.buf[..len]).unwrap().msg,
        Msg::Denied {
            reason: DenyReason::NotRegistered,
            ..
        }
    ));
}

#[test]
fn request_is_gated_while_task_priority_outranks_it_then_granted_when_it_drops() {
    let mut n = Net::new(5, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.events(a);
    n.clients[a].request("ses", 4).unwrap();
    n.pump(ms(1));
    assert_eq!(
        n.events(a),
        vec![ClientEvent::Pending {
            source: "ses".into()
        }]
    );
    assert_eq!(n.m.status()[0].requesting, vec!["ses".to_string()]);
    // The Self Agent saw the request with its priority.
    let d = n.m.agent().decisions.back().unwrap().clone();
    assert_eq!(
        (d.priority.robot, d.priority.request, d.task_priority),
        (1, 4, 5)
    );
    assert_eq!(d.outcome, Outcome::Pending);
    // Still gated at equal-minus-one; granted once task priority falls to 4.
    n.m.handle_timeout(ms(50));
    n.pump(ms(50));
    assert!(n.events(a).is_empty());
    n.m.agent_mut().task_priority = 4;
    n.m.handle_timeout(ms(60));
    n.pump(ms(60));
    assert!(matches!(&n.events(a)[..], [ClientEvent::Granted { source, .. }] if source == "ses"));
    assert_eq!(n.m.status()[0].granted, vec!["ses".to_string()]);
}

#[test]
fn renewal_with_higher_priority_is_reexamined() {
    let mut n = Net::new(5, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.clients[a].request("ses", 2).unwrap();
    n.pump(ms(1));
    n.events(a);
    n.clients[a].request("ses", 6).unwrap();
    n.pump(ms(2));
    assert!(matches!(&n.events(a)[..], [ClientEvent::Granted { .. }]));
}

#[test]
fn renewing_a_grant_gives_a_fresh_ticket_or_a_revoke_if_now_outranked() {
    let mut n = Net::new(3, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.events(a);
    n.clients[a].request("ses", 5).unwrap();
    n.pump(ms(1));
    let first = n.events(a);
    n.clients[a].request("ses", 4).unwrap();
    n.pump(ms(2));
    let second = n.events(a);
    let ticket = |ev: &[ClientEvent]| match ev {
        [ClientEvent::Granted { ticket, .. }] => *ticket,
        other => panic!("{other:?}"),
    };
    assert_ne!(ticket(&first), ticket(&second));
    n.clients[a].request("ses", 2).unwrap();
    n.pump(ms(3));
    assert_eq!(
        n.events(a),
        vec![
            ClientEvent::SourceGone {
                source: "ses".into()
            },
            ClientEvent::Revoked {
                source: "ses".into(),
                reason: RevokeReason::TaskPriority
            },
            ClientEvent::Pending {
                source: "ses".into()
            },
        ]
    );
}

#[test]
fn pending_requests_are_served_in_priority_order() {
    let mut n = Net::new(10, |_| {});
    let scout = n.add("scout", 1, ms(0)); // robot priority 1
    let leader = n.add("leader", 2, ms(0)); // 9
    let stranger = n.add("stranger", 3, ms(0)); // unknown: 0
    let scout2 = n.add("scout", 4, ms(0)); // 1
    for i in [scout, leader, stranger, scout2] {
        n.register(i, ms(0));
    }
    // Arrival order: stranger (0,9), scout2 (1,7) at t=1, scout (1,7) at t=2, leader (9,2).
    n.clients[stranger].request("ses", 9).unwrap();
    n.pump(ms(1));
    n.clients[scout2].request("ses", 7).unwrap();
    n.pump(ms(1));
    n.clients[scout].request("ses", 7).unwrap();
    n.pump(ms(2));
    n.clients[leader].request("ses", 2).unwrap();
    n.pump(ms(3));
    assert!(n.grants().is_empty());
    n.m.agent_mut().task_priority = 0;
    n.m.handle_timeout(ms(4));
    let ids = |n: &Net, i: usize| (n.clients[i].id(), "ses".to_string());
    // scout2 and ... at t=1 vs scout at t=2: earlier first; same instant -> lower client ID.
    let mut expect = vec![ids(&n, leader)];
    expect.push(ids(&n, scout2));
    expect.push(ids(&n, scout));
    expect.push(ids(&n, stranger));
    assert_eq!(n.grants(), expect);
}

#[test]
fn same_instant_ties_go_to_the_lower_client_id() {
    let mut n = Net::new(10, |_| {});
    let a = n.add("scout", 11, ms(0));
    let b = n.add("scout", 12, ms(0));
    n.register(a, ms(0));
    n.register(b, ms(0));
    n.clients[a].request("ses", 3).unwrap();
    n.clients[b].request("ses", 3).unwrap();
    n.pump(ms(5));
    n.mevents();
    n.m.agent_mut().task_priority = 0;
    n.m.handle_timeout(ms(6));
    let (ia, ib) = (n.clients[a].id(), n.clients[b].id());
    let got: Vec<u64> = n.grants().into_iter().map(|g| g.0).collect();
    assert_eq!(got, vec![ia.min(ib), ia.max(ib)]);
}

#[test]
fn capacity_limited_source_goes_to_the_best_pending_request_when_freed() {
    let mut n = Net::new(0, |c| c.max_grants_per_source = 1);
    let a = n.add("stranger", 1, ms(0));
    let b = n.add("scout", 2, ms(0));
    let c = n.add("leader", 3, ms(0));
    for i in [a, b, c] {
        n.register(i, ms(0));
    }
    n.clients[a].request("ses", 1).unwrap();
    n.pump(ms(1));
    n.clients[b].request("ses", 1).unwrap();
    n.clients[c].request("ses", 1).unwrap();
    n.pump(ms(2));
    assert_eq!(n.grants(), vec![(n.clients[a].id(), "ses".into())]);
    n.clients[a].disconnect("ses").unwrap();
    n.pump(ms(3));
    assert_eq!(n.grants(), vec![(n.clients[c].id(), "ses".into())]);
}

#[test]
fn rising_task_priority_revokes_and_falling_regrants() {
    let mut n = Net::new(2, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.clients[a].request("ses", 3).unwrap();
    n.pump(ms(1));
    n.events(a);
    n.m.agent_mut().task_priority = 7;
    n.m.handle_timeout(ms(10));
    n.pump(ms(10));
    assert_eq!(
        n.events(a),
        vec![
            ClientEvent::SourceGone {
                source: "ses".into()
            },
            ClientEvent::Revoked {
                source: "ses".into(),
                reason: RevokeReason::TaskPriority
            },
        ]
    );
    assert_eq!(
        n.clients[a].requests().get("ses"),
        Some(&SourceState::Requesting)
    );
    assert_eq!(n.m.status()[0].requesting, vec!["ses".to_string()]);
    n.m.agent_mut().task_priority = 3;
    n.m.handle_timeout(ms(20));
    n.pump(ms(20));
    assert!(matches!(&n.events(a)[..], [ClientEvent::Granted { .. }]));
}

#[test]
fn shutdown_revokes_every_grant() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.clients[a].request("ses", 3).unwrap();
    n.pump(ms(1));
    n.events(a);
    n.m.shutdown(ms(2));
    n.pump(ms(2));
    assert!(n.events(a).contains(&ClientEvent::Revoked {
        source: "ses".into(),
        reason: RevokeReason::Shutdown
    }));
}

#[test]
fn source_changes_are_pushed_and_removed_sources_revoked() {
    let mut n = Net::new(0, |c| c.rescan = Duration::from_millis(500));
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.clients[a].request("sonar", 3).unwrap();
    n.pump(ms(1));
    n.events(a);
    n.m.agent_mut().sources = vec![
        src("ses", "ses"),
        src("heading", "heading"),
        src("laser", "laser"),
    ];
    // Keep the session alive while time passes.
    for t in (100..=500).step_by(100) {
        n.clients[a].handle_timeout(ms(t));
        n.m.handle_timeout(ms(t));
        n.pump(ms(t));
    }
    let ev = n.events(a);
    assert!(ev.contains(&ClientEvent::Revoked {
        source: "sonar".into(),
        reason: RevokeReason::SourceGone
    }));
    assert!(ev.contains(&ClientEvent::SourcesChanged {
        added: vec![src("laser", "laser")],
        removed: vec!["sonar".into()]
    }));
    assert!(n.clients[a].sources().iter().any(|s| s.name == "laser"));
    assert!(!n.clients[a].sources().iter().any(|s| s.name == "sonar"));
    assert!(n.clients[a].requests().is_empty());
}

#[test]
fn silent_client_is_lost_within_three_heartbeats_and_its_grants_dropped() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.clients[a].request("ses", 3).unwrap();
    n.pump(ms(0));
    n.mevents();
    // The client goes silent after t=0. The manager keeps sending heartbeats.
    for t in (0..300).step_by(10) {
        n.m.handle_timeout(ms(t));
        while n.m.poll_transmit(&mut n.buf).is_some() {}
    }
    assert!(n.mevents().is_empty());
    assert_eq!(n.m.poll_timeout(), Some(ms(300)));
    n.m.handle_timeout(ms(300));
    let ev = n.mevents();
    assert!(ev.iter().any(|e| matches!(
        e,
        ManagerEvent::ClosePeer { reason: CloseReason::Lost, clients, .. } if clients.len() == 1
    )));
    assert!(n.m.status().is_empty());
    assert_eq!(n.m.stats().lost, 1);
}

#[test]
fn heartbeats_keep_both_ends_alive() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    for t in (0..5000).step_by(50) {
        n.clients[a].handle_timeout(ms(t));
        n.m.handle_timeout(ms(t));
        n.pump(ms(t));
    }
    assert_eq!(n.clients[a].registration(), Registration::Registered);
    assert_eq!(n.m.status().len(), 1);
}

/// Link health for the status pages: heartbeats counted both ways at both ends, last seen,
/// and each client's requests with their priorities and the latest decisions.
#[test]
fn link_health_counts_heartbeats_both_ways_and_status_shows_priorities_and_outcomes() {
    let mut n = Net::new(5, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.clients[a].request("ses", 4).unwrap();
    n.pump(ms(1));
    // 100 ms heartbeats for one second: about ten each way.
    for t in (0..=1000).step_by(50) {
        n.clients[a].handle_timeout(ms(t));
        n.m.handle_timeout(ms(t));
        n.pump(ms(t));
    }
    let links = n.m.links(ms(1030));
    assert_eq!(links.len(), 1);
    let l = links[0];
    assert_eq!(l.peer, a as u64);
    assert!((9..=12).contains(&l.heartbeats_received), "{l:?}");
    assert!((9..=12).contains(&l.heartbeats_sent), "{l:?}");
    assert!(
        l.frames_received > l.heartbeats_received,
        "register and request: {l:?}"
    );
    assert_eq!(l.silent_for, Duration::from_millis(30));
    assert_eq!(l.open_for, Duration::from_millis(1030));
    let c = n.clients[a].link_status(ms(1030));
    assert_eq!(c.registration, Registration::Registered);
    assert_eq!(c.heartbeats_received, l.heartbeats_sent);
    assert_eq!(c.heartbeats_sent, l.heartbeats_received);
    assert_eq!(c.requests, vec![("ses".to_owned(), false)]);
    assert_eq!(c.rejects, RejectCounts::default());
    // The manager's view: the pending request with its priority, and the decision.
    let st = &n.m.status()[0];
    assert_eq!(st.requests.len(), 1);
    assert_eq!(st.requests[0].source, "ses");
    assert_eq!(
        (
            st.requests[0].priority.robot,
            st.requests[0].priority.request
        ),
        (1, 4)
    );
    assert!(!st.requests[0].granted);
    assert_eq!(st.recent.last().unwrap().outcome, Outcome::Pending);
    // Granted once the task priority falls; the decisions stay bounded.
    n.m.agent_mut().task_priority = 0;
    n.m.handle_timeout(ms(1040));
    n.pump(ms(1040));
    let st = &n.m.status()[0];
    assert!(st.requests[0].granted);
    assert_eq!(st.recent.last().unwrap().outcome, Outcome::Granted);
    assert!(n.clients[a].link_status(ms(1040)).requests[0].1);
    for i in 0..20 {
        n.clients[a].request("ses", 4).unwrap();
        n.pump(ms(1050 + i));
    }
    assert_eq!(n.m.status()[0].recent.len(), RECENT_DECISIONS);
}

#[test]
fn silent_manager_is_lost_within_three_heartbeats_and_sources_reported_gone() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.clients[a].request("ses", 3).unwrap();
    n.clients[a].request("sonar", 3).unwrap();
    n.pump(ms(0));
    n.events(a);
    for t in (0..300).step_by(10) {
        n.clients[a].handle_timeout(ms(t));
        while n.clients[a].poll_transmit(&mut n.buf).is_some() {}
    }
    assert!(n.events(a).is_empty());
    n.clients[a].handle_timeout(ms(300));
    assert_eq!(
        n.events(a),
        vec![
            ClientEvent::SourceGone {
                source: "ses".into()
            },
            ClientEvent::SourceGone {
                source: "sonar".into()
            },
            ClientEvent::ManagerLost(None),
        ]
    );
    assert_eq!(n.clients[a].registration(), Registration::Lost);
    assert_eq!(n.clients[a].request("ses", 1), Err(ClientError::Lost));
}

#[test]
fn bad_frames_close_only_their_session() {
    let mut n = Net::new(0, |_| {});
    let good = n.add("scout", 1, ms(0));
    n.register(good, ms(0));
    type Check = fn(&WireError) -> bool;
    let bad_peers: Vec<(Vec<u8>, Check)> = vec![
        (b"GET / HTTP/1.0\r\n\r\nxxxxxxxxxxxx".to_vec(), |e| {
            matches!(e, WireError::BadMagic(_))
        }),
        (
            Signer::new(GroupKey::new(b"a stranger's key, 16+").unwrap(), 9, 1)
                .seal_vec(&Msg::Register {
                    client: 5,
                    robot: "x".into(),
                })
                .unwrap(),
            |e| *e == WireError::BadMac,
        ),
        (
            Signer::new(key(), 9, 1).seal_vec(&Msg::Heartbeat).unwrap()[..10].to_vec(),
            |e| matches!(e, WireError::Truncated { .. }),
        ),
        (
            Signer::new(key(), 9, 1)
                .seal_vec(&Msg::Granted {
                    client: 1,
                    source: "ses".into(),
                    address: "x".into(),
                    ticket: [0; 32],
                })
                .unwrap(),
            |_| false,
        ),
    ];
    for (frame, check) in bad_peers {
        let p = n.add("stranger", 77, ms(1));
        n.m.handle_frame(p as u64, &frame, ms(1));
        let ev = n.mevents();
        let closed = ev.iter().find_map(|e| match e {
            ManagerEvent::ClosePeer { peer, reason, .. } if *peer == p as u64 => Some(*reason),
            _ => None,
        });
        match closed {
            Some(CloseReason::Wire(e)) => assert!(check(&e), "{e:?}"),
            Some(CloseReason::Unexpected(0x13)) => {}
            other => panic!("{other:?}"),
        }
    }
    // The good client is still served.
    n.clients[good].request("ses", 1).unwrap();
    n.pump(ms(2));
    assert!(
        n.events(good)
            .iter()
            .any(|e| matches!(e, ClientEvent::Granted { .. }))
    );
    assert_eq!(n.m.stats().closed_bad, 4);
    assert_eq!(n.m.stats().rejects.bad_mac, 1);
}

#[test]
fn replayed_frame_is_rejected_and_closes_the_session() {
    let mut n = Net::new(0, |_| {});
    let p = n.add("scout", 1, ms(0));
    let mut s = Signer::new(key(), 9, 1);
    let f = s
        .seal_vec(&Msg::Register {
            client: 5,
            robot: "scout".into(),
        })
        .unwrap();
    n.m.handle_frame(p as u64, &f, ms(0));
    n.m.handle_frame(p as u64, &f, ms(1));
    assert!(n.mevents().iter().any(|e| matches!(
        e,
        ManagerEvent::ClosePeer {
            reason: CloseReason::Wire(WireError::Replay {
                last: 1,
                got: 1,
                ..
            }),
            ..
        }
    )));
    assert_eq!(n.m.stats().rejects.replay, 1);
    assert!(n.m.status().is_empty());
}

#[test]
fn frames_recorded_on_one_session_cannot_be_replayed_on_another() {
    let mut n = Net::new(0, |_| {});
    let p1 = n.add("scout", 1, ms(0));
    let mut s = Signer::new(key(), 9, 1);
    let reg = s
        .seal_vec(&Msg::Register {
            client: 5,
            robot: "scout".into(),
        })
        .unwrap();
    let unreg = s.seal_vec(&Msg::Unregister { client: 5 }).unwrap();
    n.m.handle_frame(p1 as u64, &reg, ms(0));
    n.m.handle_frame(p1 as u64, &unreg, ms(1));
    assert!(n.m.status().is_empty());
    let p2 = n.add("stranger", 2, ms(2));
    n.m.handle_frame(p2 as u64, &reg, ms(2));
    assert!(n.m.status().is_empty(), "replayed registration accepted");
    assert!(n.mevents().iter().any(|e| matches!(
        e,
        ManagerEvent::ClosePeer {
            reason: CloseReason::Wire(WireError::Replay { .. }),
            ..
        }
    )));
}

#[test]
fn client_closes_on_a_tampered_frame() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.clients[a].register().unwrap();
    let len = n.clients[a].poll_transmit(&mut n.buf).unwrap();
    let f = n.buf[..len].to_vec();
    n.m.handle_frame(0, &f, ms(0));
    let (_, len) = n.m.poll_transmit(&mut n.buf).unwrap();
    let mut f = n.buf[..len].to_vec();
    f[HEADER_LEN] ^= 0x01;
    n.clients[a].handle_frame(&f, ms(0));
    assert_eq!(
        n.events(a),
        vec![ClientEvent::ManagerLost(Some(WireError::BadMac))]
    );
    assert_eq!(n.clients[a].rejects().bad_mac, 1);
}

#[test]
fn unregister_drops_requests_and_grants() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    n.register(a, ms(0));
    n.clients[a].request("ses", 1).unwrap();
    n.pump(ms(1));
    n.events(a);
    n.clients[a].unregister().unwrap();
    n.pump(ms(2));
    assert_eq!(
        n.events(a),
        vec![
            ClientEvent::SourceGone {
                source: "ses".into()
            },
            ClientEvent::Unregistered
        ]
    );
    assert!(n.m.status().is_empty());
    assert_eq!(n.clients[a].registration(), Registration::Unregistered);
}

#[test]
fn outbox_is_bounded_and_a_slow_session_is_closed() {
    let mut n = Net::new(0, |c| c.max_outbox = 4);
    let p = n.add("scout", 1, ms(0));
    let mut s = Signer::new(key(), 9, 1);
    for c in 0..10 {
        let f = s
            .seal_vec(&Msg::Register {
                client: 1,
                robot: "x".into(),
            })
            .unwrap();
        let _ = c;
        n.m.handle_frame(p as u64, &f, ms(0));
    }
    n.m.handle_timeout(ms(0));
    assert!(n.mevents().iter().any(|e| matches!(
        e,
        ManagerEvent::ClosePeer {
            reason: CloseReason::SlowConsumer,
            ..
        }
    )));
    assert_eq!(n.m.session_count(), 0);
}

// ---- broadcast ----

fn status(robot: &str, seq: u64) -> Msg {
    Msg::Status {
        robot: robot.into(),
        seq,
        behaviour: "scan".into(),
        san: "ok".into(),
        pose: None,
    }
}

#[test]
fn broadcast_drops_duplicates_and_stale_reorderings() {
    let mut rx = BroadcastReceiver::new(key(), ReceiverConfig::default());
    let mut s = Signer::new(key(), 3, 1);
    let mut feed = |m: Msg, t: u64| rx.handle_datagram(&s.seal_vec(&m).unwrap(), ms(t));
    assert_eq!(feed(status("skeeter", 5), 0), Ok(status("skeeter", 5)));
    assert_eq!(
        feed(status("skeeter", 5), 1),
        Err(Rejection::Duplicate { seq: 5 })
    );
    assert_eq!(
        feed(status("skeeter", 3), 2),
        Err(Rejection::Stale { last: 5, seq: 3 })
    );
    assert!(feed(status("skeeter", 6), 3).is_ok());
    assert!(
        feed(status("scooter", 1), 3).is_ok(),
        "sequences are per robot"
    );
    // A sender silent for the forget time is accepted again from any sequence (restart).
    assert!(feed(status("skeeter", 1), 10_004).is_ok());
    assert_eq!(
        feed(Msg::Heartbeat, 10_005),
        Err(Rejection::NotBroadcast(0x05))
    );
    let st = rx.stats();
    assert_eq!(
        (st.accepted, st.duplicate, st.stale, st.not_broadcast),
        (4, 1, 1, 1)
    );
}

/// Two processes of one name (the operator's commander and a one-shot `ima commander stop`)
/// each have their own sequence: the later one's higher numbers do not make the other's
/// messages stale. Keyed by name alone, a fleet stop typed in the running commander was
/// dropped for 10 s after any one-shot command.
#[test]
fn two_senders_of_one_name_have_their_own_sequences() {
    let mut rx = BroadcastReceiver::new(key(), ReceiverConfig::default());
    let mut running = Signer::new(key(), 3, 1);
    let mut one_shot = Signer::new(key(), 4, 1);
    let stop = |seq| Msg::Emergency {
        robot: "commander".into(),
        seq,
        kind: "fleet-stop".into(),
        text: "operator".into(),
    };
    let mut feed =
        |s: &mut Signer, m: Msg, t: u64| rx.handle_datagram(&s.seal_vec(&m).unwrap(), ms(t));
    assert!(feed(&mut running, stop(100), 0).is_ok());
    assert!(feed(&mut one_shot, stop(900), 1).is_ok());
    assert_eq!(feed(&mut running, stop(101), 2), Ok(stop(101)));
    // Each sender's own duplicates and reorderings are still caught.
    assert_eq!(
        feed(&mut running, stop(101), 3),
        Err(Rejection::Duplicate { seq: 101 })
    );
    assert_eq!(
        feed(&mut one_shot, stop(800), 4),
        Err(Rejection::Stale {
            last: 900,
            seq: 800
        })
    );
}

#[test]
fn broadcast_rejects_strangers_and_replays() {
    let mut rx = BroadcastReceiver::new(key(), ReceiverConfig::default());
    let mut b = Broadcaster::new("skeeter", key(), 3, 1, 1);
    let mut buf = [0u8; 512];
    let n = b
        .emergency("scooter-lost", "Scooter lost", &mut buf)
        .unwrap();
    let f = buf[..n].to_vec();
    assert!(matches!(
        rx.handle_datagram(&f, ms(0)),
        Ok(Msg::Emergency { seq: 1, .. })
    ));
    // An exact copy of the frame last accepted (mode `both` sends two): a duplicate.
    assert_eq!(
        rx.handle_datagram(&f, ms(1)),
        Err(Rejection::Duplicate { seq: 1 })
    );
    assert_eq!(rx.wire_rejects().replay, 0);
    let mut stranger = Broadcaster::new(
        "skeeter",
        GroupKey::new(b"not the group key!").unwrap(),
        4,
        1,
        99,
    );
    let n = stranger.status("evil", "", None, &mut buf).unwrap();
    assert_eq!(
        rx.handle_datagram(&buf[..n], ms(2)),
        Err(Rejection::Wire(WireError::BadMac))
    );
    let n = b
        .mission(super::wire::MissionEvent::Accomplished, "red", &mut buf)
        .unwrap();
    assert!(matches!(
        rx.handle_datagram(&buf[..n], ms(3)),
        Ok(Msg::Mission { seq: 2, .. })
    ));
    // The older frame played again: a replay.
    assert!(matches!(
        rx.handle_datagram(&f, ms(4)),
        Err(Rejection::Wire(WireError::Replay { .. }))
    ));
    assert_eq!(rx.wire_rejects().bad_mac, 1);
    assert_eq!(rx.wire_rejects().replay, 1);
    assert_eq!(rx.stats().duplicate, 1);
}

// ---- wire ----

/// Test vector of the module docs, computed independently (Python `hmac` + `hashlib`).
const REGISTER_VECTOR: &str = "4950010110001100000000000000220000000000000008070605040302010773\
636f6f746572387d606008114cd4afe45a93e9a8881a69a48d8494d2c6d830f9e040a719ef94";

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
        .collect()
}

#[test]
fn register_test_vector_both_ways() {
    let want = unhex(REGISTER_VECTOR);
    let msg = Msg::Register {
        client: 0x0102_0304_0506_0708,
        robot: "scooter".into(),
    };
    let got = Signer::new(key(), 0x11, 0x22).seal_vec(&msg).unwrap();
    assert_eq!(got, want);
    let o = Verifier::new(key()).open(&want).unwrap();
    assert_eq!((o.sender, o.counter, o.msg), (0x11, 0x22, msg));
}

#[test]
fn each_wire_error_is_distinct() {
    let mut s = Signer::new(key(), 1, 10);
    let f = s.seal_vec(&status("skeeter", 1)).unwrap();
    let v = || Verifier::new(key());
    assert!(v().open(&f).is_ok());
    assert!(matches!(
        v().open(&f[..5]),
        Err(WireError::Truncated {
            need: HEADER_LEN,
            got: 5
        })
    ));
    assert!(matches!(
        v().open(&f[..f.len() - 1]),
        Err(WireError::Truncated { .. })
    ));
    let mut long = f.clone();
    long.push(0);
    assert_eq!(v().open(&long), Err(WireError::TrailingBytes(1)));
    let mut bad = f.clone();
    bad[0] = b'X';
    assert_eq!(v().open(&bad), Err(WireError::BadMagic([b'X', b'P'])));
    let mut bad = f.clone();
    bad[2] = 2;
    assert_eq!(v().open(&bad), Err(WireError::BadVersion(2)));
    let mut bad = f.clone();
    bad[4..6].copy_from_slice(&9000u16.to_le_bytes());
    assert_eq!(
        v().open(&bad),
        Err(WireError::Oversize {
            len: 9000,
            max: 8192
        })
    );
    let mut bad = f.clone();
    let last = bad.len() - 1;
    bad[last] ^= 0x80;
    assert_eq!(v().open(&bad), Err(WireError::BadMac));
    let mut vv = v();
    vv.open(&f).unwrap();
    assert_eq!(
        vv.open(&f),
        Err(WireError::Replay {
            sender: 1,
            last: 10,
            got: 10
        })
    );
    // Unknown type and bad body, correctly signed: the MAC passes, then the body fails.
    let mut raw = f.clone();
    raw[3] = 0x7f;
    resign(&mut raw);
    assert_eq!(v().open(&raw), Err(WireError::UnknownType(0x7f)));
    let mut raw = f.clone();
    raw[HEADER_LEN] = 200; // robot-name length beyond the body
    resign(&mut raw);
    assert!(matches!(v().open(&raw), Err(WireError::Body(_))));
    let mut big = Signer::new(key(), 1, 1);
    let payload = vec![0u8; 9000];
    let f = big
        .seal_vec(&Msg::Sample {
            seq: 1,
            stamp_us: 2,
            payload,
        })
        .unwrap();
    assert!(matches!(v().open(&f), Err(WireError::Oversize { .. })));
    assert_eq!(super::wire::frame_len(&f[..3], 8192), Ok(None));
    let ok = Signer::new(key(), 1, 1).seal_vec(&Msg::Heartbeat).unwrap();
    assert_eq!(
        super::wire::frame_len(&ok, 8192),
        Ok(Some(HEADER_LEN + MAC_LEN))
    );
}

fn resign(frame: &mut [u8]) {
    use hmac::{Hmac, Mac};
    let split = frame.len() - MAC_LEN;
    let mut m = Hmac::<sha2::Sha256>::new_from_slice(KEY).unwrap();
    m.update(&frame[..split]);
    let tag = m.finalize().into_bytes();
    frame[split..].copy_from_slice(&tag);
}

#[test]
fn counters_must_increase_per_sender_only() {
    let mut v = Verifier::new(key());
    let mut a = Signer::new(key(), 1, 100);
    let mut b = Signer::new(key(), 2, 1);
    assert!(v.open(&a.seal_vec(&Msg::Heartbeat).unwrap()).is_ok());
    assert!(v.open(&b.seal_vec(&Msg::Heartbeat).unwrap()).is_ok());
    let mut a_old = Signer::new(key(), 1, 50);
    assert!(matches!(
        v.open(&a_old.seal_vec(&Msg::Heartbeat).unwrap()),
        Err(WireError::Replay {
            last: 100,
            got: 50,
            ..
        })
    ));
    assert_eq!(v.rejects.replay, 1);
}

mod props {
    use super::super::wire::{
        DeclineReason, DenyReason, MissionEvent, Msg, Pose, RevokeReason, Signer, SourceInfo,
        Verifier, WireError,
    };
    use super::key;
    use proptest::prelude::*;

    fn s() -> impl Strategy<Value = String> {
        "[a-z\u{e9}\u{3b8} -]{0,20}"
    }
    fn source() -> impl Strategy<Value = SourceInfo> {
        (s(), s(), any::<u16>(), any::<u32>()).prop_map(|(name, kind, schema, rate_mhz)| {
            SourceInfo {
                name,
                kind,
                schema,
                rate_mhz,
            }
        })
    }
    fn revoke() -> impl Strategy<Value = RevokeReason> {
        prop_oneof![
            Just(RevokeReason::TaskPriority),
            Just(RevokeReason::SourceGone),
            Just(RevokeReason::Shutdown),
            Just(RevokeReason::BadTicket)
        ]
    }

    pub(super) fn msg() -> impl Strategy<Value = Msg> {
        let t = any::<[u8; 32]>();
        prop_oneof![
            (any::<u64>(), s()).prop_map(|(client, robot)| Msg::Register { client, robot }),
            any::<u64>().prop_map(|client| Msg::Unregister { client }),
            (any::<u64>(), s(), any::<u8>()).prop_map(|(client, source, priority)| Msg::Request {
                client,
                source,
                priority
            }),
            (any::<u64>(), s()).prop_map(|(client, source)| Msg::Disconnect { client, source }),
            Just(Msg::Heartbeat),
            (any::<u64>(), prop::collection::vec(source(), 0..6))
                .prop_map(|(client, sources)| Msg::Registered { client, sources }),
            (
                any::<u64>(),
                prop_oneof![Just(DeclineReason::DuplicateId), Just(DeclineReason::Full)]
            )
                .prop_map(|(client, reason)| Msg::Declined { client, reason }),
            any::<u64>().prop_map(|client| Msg::Unregistered { client }),
            (any::<u64>(), s(), s(), t).prop_map(|(client, source, address, ticket)| {
                Msg::Granted {
                    client,
                    source,
                    address,
                    ticket,
                }
            }),
            (any::<u64>(), s()).prop_map(|(client, source)| Msg::Pending { client, source }),
            (
                any::<u64>(),
                s(),
                prop_oneof![
                    Just(DenyReason::NotRegistered),
                    Just(DenyReason::UnknownSource),
                    Just(DenyReason::QueueFull)
                ]
            )
                .prop_map(|(client, source, reason)| Msg::Denied {
                    client,
                    source,
                    reason
                }),
            (any::<u64>(), s(), revoke()).prop_map(|(client, source, reason)| Msg::Revoked {
                client,
                source,
                reason
            }),
            (
                prop::collection::vec(source(), 0..4),
                prop::collection::vec(s(), 0..4)
            )
                .prop_map(|(added, removed)| Msg::SourcesChanged { added, removed }),
            (any::<u64>(), s(), t).prop_map(|(client, source, ticket)| Msg::OpenData {
                client,
                source,
                ticket
            }),
            s().prop_map(|source| Msg::DataAccepted { source }),
            (s(), revoke()).prop_map(|(source, reason)| Msg::DataClosed { source, reason }),
            (
                any::<u64>(),
                any::<u64>(),
                prop::collection::vec(any::<u8>(), 0..1100)
            )
                .prop_map(|(seq, stamp_us, payload)| Msg::Sample {
                    seq,
                    stamp_us,
                    payload
                }),
            (
                s(),
                any::<u64>(),
                s(),
                s(),
                proptest::option::of((any::<i32>(), any::<i32>(), any::<i32>()))
            )
                .prop_map(|(robot, seq, behaviour, san, p)| Msg::Status {
                    robot,
                    seq,
                    behaviour,
                    san,
                    pose: p.map(|(x_mm, y_mm, theta_mrad)| Pose {
                        x_mm,
                        y_mm,
                        theta_mrad
                    }),
                }),
            (s(), any::<u64>(), s(), s()).prop_map(|(robot, seq, kind, text)| Msg::Emergency {
                robot,
                seq,
                kind,
                text
            }),
            (
                s(),
                any::<u64>(),
                prop_oneof![
                    Just(MissionEvent::Accepted),
                    Just(MissionEvent::Accomplished),
                    Just(MissionEvent::Failed)
                ],
                s()
            )
                .prop_map(|(robot, seq, event, target)| Msg::Mission {
                    robot,
                    seq,
                    event,
                    target
                }),
        ]
    }

    proptest! {
        #[test]
        fn every_message_round_trips(m in msg(), sender in any::<u64>(), ctr in 0u64..u64::MAX) {
            let mut sg = Signer::new(key(), sender, ctr);
            let f = sg.seal_vec(&m).unwrap();
            let o = Verifier::new(key()).open(&f).unwrap();
            prop_assert_eq!((o.sender, o.counter), (sender, ctr));
            prop_assert_eq!(o.msg, m);
        }

        #[test]
        fn any_flipped_bit_is_detected(m in msg(), bit in any::<prop::sample::Index>()) {
            let f = Signer::new(key(), 1, 1).seal_vec(&m).unwrap();
            let mut t = f.clone();
            let i = bit.index(f.len() * 8);
            t[i / 8] ^= 1 << (i % 8);
            prop_assert!(Verifier::new(key()).open(&t).is_err());
        }

        #[test]
        fn every_truncation_is_truncated(m in msg(), cut in any::<prop::sample::Index>()) {
            let f = Signer::new(key(), 1, 1).seal_vec(&m).unwrap();
            let n = cut.index(f.len());
            let e = Verifier::new(key()).open(&f[..n]).unwrap_err();
            prop_assert!(matches!(e, WireError::Truncated { .. }), "{:?}", e);
        }

        #[test]
        fn arbitrary_bytes_never_panic(b in prop::collection::vec(any::<u8>(), 0..200)) {
            let _ = Verifier::new(key()).open(&b);
            let _ = super::super::wire::parse_unauthenticated(&b, 8192);
            for code in [0x01u8, 0x10, 0x13, 0x17, 0x23, 0x30, 0x32] {
                let _ = Msg::parse_body(code, &b);
            }
        }
    }
}

// ---- data sessions ----

mod data_sessions {
    use super::*;
    use crate::peer::data::{
        DataClientSession, DataClose, DataConfig, DataEvent, DataServerSession,
    };

    fn granted() -> (Net, u64, [u8; 32]) {
        let mut n = Net::new(0, |_| {});
        let a = n.add("scout", 1, ms(0));
        n.register(a, ms(0));
        n.events(a);
        n.clients[a].request("sonar", 3).unwrap();
        n.pump(ms(1));
        let ev = n.events(a);
        let [ClientEvent::Granted { ticket, .. }] = &ev[..] else {
            panic!("{ev:?}")
        };
        let id = n.clients[a].id();
        (n, id, *ticket)
    }

    fn cfg(node: u64, queue: usize) -> DataConfig {
        let mut c = DataConfig::new(node);
        c.queue = queue;
        c
    }

    /// Moves frames between the two ends until quiet.
    fn pump(s: &mut DataServerSession, c: &mut DataClientSession, m: &mut Net, now: Instant) {
        let mut buf = vec![0u8; 70_000];
        loop {
            let mut moved = false;
            while let Some(k) = c.poll_transmit(&mut buf, now) {
                s.handle_frame(&buf[..k], &mut m.m, now);
                moved = true;
            }
            while let Some(k) = s.poll_transmit(&mut buf, now) {
                c.handle_frame(&buf[..k], now);
                moved = true;
            }
            if !moved {
                break;
            }
        }
    }

    #[test]
    fn valid_ticket_opens_and_samples_flow_in_order() {
        let (mut n, id, ticket) = granted();
        let mut s = DataServerSession::new(cfg(50, 8), key(), ms(2));
        let mut c = DataClientSession::new(cfg(51, 8), key(), id, "sonar", ticket, ms(2));
        pump(&mut s, &mut c, &mut n, ms(2));
        assert!(s.is_streaming() && c.is_open());
        assert_eq!(
            s.poll_event(),
            Some(DataEvent::Opened {
                client: id,
                source: "sonar".into()
            })
        );
        assert_eq!(
            c.poll_event(),
            Some(DataEvent::Opened {
                client: id,
                source: "sonar".into()
            })
        );
        for i in 0..3u8 {
            s.offer(u64::from(i), &[i; 4]);
        }
        pump(&mut s, &mut c, &mut n, ms(3));
        let got: Vec<u64> = std::iter::from_fn(|| c.pop_sample())
            .map(|x| x.seq)
            .collect();
        assert_eq!(got, vec![1, 2, 3]);
        assert_eq!(c.lost_samples(), 0);
    }

    #[test]
    fn data_server_refuses_a_session_without_a_valid_ticket() {
        let (mut n, id, ticket) = granted();
        let mut forged = ticket;
        forged[31] ^= 1;
        for (client, source, t, want) in [
            (id, "sonar", forged, TicketError::Forged),
            (id ^ 1, "sonar", ticket, TicketError::Forged),
            (id, "ses", ticket, TicketError::Forged),
        ] {
            let mut s = DataServerSession::new(cfg(50, 8), key(), ms(2));
            let mut c = DataClientSession::new(cfg(51, 8), key(), client, source, t, ms(2));
            s.offer(1, b"secret");
            pump(&mut s, &mut c, &mut n, ms(2));
            assert_eq!(
                s.poll_event(),
                Some(DataEvent::Closed(DataClose::Ticket(want)))
            );
            assert_eq!(
                c.poll_event(),
                Some(DataEvent::Closed(DataClose::Revoked(
                    RevokeReason::BadTicket
                )))
            );
            assert_eq!(c.pop_sample(), None);
        }
        // A first frame that is not OpenData closes the session too.
        let mut s = DataServerSession::new(cfg(50, 8), key(), ms(2));
        let f = Signer::new(key(), 9, 1).seal_vec(&Msg::Heartbeat).unwrap();
        s.handle_frame(&f, &mut n.m, ms(2));
        assert_eq!(
            s.poll_event(),
            Some(DataEvent::Closed(DataClose::Unexpected(0x05)))
        );
    }

    #[test]
    fn a_ticket_opens_one_session_only_and_renewal_issues_a_fresh_one() {
        let (mut n, id, ticket) = granted();
        let mut s = DataServerSession::new(cfg(50, 8), key(), ms(2));
        let mut c = DataClientSession::new(cfg(51, 8), key(), id, "sonar", ticket, ms(2));
        pump(&mut s, &mut c, &mut n, ms(2));
        assert!(s.is_streaming());
        // A second session with the same ticket (say, a recorded OpenData replayed on a new
        // connection) is refused.
        let mut s2 = DataServerSession::new(cfg(50, 8), key(), ms(3));
        let mut c2 = DataClientSession::new(cfg(52, 8), key(), id, "sonar", ticket, ms(3));
        pump(&mut s2, &mut c2, &mut n, ms(3));
        assert_eq!(
            s2.poll_event(),
            Some(DataEvent::Closed(DataClose::Ticket(
                TicketError::AlreadyUsed
            )))
        );
        // Renewing the request gives a fresh ticket that works.
        n.clients[0].request("sonar", 3).unwrap();
        n.pump(ms(4));
        let ev = n.events(0);
        let [ClientEvent::Granted { ticket: fresh, .. }] = &ev[..] else {
            panic!("{ev:?}")
        };
        assert_ne!(*fresh, ticket);
        let mut s3 = DataServerSession::new(cfg(50, 8), key(), ms(5));
        let mut c3 = DataClientSession::new(cfg(53, 8), key(), id, "sonar", *fresh, ms(5));
        pump(&mut s3, &mut c3, &mut n, ms(5));
        assert!(s3.is_streaming() && c3.is_open());
    }

    #[test]
    fn slow_consumer_loses_the_oldest_samples_and_never_blocks_the_source() {
        let (mut n, id, ticket) = granted();
        let mut s = DataServerSession::new(cfg(50, 8), key(), ms(2));
        let mut c = DataClientSession::new(cfg(51, 4), key(), id, "sonar", ticket, ms(2));
        pump(&mut s, &mut c, &mut n, ms(2));
        // The socket is not drained while the source produces 100 samples.
        for i in 0..100u64 {
            s.offer(i, &i.to_le_bytes());
        }
        assert_eq!(s.dropped(), 92);
        pump(&mut s, &mut c, &mut n, ms(3));
        // The target does not read while 8 arrive; it keeps the latest 4.
        let got: Vec<u64> = std::iter::from_fn(|| c.pop_sample())
            .map(|x| x.stamp_us)
            .collect();
        assert_eq!(got, vec![96, 97, 98, 99]);
        assert_eq!(c.lost_samples(), 4);
    }

    #[test]
    fn revoke_closes_the_session_and_tells_the_client_why() {
        let (mut n, id, ticket) = granted();
        let mut s = DataServerSession::new(cfg(50, 8), key(), ms(2));
        let mut c = DataClientSession::new(cfg(51, 8), key(), id, "sonar", ticket, ms(2));
        pump(&mut s, &mut c, &mut n, ms(2));
        c.poll_event();
        s.revoke(RevokeReason::TaskPriority);
        s.offer(1, b"late");
        pump(&mut s, &mut c, &mut n, ms(3));
        assert_eq!(
            c.poll_event(),
            Some(DataEvent::Closed(DataClose::Revoked(
                RevokeReason::TaskPriority
            )))
        );
        assert!(!c.is_open());
        assert_eq!(c.pop_sample(), None);
    }

    #[test]
    fn silent_source_is_lost_within_three_heartbeats() {
        let (mut n, id, ticket) = granted();
        let mut s = DataServerSession::new(cfg(50, 8), key(), ms(0));
        let mut c = DataClientSession::new(cfg(51, 8), key(), id, "sonar", ticket, ms(0));
        pump(&mut s, &mut c, &mut n, ms(0));
        c.poll_event();
        // Heartbeats both ways keep the session up.
        for t in (0..1000).step_by(50) {
            s.handle_timeout(ms(t));
            c.handle_timeout(ms(t));
            pump(&mut s, &mut c, &mut n, ms(t));
        }
        assert!(c.is_open() && s.is_streaming());
        // The source dies after t = 950; its last frame (a heartbeat, sent when idle for one
        // interval) left at t = 900, so the client must declare it lost at 900 + 3 × 100.
        let mut buf = vec![0u8; 1000];
        let mut t = 1000;
        while t < 1200 {
            c.handle_timeout(ms(t));
            while c.poll_transmit(&mut buf, ms(t)).is_some() {}
            assert!(c.poll_event().is_none(), "lost too early at {t}");
            t += 10;
        }
        assert_eq!(c.poll_timeout(), Some(ms(1200)));
        c.handle_timeout(ms(1200));
        assert_eq!(c.poll_event(), Some(DataEvent::Closed(DataClose::Lost)));
    }
}

#[test]
fn first_counter_window_applies_to_unknown_senders_only() {
    let mut s = Signer::new(key(), 5, 1_000);
    let a = s.seal_vec(&Msg::Heartbeat).unwrap();
    let mut v = Verifier::new(key());
    v.set_first_counter_window(Some((2_000, 3_000)));
    assert_eq!(
        v.open(&a).map(|_| ()),
        Err(WireError::Replay {
            sender: 5,
            last: 2_000,
            got: 1_000
        })
    );
    let mut late = Signer::new(key(), 6, 4_000);
    assert!(matches!(
        v.open(&late.seal_vec(&Msg::Heartbeat).unwrap()),
        Err(WireError::Replay { last: 3_000, .. })
    ));
    // Inside the window: accepted; afterwards only the per-sender rule applies.
    s.advance_to(2_500);
    assert_eq!(s.next_counter(), 2_500);
    s.advance_to(10); // never down
    assert_eq!(s.next_counter(), 2_500);
    v.open(&s.seal_vec(&Msg::Heartbeat).unwrap()).unwrap();
    v.set_first_counter_window(Some((9_000, 9_500)));
    v.open(&s.seal_vec(&Msg::Heartbeat).unwrap()).unwrap();
    v.set_first_counter_window(None);
    v.open(&late.seal_vec(&Msg::Heartbeat).unwrap()).unwrap();
    assert_eq!(v.rejects.replay, 2);
}

#[test]
fn a_session_data_address_overrides_the_configured_one_in_grants() {
    let mut n = Net::new(0, |_| {});
    let a = n.add("scout", 1, ms(0));
    let b = n.add("pioneer", 2, ms(0));
    n.m.set_data_address(a as u64, "192.168.1.5:7401".into());
    for c in [a, b] {
        n.register(c, ms(0));
        n.events(c);
        n.clients[c].request("sonar", 3).unwrap();
    }
    n.pump(ms(10));
    let addr_of = |ev: Vec<ClientEvent>| match &ev[..] {
        [ClientEvent::Granted { address, .. }] => address.clone(),
        other => panic!("{other:?}"),
    };
    assert_eq!(addr_of(n.events(a)), "192.168.1.5:7401");
    assert_eq!(addr_of(n.events(b)), ADDR);
}

/// Errors read as sentences that name the limit or the cause, not as `Debug` names
/// (`FieldTooLong` used to be all a user saw of a name over 255 bytes).
#[test]
fn wire_errors_say_what_is_wrong_in_words() {
    let long = "r".repeat(256);
    let e = Signer::new(key(), 9, 1)
        .seal_vec(&status(&long, 1))
        .unwrap_err();
    assert_eq!(e, WireError::FieldTooLong);
    let text = e.to_string();
    assert!(text.contains("at most 255 bytes"), "{text}");
    assert!(text.contains("65,535"), "{text}");
    assert!(
        Signer::new(key(), 9, 1)
            .seal_vec(&status(&long[..255], 1))
            .is_ok()
    );
    let texts = [
        (WireError::BadMac, "another group key"),
        (WireError::BadMagic(*b"GE"), "47 45, not 49 50"),
        (
            WireError::Truncated { need: 40, got: 10 },
            "10 bytes where 40",
        ),
        (
            WireError::Body(BodyError::BadCode(9)),
            "malformed body: code 9",
        ),
        (
            WireError::Replay {
                sender: 3,
                last: 7,
                got: 7,
            },
            "counter 7 from sender 0x0000000000000003 is not above its last accepted counter 7",
        ),
    ];
    for (e, want) in texts {
        let text = e.to_string();
        assert!(text.contains(want), "{e:?}: {text}");
        assert!(!text.contains(&format!("{e:?}")), "{text}");
    }
}
