//! Loopback benchmarks of the Peer Agent net shell (feature `net`):
//! `cargo bench -p ima-agents --features net --bench peer_net`.
//!
//! `main` first runs the socket measurements whose figures are distributions or rates
//! (percentiles computed here from the raw samples and printed), then divan's benches:
//!
//! * register → grant round trip over TCP (p50/p99 of `register()` and of `request()`);
//! * one data session's throughput, 64 B and 1 KiB samples (samples/s delivered);
//! * broadcast fan-out: one multicast datagram to 50 listeners (time until all have it);
//! * a manager holding 1,000 registered clients: RSS growth and grant latency;
//! * loss detection at a 100 ms heartbeat (a proxy stops forwarding; time to `Closed`).
//!
//! divan measures the per-call costs with allocation counts (`AllocProfiler`): publishing one
//! sample, and registering 1,000 clients on the sans-IO manager core.

use std::hint::black_box;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use ima_agents::peer::manager::{FixedSelfAgent, ManagerConfig, PeerManager};
use ima_agents::peer::net::{
    BroadcastChannel, PeerClientHandle, PeerNetConfig, SubscriptionEvent, spawn_manager,
};
use ima_agents::peer::wire::{GroupKey, Msg, Signer, SourceInfo};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

#[global_allocator]
static ALLOC: divan::AllocProfiler = divan::AllocProfiler::system();

fn key() -> GroupKey {
    GroupKey::from_array(*b"group key of the test fleet, 32b")
}

fn info(name: &str) -> SourceInfo {
    SourceInfo {
        name: name.into(),
        kind: "bench".into(),
        schema: 1,
        rate_mhz: 0,
    }
}

fn rt() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

fn pct(v: &mut [Duration], p: f64) -> Duration {
    v.sort_unstable();
    let i = ((v.len() as f64 - 1.0) * p).round() as usize;
    v[i.min(v.len() - 1)]
}

fn report(name: &str, v: &mut [Duration]) {
    let p50 = pct(v, 0.50);
    let p99 = pct(v, 0.99);
    let max = pct(v, 1.0);
    println!(
        "{name:<44} n={:<5} p50={:>8.1} µs  p99={:>8.1} µs  max={:>8.1} µs",
        v.len(),
        p50.as_secs_f64() * 1e6,
        p99.as_secs_f64() * 1e6,
        max.as_secs_f64() * 1e6
    );
}

async fn round_trips(n: usize) {
    let cfg = PeerNetConfig::loopback("skeeter");
    let m = spawn_manager(&cfg, key(), FixedSelfAgent::default())
        .await
        .unwrap();
    let _p = m.publisher(info("ses")).unwrap();
    let c = PeerClientHandle::connect(m.local_addr(), &PeerNetConfig::loopback("scooter"), key())
        .await
        .unwrap();
    let mut reg = Vec::with_capacity(n);
    let mut grant = Vec::with_capacity(n);
    for _ in 0..n {
        let t = Instant::now();
        c.register().await.unwrap();
        reg.push(t.elapsed());
        let t = Instant::now();
        let sub = c.request("ses", 1).await.unwrap();
        grant.push(t.elapsed());
        // Dropping the subscription disconnects the source.
        drop(sub);
        c.unregister().await.unwrap();
    }
    report("register round trip", &mut reg);
    report("request -> grant round trip", &mut grant);
}

