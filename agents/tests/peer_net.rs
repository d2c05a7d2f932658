//! Loopback tests of the Peer Agent net shell (feature `net`): real sockets on 127.0.0.1.
//! No timing assertions: every wait is bounded by a generous timeout so that a failure fails
//! instead of hanging, and heartbeats are long (500 ms) so that a loaded CI machine does not
//! declare a live peer lost; only the loss-detection test uses a shorter interval.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use ima_agents::peer::manager::FixedSelfAgent;
use ima_agents::peer::net::{
    BroadcastChannel, BroadcastMode, EndReason, LossReason, ManagerHandle, NetError,
    PeerClientHandle, PeerNetConfig, SourcePublisher, Subscription, SubscriptionEvent,
    spawn_manager, unix_micros,
};
use ima_agents::peer::wire::{GroupKey, MissionEvent, Msg, RevokeReason, Signer, SourceInfo};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::time::timeout;

const GENEROUS: Duration = Duration::from_secs(20);

/// Heartbeat interval of every test but the loss-detection one (loss window 1.5 s).
const HEARTBEAT_MS: u64 = 500;

fn key() -> GroupKey {
    GroupKey::from_array(*b"group key of the test fleet, 32b")
}

fn cfg(robot: &str) -> PeerNetConfig {
    let mut c = PeerNetConfig::loopback(robot);
    c.heartbeat_ms = HEARTBEAT_MS;
    c
}

/// Awaits `f` for at most [`GENEROUS`]; a hang becomes a failure.
async fn within<T>(what: &str, f: impl std::future::Future<Output = T>) -> T {
    match timeout(GENEROUS, f).await {
        Ok(v) => v,
        Err(_) => panic!("timed out waiting for {what}"),
    }
}

fn info(name: &str) -> SourceInfo {
    SourceInfo {
        name: name.into(),
        kind: "status".into(),
        schema: 1,
        rate_mhz: 100_000,
    }
}

async fn manager(robot: &str) -> ManagerHandle {
    spawn_manager(&cfg(robot), key(), FixedSelfAgent::new(0, Vec::new()))
        .await
        .unwrap()
}

/// Publishes a counter every 2 ms until dropped.
fn pump(p: SourcePublisher) -> tokio::task::JoinHandle<()> {
    tokio::spawn(async move {
        let mut i: u64 = 0;
        loop {
            i += 1;
            let _ = p.publish(i, &i.to_le_bytes());
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
    })
}

async fn next(sub: &mut Subscription) -> SubscriptionEvent {
    timeout(GENEROUS, sub.next())
        .await
        .expect("an event in time")
        .expect("subscription still open")
}

async fn expect_samples(sub: &mut Subscription, n: usize) {
    let mut last = 0;
    let mut got = 0;
    while got < n {
        match next(sub).await {
            SubscriptionEvent::Sample { seq, payload, .. } => {
                assert!(seq > last, "sequence grows");
                assert_eq!(payload.len(), 8);
                last = seq;
                got += 1;
            }
            other => panic!("expected samples, got {other:?}"),
        }
    }
}

/// Waits for the end of a subscription, skipping samples.
async fn end_of(sub: &mut Subscription) -> EndReason {
    loop {
        match next(sub).await {
            SubscriptionEvent::Closed { reason } => return reason,
            SubscriptionEvent::Sample { .. } | SubscriptionEvent::Lost { .. } => {}
        }
    }
}

#[tokio::test]
async fn client_streams_a_source_end_to_end() {
    let m = manager("skeeter").await;
    let _p = pump(m.publisher(info("counter")).unwrap());
    let c = PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
        .await
        .unwrap();
    let sources = within("register", c.register()).await.unwrap();
    assert!(sources.iter().any(|s| s.name == "counter"));
    let mut sub = within("request", c.request("counter", 1)).await.unwrap();
    expect_samples(&mut sub, 20).await;
    assert!(matches!(
        within("request", c.request("counter", 1)).await,
        Err(NetError::AlreadySubscribed)
    ));
    assert!(matches!(
        within("request", c.request("nope", 1)).await,
        Err(NetError::Denied(_))
    ));
    let st = within("stats", m.stats()).await.unwrap();
    assert_eq!(st.clients, 1);
    assert_eq!(st.data_sessions, 1);
    within("disconnect", c.disconnect("counter")).await.unwrap();
    assert_eq!(end_of(&mut sub).await, EndReason::Disconnected);
    assert!(
        within("end of the subscription", sub.next())
            .await
            .is_none()
    );
    within("unregister", c.unregister()).await.unwrap();
}

#[tokio::test]
async fn sources_added_and_removed_at_runtime() {
    let m = manager("skeeter").await;
    let c = PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
        .await
        .unwrap();
    assert!(within("register", c.register()).await.unwrap().is_empty());
    let p = m.publisher(info("late")).unwrap();
    timeout(GENEROUS, async {
        while !c
            .sources()
            .await
            .unwrap()
            .1
            .iter()
            .any(|s| s.name == "late")
        {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .unwrap();
    let pumping = pump(p);
    let mut sub = within("request", c.request("late", 0)).await.unwrap();
    expect_samples(&mut sub, 3).await;
    pumping.abort(); // drops the publisher: the source is gone
    assert_eq!(
        end_of(&mut sub).await,
        EndReason::Revoked(RevokeReason::SourceGone)
    );
    timeout(GENEROUS, async {
        while c
            .sources()
            .await
            .unwrap()
            .1
            .iter()
            .any(|s| s.name == "late")
        {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .unwrap();
}

#[tokio::test]
async fn task_priority_gates_revokes_and_regrants() {
    let m = manager("skeeter").await;
    let _p = pump(m.publisher(info("ses")).unwrap());
    m.set_task_priority(Some(5));
    let c = Arc::new(
        PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
            .await
            .unwrap(),
    );
    within("register", c.register()).await.unwrap();
    // Priority 3 < task 5: pending until the task priority falls.
    let c2 = c.clone();
    let req = tokio::spawn(async move { within("request", c2.request("ses", 3)).await });
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert!(!req.is_finished(), "a pending request waits");
    m.set_task_priority(Some(2));
    let mut sub = timeout(GENEROUS, req).await.unwrap().unwrap().unwrap();
    expect_samples(&mut sub, 5).await;
    // Task priority rises: revoked, pending again, then re-granted.
    m.set_task_priority(Some(9));
    loop {
        match next(&mut sub).await {
            SubscriptionEvent::Lost { reason } => {
                assert_eq!(reason, LossReason::Revoked(RevokeReason::TaskPriority));
                break;
            }
            SubscriptionEvent::Sample { .. } => {}
            other => panic!("{other:?}"),
        }
    }
    m.set_task_priority(None);
    expect_samples(&mut sub, 5).await;
}

/// A TCP proxy that can be cut: it then stops forwarding but keeps both sockets open, so
/// only the missed heartbeats can reveal the loss.
async fn proxy(upstream: Arc<Mutex<Option<SocketAddr>>>, cut: Arc<AtomicBool>) -> SocketAddr {
    let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(async move {
        loop {
            let (inbound, _) = l.accept().await.unwrap();
            let up = (*upstream.lock().unwrap()).unwrap();
            let outbound = TcpStream::connect(up).await.unwrap();
            let (ri, wi) = inbound.into_split();
            let (ro, wo) = outbound.into_split();
            for (mut r, mut w) in [
                (
                    Box::new(ri) as Box<dyn tokio::io::AsyncRead + Unpin + Send>,
                    Box::new(wo) as Box<dyn tokio::io::AsyncWrite + Unpin + Send>,
                ),
                (Box::new(ro), Box::new(wi)),
            ] {
                let cut = cut.clone();
                tokio::spawn(async move {
                    let mut buf = vec![0u8; 65536];
                    loop {
                        let n = match r.read(&mut buf).await {
                            Ok(0) | Err(_) => return,
                            Ok(n) => n,
                        };
                        if cut.load(Ordering::SeqCst) {
                            // Hold the sockets open, forward nothing more.
                            std::future::pending::<()>().await;
                        }
                        if w.write_all(&buf[..n]).await.is_err() {
                            return;
                        }
                    }
                });
            }
        }
    });
    addr
}

#[tokio::test]
async fn silent_manager_is_declared_lost_within_three_heartbeats() {
    let cut = Arc::new(AtomicBool::new(false));
    let req_up = Arc::new(Mutex::new(None));
    let data_up = Arc::new(Mutex::new(None));
    let req_proxy = proxy(req_up.clone(), cut.clone()).await;
    let data_proxy = proxy(data_up.clone(), cut.clone()).await;
    // The one test with a short heartbeat: 200 ms (0.6 s loss window).
    let short = |robot: &str| {
        let mut c = cfg(robot);
        c.heartbeat_ms = 200;
        c
    };
    let mut mc = short("skeeter");
    mc.manager.data_advertise = Some(data_proxy.to_string());
    let m = spawn_manager(&mc, key(), FixedSelfAgent::new(0, Vec::new()))
        .await
        .unwrap();
    *req_up.lock().unwrap() = Some(m.local_addr());
    *data_up.lock().unwrap() = Some(m.data_addr());
    let _p = pump(m.publisher(info("counter")).unwrap());
    let c = PeerClientHandle::connect(req_proxy, &short("scooter"), key())
        .await
        .unwrap();
    within("register", c.register()).await.unwrap();
    let mut sub = within("request", c.request("counter", 0)).await.unwrap();
    expect_samples(&mut sub, 5).await;
    cut.store(true, Ordering::SeqCst);
    let reason = end_of(&mut sub).await;
    assert!(
        matches!(
            reason,
            EndReason::ManagerLost | EndReason::Data(ima_agents::peer::data::DataClose::Lost)
        ),
        "{reason:?}"
    );
    // Reported: `end_of` bounds the wait generously; no assertion on the elapsed time.
    // The client's side goes on running: its handle answers, with the loss.
    timeout(GENEROUS, async {
        while !c.is_lost() {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .unwrap();
    assert!(matches!(
        within("register", c.register()).await,
        Err(NetError::ManagerLost)
    ));
    // The manager, too, saw the silent client go.
    timeout(GENEROUS, async {
        while within("stats", m.stats()).await.unwrap().clients != 0 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await
    .unwrap();
    assert!(within("stats", m.stats()).await.unwrap().core.lost >= 1);
}

#[tokio::test]
async fn killed_manager_closes_every_session() {
    let m = manager("skeeter").await;
    let _p = pump(m.publisher(info("a")).unwrap());
    let _q = pump(m.publisher(info("b")).unwrap());
    let c = PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
        .await
        .unwrap();
    within("register", c.register()).await.unwrap();
    let mut a = within("request", c.request("a", 0)).await.unwrap();
    let mut b = within("request", c.request("b", 0)).await.unwrap();
    expect_samples(&mut a, 2).await;
    expect_samples(&mut b, 2).await;
    m.abort();
    for s in [&mut a, &mut b] {
        let r = end_of(s).await;
        assert!(
            matches!(r, EndReason::ManagerLost | EndReason::Data(_)),
            "{r:?}"
        );
    }
}

#[tokio::test]
async fn orderly_shutdown_revokes_grants() {
    let m = manager("skeeter").await;
    let _p = pump(m.publisher(info("a")).unwrap());
    let c = PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
        .await
        .unwrap();
    within("register", c.register()).await.unwrap();
    let mut a = within("request", c.request("a", 0)).await.unwrap();
    expect_samples(&mut a, 2).await;
    within("shutdown", m.shutdown()).await;
    let r = end_of(&mut a).await;
    assert_eq!(r, EndReason::Revoked(RevokeReason::Shutdown));
}

async fn closed_by_peer(mut s: TcpStream) -> bool {
    let mut buf = [0u8; 4096];
    timeout(GENEROUS, async {
        loop {
            match s.read(&mut buf).await {
                Ok(0) | Err(_) => return true,
                Ok(_) => {}
            }
        }
    })
    .await
    .unwrap_or(false)
}

#[tokio::test]
async fn bad_frames_are_rejected_counted_and_others_served() {
    let m = manager("skeeter").await;
    let _p = pump(m.publisher(info("counter")).unwrap());
    let good = PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
        .await
        .unwrap();
    within("register", good.register()).await.unwrap();
    let mut sub = within("request", good.request("counter", 0)).await.unwrap();
    expect_samples(&mut sub, 3).await;

    let register = |client| Msg::Register {
        client,
        robot: "mallory".into(),
    };
    // Unauthenticated: sealed under another key.
    let mut s = TcpStream::connect(m.local_addr()).await.unwrap();
    let wrong = GroupKey::from_array([9; 32]);
    s.write_all(
        &Signer::new(wrong, 77, unix_micros() + 1)
            .seal_vec(&register(1))
            .unwrap(),
    )
    .await
    .unwrap();
    assert!(closed_by_peer(s).await);
    // Malformed: garbage.
    let mut s = TcpStream::connect(m.local_addr()).await.unwrap();
    s.write_all(&[0x55; 64]).await.unwrap();
    assert!(closed_by_peer(s).await);
    // Oversized: a header that claims a 60 000-byte body.
    let mut s = TcpStream::connect(m.local_addr()).await.unwrap();
    let mut big = Signer::new(key(), 78, unix_micros() + 1)
        .seal_vec(&Msg::Heartbeat)
        .unwrap();
    big[4..6].copy_from_slice(&60_000u16.to_le_bytes());
    s.write_all(&big).await.unwrap();
    assert!(closed_by_peer(s).await);
    // Replayed: a good frame recorded on one session, played again on another.
    let recorded = Signer::new(key(), 79, unix_micros() + 1)
        .seal_vec(&register(5))
        .unwrap();
    let mut s1 = TcpStream::connect(m.local_addr()).await.unwrap();
    s1.write_all(&recorded).await.unwrap();
    let mut buf = [0u8; 512];
    let n = within("Registered", s1.read(&mut buf)).await.unwrap();
    assert!(n > 0, "the original frame is answered (Registered)");
    let mut s2 = TcpStream::connect(m.local_addr()).await.unwrap();
    s2.write_all(&recorded).await.unwrap();
    assert!(closed_by_peer(s2).await);
    // A forged ticket on the data server.
    let mut d = TcpStream::connect(m.data_addr()).await.unwrap();
    let open = Msg::OpenData {
        client: 5,
        source: "counter".into(),
        ticket: [0; 32],
    };
    d.write_all(
        &Signer::new(key(), 80, unix_micros() + 1)
            .seal_vec(&open)
            .unwrap(),
    )
    .await
    .unwrap();
    assert!(closed_by_peer(d).await);
    // Garbage and a wrong-key frame on the data server.
    let mut d = TcpStream::connect(m.data_addr()).await.unwrap();
    d.write_all(&[0xAA; 40]).await.unwrap();
    assert!(closed_by_peer(d).await);
    let mut d = TcpStream::connect(m.data_addr()).await.unwrap();
    let stranger_open = Signer::new(GroupKey::from_array([4; 32]), 81, unix_micros() + 1)
        .seal_vec(&Msg::OpenData {
            client: 5,
            source: "counter".into(),
            ticket: [0; 32],
        })
        .unwrap();
    d.write_all(&stranger_open).await.unwrap();
    assert!(closed_by_peer(d).await);
    // A client with the wrong key cannot register.
    let stranger = PeerClientHandle::connect(
        m.local_addr(),
        &cfg("mallory"),
        GroupKey::from_array([1; 32]),
    )
    .await
    .unwrap();
    // It is told why, not only that the manager is lost.
    let e = timeout(GENEROUS, stranger.register()).await.unwrap();
    let Err(NetError::Unauthenticated(a)) = e else {
        panic!("expected an authentication failure, got {e:?}")
    };
    assert_eq!(a.from, m.local_addr());
    assert_eq!(stranger.auth_failure(), Some(a));
    assert!(
        e.unwrap_err()
            .to_string()
            .contains("is the key file the same")
    );

    let st = within("stats", m.stats()).await.unwrap();
    let r = st.core.rejects;
    assert!(r.bad_mac >= 2, "{r:?}");
    assert!(r.bad_magic >= 1, "{r:?}");
    assert!(r.oversize >= 1, "{r:?}");
    assert!(r.replay >= 1, "{r:?}");
    assert!(st.data_bad_tickets >= 1, "{st:?}");
    timeout(GENEROUS, async {
        loop {
            let d = within("stats", m.stats()).await.unwrap().data_rejects;
            if d.bad_magic >= 1 && d.bad_mac >= 1 {
                break;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await
    .expect("data-server rejections counted");
    // The good client is still served.
    expect_samples(&mut sub, 10).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_hundred_clients_register_at_once() {
    // Long heartbeats (3 s loss window) and generous waits: 400 sessions on a loaded
    // 2-core machine must not be declared lost while they queue.
    let slow = |robot: &str| {
        let mut c = cfg(robot);
        c.heartbeat_ms = 1000;
        // A registration may queue behind 199 others on a loaded machine.
        c.call_timeout_ms = 60_000;
        c
    };
    let m = spawn_manager(&slow("skeeter"), key(), FixedSelfAgent::new(0, Vec::new()))
        .await
        .unwrap();
    let addr = m.local_addr();
    let mut tasks = Vec::new();
    for i in 0..200 {
        tasks.push(tokio::spawn(async move {
            let c = PeerClientHandle::connect(addr, &slow(&format!("r{i}")), key())
                .await
                .unwrap();
            let r = c.register().await;
            (c, r)
        }));
    }
    let mut clients = Vec::new();
    for t in tasks {
        let (c, r) = timeout(Duration::from_secs(120), t)
            .await
            .expect("a registration in time")
            .unwrap();
        r.unwrap();
        clients.push(c);
    }
    let st = within("stats", m.stats()).await.unwrap();
    assert_eq!(st.clients, 200);
    assert_eq!(st.sessions, 200);
    // No frame came before the core knew its session (a Register that did was dropped, and
    // its client waited out the 60 s call timeout: one `.ci/run` failed so).
    assert_eq!(st.core.unknown_peer, 0);
    let ids: std::collections::BTreeSet<u64> = {
        let mut v = std::collections::BTreeSet::new();
        for c in &clients {
            v.insert(within("sources", c.sources()).await.unwrap().0);
        }
        v
    };
    assert_eq!(ids.len(), 200);
}

/// A UDP port that no other test of this process was given: the channels share ports
/// through `SO_REUSEPORT`, so two tests handed the same free port would hear each other.
/// The port is free when picked (a socket without `SO_REUSE*` got it from the kernel) and
/// never handed out twice in this process.
fn free_udp_port() -> u16 {
    static GIVEN: Mutex<std::collections::BTreeSet<u16>> =
        Mutex::new(std::collections::BTreeSet::new());
    loop {
        let port = std::net::UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        if GIVEN.lock().unwrap().insert(port) {
            return port;
        }
    }
}

fn bcfg(robot: &str, mode: BroadcastMode, port: u16, peers: &[u16]) -> PeerNetConfig {
    let mut c = cfg(robot);
    c.broadcast.mode = mode;
    c.broadcast.port = port;
    c.broadcast.group = "239.255.73.78".into();
    c.broadcast.peers = peers.iter().map(|p| format!("127.0.0.1:{p}")).collect();
    c
}

async fn recv(ch: &BroadcastChannel) -> Msg {
    timeout(GENEROUS, ch.recv()).await.unwrap().unwrap().0
}

async fn exchange(
    skeeter: BroadcastChannel,
    scooter: BroadcastChannel,
    commander: BroadcastChannel,
) {
    skeeter
        .send_mission(MissionEvent::Accepted, "red")
        .await
        .unwrap();
    scooter
        .send_emergency("target-reached", "red")
        .await
        .unwrap();
    let mut seen = Vec::new();
    for _ in 0..2 {
        seen.push(recv(&commander).await);
    }
    assert!(seen.iter().any(|m| matches!(m, Msg::Mission { robot, event: MissionEvent::Accepted, target, .. } if robot == "skeeter" && target == "red")), "{seen:?}");
    assert!(seen.iter().any(|m| matches!(m, Msg::Emergency { robot, kind, .. } if robot == "scooter" && kind == "target-reached")), "{seen:?}");
    // Managers hear each other, not themselves.
    assert!(matches!(recv(&scooter).await, Msg::Mission { robot, .. } if robot == "skeeter"));
    assert!(matches!(recv(&skeeter).await, Msg::Emergency { robot, .. } if robot == "scooter"));
    skeeter.send_status("scan", "scan=0.9", None).await.unwrap();
    assert!(matches!(recv(&commander).await, Msg::Status { behaviour, .. } if behaviour == "scan"));
}

#[tokio::test]
async fn two_managers_and_a_commander_exchange_broadcasts_by_multicast() {
    let port = free_udp_port();
    let key = key();
    let sk = BroadcastChannel::bind(
        &bcfg("skeeter", BroadcastMode::Multicast, port, &[]),
        "skeeter",
        key.clone(),
    )
    .unwrap();
    let sc = BroadcastChannel::bind(
        &bcfg("scooter", BroadcastMode::Multicast, port, &[]),
        "scooter",
        key.clone(),
    )
    .unwrap();
    let cmd = BroadcastChannel::bind(
        &bcfg("commander", BroadcastMode::Multicast, port, &[]),
        "commander",
        key,
    )
    .unwrap();
    exchange(sk, sc, cmd).await;
}

#[tokio::test]
async fn unicast_fallback_and_both_modes() {
    let (a, b, c) = (free_udp_port(), free_udp_port(), free_udp_port());
    let key = key();
    let sk = BroadcastChannel::bind(
        &bcfg("skeeter", BroadcastMode::Unicast, a, &[b, c]),
        "skeeter",
        key.clone(),
    )
    .unwrap();
    let sc = BroadcastChannel::bind(
        &bcfg("scooter", BroadcastMode::Unicast, b, &[a, c]),
        "scooter",
        key.clone(),
    )
    .unwrap();
    let cmd = BroadcastChannel::bind(
        &bcfg("commander", BroadcastMode::Unicast, c, &[]),
        "commander",
        key.clone(),
    )
    .unwrap();
    exchange(sk, sc, cmd.clone()).await;

    // Both: the same message arrives twice; the copy is dropped as a duplicate.
    // The sender binds its own port, so the listener alone owns port d and gets both the
    // multicast copy and the unicast one.
    let d = free_udp_port();
    let mut both_cfg = bcfg("skeeter2", BroadcastMode::Both, d, &[c, d]);
    both_cfg.broadcast.bind_port = Some(0);
    let both = BroadcastChannel::bind(&both_cfg, "skeeter2", key.clone()).unwrap();
    let mut mc = bcfg("commander", BroadcastMode::Multicast, d, &[]);
    mc.broadcast.receive_own = true;
    let listener = BroadcastChannel::bind(&mc, "commander", key).unwrap();
    both.send_emergency("scooter-lost", "x").await.unwrap();
    assert!(matches!(recv(&listener).await, Msg::Emergency { .. }));
    assert!(matches!(recv(&cmd).await, Msg::Emergency { .. }));
    both.send_emergency("scooter-found", "y").await.unwrap();
    assert!(
        matches!(recv(&listener).await, Msg::Emergency { kind, .. } if kind == "scooter-found")
    );
    // The copies were counted as duplicates, not as replays.
    let st = listener.stats();
    assert!(st.receiver.duplicate >= 1, "{st:?}");
    assert_eq!(st.wire.replay, 0, "{st:?}");
    assert_eq!(st.receiver.accepted, 2, "{st:?}");
}

/// A unicast port is not shared: a second process binding it (a commander started twice
/// from one configuration) fails, naming the address, instead of taking half of the
/// datagrams meant for the first. A multicast port is shared, as every listener on a host
/// needs it.
#[tokio::test]
async fn a_unicast_port_is_not_shared_and_a_multicast_one_is() {
    let a = free_udp_port();
    let c = bcfg("commander", BroadcastMode::Unicast, a, &[]);
    let _first = BroadcastChannel::bind(&c, "commander", key()).unwrap();
    let e = BroadcastChannel::bind(&c, "commander", key()).unwrap_err();
    assert!(
        e.to_string().contains(&format!(
            "binding the broadcast channel to 0.0.0.0:{a}: Address already in use"
        )),
        "{e}"
    );
    let m = free_udp_port();
    let mut c = bcfg("skeeter", BroadcastMode::Multicast, m, &[]);
    c.broadcast.interface = "127.0.0.1".into();
    let _one = BroadcastChannel::bind(&c, "skeeter", key()).unwrap();
    let _two = BroadcastChannel::bind(&c, "scooter", key()).unwrap();
}

#[tokio::test]
async fn broadcast_rejections_are_counted() {
    let (a, b) = (free_udp_port(), free_udp_port());
    let rx = BroadcastChannel::bind(
        &bcfg("commander", BroadcastMode::Unicast, a, &[]),
        "commander",
        key(),
    )
    .unwrap();
    let tx = BroadcastChannel::bind(
        &bcfg("skeeter", BroadcastMode::Unicast, b, &[a]),
        "skeeter",
        key(),
    )
    .unwrap();
    let stranger = BroadcastChannel::bind(
        &bcfg("mallory", BroadcastMode::Unicast, free_udp_port(), &[a]),
        "mallory",
        GroupKey::from_array([2; 32]),
    )
    .unwrap();
    stranger.send_emergency("fake", "x").await.unwrap();
    tx.send_raw(&[1, 2, 3]).await.unwrap();
    let mut s = Signer::new(key(), 4242, unix_micros() + 10);
    let mut emergency = |seq| {
        s.seal_vec(&Msg::Emergency {
            robot: "replayer".into(),
            seq,
            kind: "k".into(),
            text: "t".into(),
        })
        .unwrap()
    };
    let (first, second) = (emergency(1), emergency(2));
    tx.send_raw(&first).await.unwrap();
    tx.send_raw(&second).await.unwrap();
    tx.send_raw(&first).await.unwrap(); // replay of an older frame
    tx.send_raw(&second).await.unwrap(); // a copy of the last one: a duplicate
    tx.send_mission(MissionEvent::Failed, "blue").await.unwrap();
    let mut got = Vec::new();
    for _ in 0..3 {
        got.push(recv(&rx).await);
    }
    assert!(matches!(&got[0], Msg::Emergency { robot, seq: 1, .. } if robot == "replayer"));
    assert!(matches!(&got[1], Msg::Emergency { robot, seq: 2, .. } if robot == "replayer"));
    assert!(matches!(&got[2], Msg::Mission { robot, .. } if robot == "skeeter"));
    let st = rx.stats();
    assert_eq!(st.wire.bad_mac, 1, "{st:?}");
    assert_eq!(st.wire.replay, 1, "{st:?}");
    assert_eq!(st.receiver.duplicate, 1, "{st:?}");
    assert!(st.wire.truncated >= 1, "{st:?}");
    assert_eq!(st.receiver.accepted, 3);
    // The operator hears of the stranger's frame once, with its address, then not again
    // until more arrive (and the report interval has passed).
    let report = rx.take_auth_report().expect("a report of the bad MAC");
    assert_eq!(report.frames, 1);
    assert_eq!(report.from.port(), stranger.local_addr().unwrap().port());
    assert!(
        report
            .to_string()
            .contains("failed authentication — is the key file the same on every robot?"),
        "{report}"
    );
    assert_eq!(rx.take_auth_report(), None);
}

#[tokio::test]
async fn connections_beyond_the_cap_wait_until_one_closes() {
    let mut mc = cfg("skeeter");
    mc.manager.max_connections = 2;
    // Idle sessions must outlive the test: a 15 s loss window.
    mc.heartbeat_ms = 5000;
    let m = spawn_manager(&mc, key(), FixedSelfAgent::new(0, Vec::new()))
        .await
        .unwrap();
    // Two silent connections hold both permits.
    let idle1 = TcpStream::connect(m.local_addr()).await.unwrap();
    let _idle2 = TcpStream::connect(m.local_addr()).await.unwrap();
    within("two sessions", async {
        while m.stats().await.unwrap().sessions < 2 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await;
    // A third one is not served while they stay open (its frame is not even read)...
    let mut third = TcpStream::connect(m.local_addr()).await.unwrap();
    let register = Msg::Register {
        client: 42,
        robot: "third".into(),
    };
    third
        .write_all(
            &Signer::new(key(), 90, unix_micros() + 1)
                .seal_vec(&register)
                .unwrap(),
        )
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(300)).await;
    assert_eq!(within("stats", m.stats()).await.unwrap().sessions, 2);
    // The one-round-trip snapshot says the same as the two queries.
    let (stats, clients) = within("snapshot", m.snapshot()).await.unwrap();
    assert_eq!((stats.sessions, stats.links.len()), (2, 2));
    assert_eq!(clients, within("status", m.status()).await.unwrap());
    // ...and is served once one of them closes.
    drop(idle1);
    let mut buf = [0u8; 512];
    let n = within("Registered", third.read(&mut buf)).await.unwrap();
    assert!(n > 0, "the third connection is answered");
}

#[tokio::test]
async fn a_first_counter_far_from_the_clock_is_refused_as_a_replay() {
    // A frame recorded a minute ago (before a restart, say): the manager has never heard
    // its sender, and its counter (UNIX µs) lies outside now ± 30 s.
    let m = manager("skeeter").await;
    let old = Signer::new(key(), 91, unix_micros() - 60_000_000)
        .seal_vec(&Msg::Register {
            client: 7,
            robot: "ghost".into(),
        })
        .unwrap();
    let mut s = TcpStream::connect(m.local_addr()).await.unwrap();
    s.write_all(&old).await.unwrap();
    assert!(closed_by_peer(s).await);
    // So is one from the far future.
    let future = Signer::new(key(), 92, unix_micros() + 60_000_000)
        .seal_vec(&Msg::Heartbeat)
        .unwrap();
    let mut s = TcpStream::connect(m.local_addr()).await.unwrap();
    s.write_all(&future).await.unwrap();
    assert!(closed_by_peer(s).await);
    let r = within("stats", m.stats()).await.unwrap().core.rejects;
    assert_eq!(r.replay, 2, "{r:?}");
    // A fresh one is served.
    let c = PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
        .await
        .unwrap();
    within("register", c.register()).await.unwrap();

    // The broadcast receiver applies the same rule.
    let rx = BroadcastChannel::bind(
        &bcfg("commander", BroadcastMode::Unicast, free_udp_port(), &[]),
        "commander",
        key(),
    )
    .unwrap();
    let port = rx.local_addr().unwrap().port();
    let tx = BroadcastChannel::bind(
        &bcfg("skeeter", BroadcastMode::Unicast, free_udp_port(), &[port]),
        "skeeter",
        key(),
    )
    .unwrap();
    let stale = Signer::new(key(), 93, unix_micros() - 60_000_000)
        .seal_vec(&Msg::Emergency {
            robot: "ghost".into(),
            seq: 1,
            kind: "old".into(),
            text: "t".into(),
        })
        .unwrap();
    tx.send_raw(&stale).await.unwrap();
    tx.send_emergency("fresh", "t").await.unwrap();
    assert!(matches!(recv(&rx).await, Msg::Emergency { kind, .. } if kind == "fresh"));
    assert_eq!(rx.stats().wire.replay, 1);
}

#[tokio::test]
async fn dropping_a_subscription_disconnects_and_dropping_the_handle_closes_the_rest() {
    let m = manager("skeeter").await;
    let _p = pump(m.publisher(info("a")).unwrap());
    let _q = pump(m.publisher(info("b")).unwrap());
    let c = PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
        .await
        .unwrap();
    within("register", c.register()).await.unwrap();
    let mut a = within("request", c.request("a", 0)).await.unwrap();
    let mut b = within("request", c.request("b", 0)).await.unwrap();
    expect_samples(&mut a, 2).await;
    expect_samples(&mut b, 2).await;
    drop(a);
    // The manager hears the Disconnect: one data session left, and "a" can be asked again.
    within("one data session", async {
        while m.stats().await.unwrap().data_sessions != 1 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    })
    .await;
    let mut a = within("request", c.request("a", 0)).await.unwrap();
    expect_samples(&mut a, 2).await;
    // Dropping the handle ends every subscription with Closed (not a hang).
    drop(c);
    for s in [&mut a, &mut b] {
        assert_eq!(end_of(s).await, EndReason::Disconnected);
        assert!(within("end", s.next()).await.is_none());
    }
}

#[tokio::test]
async fn publisher_refuses_what_the_competency_list_cannot_carry() {
    let m = manager("skeeter").await;
    let long = "x".repeat(256);
    assert!(matches!(m.publisher(info(&long)), Err(NetError::Config(_))));
    let mut kind = info("k");
    kind.kind = long.clone();
    assert!(matches!(m.publisher(kind), Err(NetError::Config(_))));
    assert!(matches!(m.publisher(info("")), Err(NetError::Config(_))));
    // 255-byte names: the list outgrows max_body (8192) long before 255 sources.
    let name = |i: usize| format!("{i:0>255}");
    let mut kept = Vec::new();
    let mut refused = None;
    for i in 0..40 {
        match m.publisher(info(&name(i))) {
            Ok(p) => kept.push(p),
            Err(e) => {
                refused = Some((i, e));
                break;
            }
        }
    }
    let (i, e) = refused.expect("the list fills up");
    assert!(i > 20 && i < 40, "{i}");
    assert!(matches!(e, NetError::Config(_)));
    // Clients can still register and get the whole list.
    let c = PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
        .await
        .unwrap();
    assert_eq!(within("register", c.register()).await.unwrap().len(), i);
}

#[tokio::test]
async fn a_call_the_manager_never_answers_times_out() {
    // A "manager" that accepts and reads but never answers.
    let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(async move {
        let (mut s, _) = l.accept().await.unwrap();
        let mut buf = [0u8; 1024];
        while s.read(&mut buf).await.is_ok_and(|n| n > 0) {}
    });
    let mut c = cfg("scooter");
    c.heartbeat_ms = 60_000; // the loss window would end it otherwise
    c.call_timeout_ms = 200;
    let h = PeerClientHandle::connect(addr, &c, key()).await.unwrap();
    assert!(matches!(
        within("register", h.register()).await,
        Err(NetError::Timeout)
    ));
}

#[tokio::test]
async fn own_messages_are_recognised_by_node_not_by_robot_name() {
    let port = free_udp_port();
    let a = BroadcastChannel::bind(
        &bcfg("twin", BroadcastMode::Multicast, port, &[]),
        "twin",
        key(),
    )
    .unwrap();
    let b = BroadcastChannel::bind(
        &bcfg("twin", BroadcastMode::Multicast, port, &[]),
        "twin",
        key(),
    )
    .unwrap();
    a.send_emergency("from-a", "").await.unwrap();
    // b hears a (same robot name, another node); a drops its own looped-back copy.
    assert!(matches!(recv(&b).await, Msg::Emergency { kind, .. } if kind == "from-a"));
    b.send_emergency("from-b", "").await.unwrap();
    assert!(matches!(recv(&a).await, Msg::Emergency { kind, .. } if kind == "from-b"));
    assert_eq!(a.stats().own, 1);
}

#[tokio::test] // current-thread runtime: nothing else runs while the loop publishes
async fn samples_a_data_session_missed_are_counted() {
    let mut mc = cfg("skeeter");
    mc.manager.data_queue = 4;
    let m = spawn_manager(&mc, key(), FixedSelfAgent::new(0, Vec::new()))
        .await
        .unwrap();
    let p = m.publisher(info("burst")).unwrap();
    let c = PeerClientHandle::connect(m.local_addr(), &cfg("scooter"), key())
        .await
        .unwrap();
    within("register", c.register()).await.unwrap();
    let mut sub = within("request", c.request("burst", 0)).await.unwrap();
    within("streaming", async {
        while p.subscribers() == 0 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await;
    for i in 0..100u64 {
        let _ = p.publish(i, &i.to_le_bytes());
    }
    within("lag counted", async {
        while m.stats().await.unwrap().lagged_samples == 0 {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
    })
    .await;
    // The newest samples still arrive.
    let _ = next(&mut sub).await;
}

/// Register against a server that reads the registration, answers `reply` and closes: the
/// server's address, the client and the registration's error.
async fn register_with(reply: &[u8]) -> (SocketAddr, PeerClientHandle, NetError) {
    let server = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = server.local_addr().unwrap();
    let reply = reply.to_vec();
    tokio::spawn(async move {
        let (mut s, _) = server.accept().await.unwrap();
        let mut buf = [0u8; 256];
        let _ = s.read(&mut buf).await;
        let _ = s.write_all(&reply).await;
    });
    let c = PeerClientHandle::connect(addr, &cfg("scooter"), key())
        .await
        .unwrap();
    let e = within("register", c.register()).await.unwrap_err();
    (addr, c, e)
}

/// A manager address that is something else (a web server) or a silent listener is named as
/// such: not as a key mismatch, which is what a session closed before any authenticated frame
/// means from a real manager.
#[tokio::test]
async fn a_foreign_or_silent_server_is_not_taken_for_a_key_mismatch() {
    // A web server: it answers the registration with HTTP and closes.
    let (web_addr, c, e) = register_with(b"HTTP/1.1 400 Bad Request\r\n\r\n").await;
    let NetError::NotAPeer(a) = e else {
        panic!("expected NotAPeer, got {e:?}")
    };
    assert_eq!((a.from, a.bytes), (web_addr, 28));
    assert_eq!(c.auth_failure(), None);
    let text = NetError::NotAPeer(a).to_string();
    assert!(
        text.contains("sent 28 byte(s) that are not Peer Agent frames (they begin 48 54 54 50")
            && text.contains("\"HTTP/1.1\"")
            && text.contains("is a Peer Agent manager listening"),
        "{text}"
    );
    // A listener that accepts and says nothing, until the session's loss window passes.
    let mute = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let mute_addr = mute.local_addr().unwrap();
    let keep = tokio::spawn(async move {
        let (s, _) = mute.accept().await.unwrap();
        tokio::time::sleep(GENEROUS).await;
        drop(s);
    });
    let c = PeerClientHandle::connect(mute_addr, &cfg("scooter"), key())
        .await
        .unwrap();
    let e = within("register", c.register()).await.unwrap_err();
    let NetError::NotAPeer(a) = e else {
        panic!("expected NotAPeer, got {e:?}")
    };
    assert_eq!(a.bytes, 0);
    assert!(
        NetError::NotAPeer(a)
            .to_string()
            .contains("accepted the connection but sent nothing"),
        "{a:?}"
    );
    keep.abort();
    // A short reply, too short for a Peer header (22 bytes), then the close: foreign too.
    let (_, _, e) = register_with(b"-ERR\r\n").await;
    let NetError::NotAPeer(a) = e else {
        panic!("expected NotAPeer for a 6-byte reply, got {e:?}")
    };
    let text = NetError::NotAPeer(a).to_string();
    assert!(
        text.contains(
            "sent 6 byte(s) that are not Peer Agent frames (they begin 2d 45 52 52 0d 0a"
        ),
        "{text}"
    );
    // A Peer header of another protocol version: named as such.
    let mut frame = [0u8; 64];
    frame[..3].copy_from_slice(&[b'I', b'P', 9]);
    let (_, _, e) = register_with(&frame).await;
    let NetError::NotAPeer(a) = e else {
        panic!("expected NotAPeer for another version, got {e:?}")
    };
    let text = NetError::NotAPeer(a).to_string();
    assert!(
        text.contains("speaks version 9 of the Peer Agent protocol; this program speaks version 1"),
        "{text}"
    );
    // A listener that closes at once is what a manager under another key does: still told
    // as a possible key mismatch.
    let shut = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let shut_addr = shut.local_addr().unwrap();
    tokio::spawn(async move {
        let (s, _) = shut.accept().await.unwrap();
        drop(s);
    });
    let c = PeerClientHandle::connect(shut_addr, &cfg("scooter"), key())
        .await
        .unwrap();
    let e = within("register", c.register()).await.unwrap_err();
    assert!(
        matches!(e, NetError::Unauthenticated(a) if a.frames == 0),
        "{e:?}"
    );
}