async fn throughput(size: usize, secs: f64) {
    let cfg = PeerNetConfig::loopback("skeeter");
    let m = spawn_manager(&cfg, key(), FixedSelfAgent::default())
        .await
        .unwrap();
    let p = m.publisher(info("blob")).unwrap();
    let c = PeerClientHandle::connect(m.local_addr(), &PeerNetConfig::loopback("scooter"), key())
        .await
        .unwrap();
    c.register().await.unwrap();
    let mut sub = c.request("blob", 0).await.unwrap();
    while p.subscribers() == 0 {
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
    // Flow control for the measurement only: the producer keeps at most WINDOW samples in
    // flight (below the 64-sample latest-value queues), so what is measured is the rate a
    // session sustains without dropping, not how fast `publish` can overwrite.
    const WINDOW: u64 = 48;
    let stop = Arc::new(AtomicBool::new(false));
    let received = Arc::new(AtomicU64::new(0));
    let credit = Arc::new(tokio::sync::Notify::new());
    let (stop2, recv2, credit2) = (stop.clone(), received.clone(), credit.clone());
    let payload = vec![0xA5u8; size];
    let producer = tokio::spawn(async move {
        let mut published = 0u64;
        while !stop2.load(Ordering::Relaxed) {
            if published >= recv2.load(Ordering::Relaxed) + WINDOW {
                let _ = tokio::time::timeout(Duration::from_millis(2), credit2.notified()).await;
                // Samples dropped on the way never come back: resynchronise.
                let r = recv2.load(Ordering::Relaxed);
                if published >= r + WINDOW {
                    published = r;
                }
                continue;
            }
            published += 1;
            let _ = p.publish(published, &payload);
        }
    });
    let t0 = Instant::now();
    let (mut got, mut first_seq, mut last_seq) = (0u64, None, 0u64);
    while t0.elapsed().as_secs_f64() < secs {
        if let Some(SubscriptionEvent::Sample { seq, payload, .. }) = sub.next().await {
            assert_eq!(payload.len(), size);
            got += 1;
            first_seq.get_or_insert(seq);
            last_seq = seq;
            received.fetch_add(1, Ordering::Relaxed);
            if got % 16 == 0 {
                credit.notify_one();
            }
        }
    }
    let dt = t0.elapsed().as_secs_f64();
    stop.store(true, Ordering::Relaxed);
    credit.notify_one();
    let _ = producer.await;
    let sent = last_seq - first_seq.unwrap_or(0) + 1;
    println!(
        "data session {size:>5} B samples                 {:>9.0} samples/s delivered ({:.1} MB/s of \
         payload), {} of {} sent samples dropped",
        got as f64 / dt,
        got as f64 * size as f64 / dt / 1e6,
        sent.saturating_sub(got),
        sent,
    );
}

async fn fanout(listeners: usize, messages: usize) {
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut cfg = PeerNetConfig::loopback("x");
    cfg.broadcast.port = port;
    cfg.broadcast.group = "239.255.73.80".into();
    let received = Arc::new(AtomicU64::new(0));
    let notify = Arc::new(tokio::sync::Notify::new());
    let mut tasks = Vec::new();
    for i in 0..listeners {
        let ch = BroadcastChannel::bind(&cfg, &format!("listener{i}"), key()).unwrap();
        let (r, n) = (received.clone(), notify.clone());
        tasks.push(tokio::spawn(async move {
            loop {
                if ch.recv().await.is_ok() {
                    r.fetch_add(1, Ordering::SeqCst);
                    n.notify_one();
                }
            }
        }));
    }
    let tx = BroadcastChannel::bind(&cfg, "skeeter", key()).unwrap();
    let mut lat = Vec::new();
    let mut lost = 0;
    for k in 0..messages {
        let target = ((k + 1) * listeners) as u64;
        let t = Instant::now();
        tx.send_emergency("bench", "fan-out").await.unwrap();
        let done = tokio::time::timeout(Duration::from_millis(500), async {
            while received.load(Ordering::SeqCst) < target {
                notify.notified().await;
            }
        })
        .await;
        if done.is_err() {
            lost += 1;
            received.store(target, Ordering::SeqCst);
        }
        lat.push(t.elapsed());
    }
    report(
        &format!("broadcast fan-out to {listeners} listeners (all have it)"),
        &mut lat,
    );
    if lost > 0 {
        println!("  ({lost} of {messages} messages missed by at least one listener)");
    }
    for t in tasks {
        t.abort();
    }
}

fn rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/statm")
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map_or(0, |pages| pages * 4096)
}

async fn thousand_clients(n: usize, trips: usize) {
    let mut cfg = PeerNetConfig::loopback("skeeter");
    cfg.heartbeat_ms = 60_000; // the raw clients below do not heartbeat
    let m = spawn_manager(&cfg, key(), FixedSelfAgent::default())
        .await
        .unwrap();
    let _p = m.publisher(info("ses")).unwrap();
    let addr = m.local_addr();
    let before = rss_bytes();
    // Raw clients: one socket and one sealed Register each, so this process's growth is the
    // manager's (the client side holds only the sockets).
    let mut socks = Vec::with_capacity(n);
    // Counters start at the clock (µs since the UNIX epoch), as every real sender's do: the
    // manager refuses a first counter farther than `max_clock_skew_ms` from its clock.
    let now_us = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(1, |d| d.as_micros() as u64);
    for i in 0..n {
        let mut s = TcpStream::connect(addr).await.unwrap();
        let mut signer = Signer::new(key(), 1_000_000 + i as u64, now_us);
        let f = signer
            .seal_vec(&Msg::Register {
                client: 10_000 + i as u64,
                robot: format!("robot{i}"),
            })
            .unwrap();
        s.write_all(&f).await.unwrap();
        socks.push(s);
    }
    let mut buf = [0u8; 256];
    for s in &mut socks {
        let _ = s.read(&mut buf).await.unwrap();
    }
    let st = m.stats().await.unwrap();
    assert_eq!(st.clients, n);
    let after = rss_bytes();
    println!(
        "manager holding {n} registered clients         RSS growth {:.1} MiB ({:.1} KiB per client, \
         socket buffers and session tasks included)",
        (after.saturating_sub(before)) as f64 / (1 << 20) as f64,
        (after.saturating_sub(before)) as f64 / 1024.0 / n as f64
    );
    let mut ccfg = PeerNetConfig::loopback("scooter");
    ccfg.heartbeat_ms = 60_000;
    let c = PeerClientHandle::connect(addr, &ccfg, key()).await.unwrap();
    c.register().await.unwrap();
    let mut grant = Vec::new();
    for _ in 0..trips {
        let t = Instant::now();
        let sub = c.request("ses", 1).await.unwrap();
        grant.push(t.elapsed());
        // Dropping the subscription disconnects the source.
        drop(sub);
    }
    report(
        &format!("request -> grant with {n} clients registered"),
        &mut grant,
    );
}

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
            type R = Box<dyn tokio::io::AsyncRead + Unpin + Send>;
            type W = Box<dyn tokio::io::AsyncWrite + Unpin + Send>;
            let pairs: [(R, W); 2] = [(Box::new(ri), Box::new(wo)), (Box::new(ro), Box::new(wi))];
            for (mut r, mut w) in pairs {
                let cut = cut.clone();
                tokio::spawn(async move {
                    let mut buf = vec![0u8; 65536];
                    loop {
                        let n = match r.read(&mut buf).await {
                            Ok(0) | Err(_) => return,
                            Ok(n) => n,
                        };
                        if cut.load(Ordering::SeqCst) {
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

async fn loss_detection(trials: usize) {
    let mut times = Vec::new();
    for _ in 0..trials {
        let cut = Arc::new(AtomicBool::new(false));
        let (req_up, data_up) = (Arc::new(Mutex::new(None)), Arc::new(Mutex::new(None)));
        let req_proxy = proxy(req_up.clone(), cut.clone()).await;
        let data_proxy = proxy(data_up.clone(), cut.clone()).await;
        let mut mc = PeerNetConfig::loopback("skeeter");
        mc.heartbeat_ms = 100;
        mc.manager.data_advertise = Some(data_proxy.to_string());
        let m = spawn_manager(&mc, key(), FixedSelfAgent::default())
            .await
            .unwrap();
        *req_up.lock().unwrap() = Some(m.local_addr());
        *data_up.lock().unwrap() = Some(m.data_addr());
        let p = m.publisher(info("counter")).unwrap();
        let c = PeerClientHandle::connect(req_proxy, &PeerNetConfig::loopback("scooter"), key())
            .await
            .unwrap();
        c.register().await.unwrap();
        let mut sub = c.request("counter", 0).await.unwrap();
        p.publish(1, &[1]).unwrap();
        // Let the session settle into its heartbeat rhythm.
        tokio::time::sleep(Duration::from_millis(250)).await;
        cut.store(true, Ordering::SeqCst);
        let t = Instant::now();
        loop {
            match sub.next().await {
                Some(SubscriptionEvent::Closed { .. }) | None => break,
                _ => {}
            }
        }
        times.push(t.elapsed());
    }
    report(
        "loss detection at 100 ms heartbeat (cut->Closed)",
        &mut times,
    );
}

fn main() {
    let quick = std::env::args().any(|a| a == "--test");
    let rt = rt();
    if !quick {
        println!("# Peer Agent net shell on loopback (2 shared cores; figures are indicative)");
        rt.block_on(round_trips(2000));
        rt.block_on(throughput(64, 2.0));
        rt.block_on(throughput(1024, 2.0));
        rt.block_on(fanout(50, 200));
        rt.block_on(thousand_clients(1000, 500));
        rt.block_on(loss_detection(10));
    }
    drop(rt);
    divan::main();
}

/// Cost of publishing one 64-byte sample to one streaming data session (never blocks).
#[divan::bench(sample_count = 50, sample_size = 1000)]
fn publish_64b(b: divan::Bencher) {
    let rt = rt();
    let (m, p, _c, _sub) = rt.block_on(async {
        let m = spawn_manager(
            &PeerNetConfig::loopback("s"),
            key(),
            FixedSelfAgent::default(),
        )
        .await
        .unwrap();
        let p = m.publisher(info("blob")).unwrap();
        let c = PeerClientHandle::connect(m.local_addr(), &PeerNetConfig::loopback("c"), key())
            .await
            .unwrap();
        c.register().await.unwrap();
        let sub = c.request("blob", 0).await.unwrap();
        while p.subscribers() == 0 {
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        (m, p, c, sub)
    });
    let payload = [7u8; 64];
    b.bench_local(|| black_box(p.publish(1, black_box(&payload))));
    drop(m);
}

/// Registering 1,000 clients on the sans-IO manager core (allocations show its memory).
#[divan::bench(sample_count = 10, sample_size = 1)]
fn core_register_1000(b: divan::Bencher) {
    let k = key();
    let frames: Vec<Vec<u8>> = (0..1000u64)
        .map(|i| {
            Signer::new(k.clone(), 100 + i, 1)
                .seal_vec(&Msg::Register {
                    client: i,
                    robot: format!("robot{i}"),
                })
                .unwrap()
        })
        .collect();
    b.bench_local(|| {
        let now = ima_hal::Instant::from_millis(1);
        let mut m = PeerManager::new(
            ManagerConfig::new("skeeter", 1, "127.0.0.1:1"),
            k.clone(),
            [3; 32],
            FixedSelfAgent::new(0, vec![info("ses")]),
            now,
        );
        let mut buf = vec![0u8; 70_000];
        for (i, f) in frames.iter().enumerate() {
            m.connect(i as u64, now);
            m.handle_frame(i as u64, f, now);
            while m.poll_transmit(&mut buf).is_some() {}
            while m.poll_event().is_some() {}
        }
        black_box(m)
    });
}
