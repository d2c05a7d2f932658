//! A recording read back with the `mcap` crate, and the live view over a WebSocket client.

use std::time::Duration;

use foxglove::Decode;
use futures_util::{SinkExt, StreamExt};
use ima_hal::laser::{BeamFlags, LaserScan};
use ima_record::convert::{Pose2, SesMark};
use ima_record::raw::{Dir, PortInfo};
use ima_record::read::Recording;
use ima_record::{Options, Recorder};
use tokio_tungstenite::tungstenite::Message as WsMessage;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;

fn scan(n: usize) -> LaserScan {
    let mut s = LaserScan::new(-1.0, 0.01);
    for i in 0..n {
        s.push(1.0 + i as f32 * 0.01, BeamFlags::default()).unwrap();
    }
    s
}

fn tmp(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("ima-record-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join(name);
    let _ = std::fs::remove_file(&p);
    p
}

/// A recorder that writes `path`, with a queue of `queue` messages (0: the default).
fn record_to(path: &std::path::Path, queue: usize) -> Recorder {
    Recorder::start(&Options {
        mcap: Some(path.to_owned()),
        name: "test".into(),
        queue,
        ..Options::default()
    })
    .unwrap()
}

/// Two robots' ports at one path (each robot's laptop calls its base `/dev/ttyS0`): the path
/// names the first in file order, `robot/device` and the topic name each; a robot whose name
/// holds a `/` is still named by `robot/device`.
#[test]
fn a_port_path_names_the_first_channel_in_file_order() {
    let path = tmp("one-path.mcap");
    let rec = record_to(&path, 0);
    let port = |robot: &str| PortInfo {
        robot: robot.into(),
        device: "base".into(),
        port: "/dev/ttyS0".into(),
        baud: 9600,
        protocol: "p2os".into(),
        params: Default::default(),
    };
    // Written first, but last by topic.
    let zed = rec.raw_port(port("zed"));
    zed.rx(b"zed");
    let lab = rec.raw_port(port("lab/a"));
    lab.rx(b"lab");
    rec.finish(Duration::from_secs(10));
    let r = Recording::open(&path).unwrap();
    let bytes = |name: &str| r.raw_stream(name).unwrap().rx_bytes();
    assert_eq!(bytes("/dev/ttyS0"), b"zed");
    assert_eq!(bytes("zed/base"), b"zed");
    assert_eq!(bytes("lab/a/base"), b"lab");
    assert_eq!(bytes("/lab/a/serial/base"), b"lab");
    assert!(r.raw_stream("lab/base").is_err());
    assert!(r.raw_stream("lab").is_err());
}

#[test]
fn a_recording_reads_back_with_its_channels_schemas_and_counts() {
    let path = tmp("a.mcap");
    let rec = record_to(&path, 0);
    let port = rec.raw_port(PortInfo {
        robot: "scooter".into(),
        device: "laser".into(),
        port: "/dev/pts/9".into(),
        baud: 9600,
        protocol: "sick-lms".into(),
        params: Default::default(),
    });
    port.tx(b"\x02\x00");
    port.baud(38400);
    port.rx(b"\x06\x02\x80");
    for i in 0..25 {
        rec.log_scan("scooter", &scan(181));
        rec.log_odometry(
            "scooter",
            Pose2 {
                x_m: f64::from(i) * 0.1,
                ..Pose2::default()
            },
        );
    }
    rec.log_ses(
        "skeeter",
        &[SesMark {
            azimuth_rad: 0.5,
            elevation_rad: 0.1,
            tag: "red".into(),
        }],
    );
    rec.log_broadcast("skeeter", "skeeter: found red");
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!(report.dropped, 0);
    assert_eq!(report.error, None);
    assert_eq!(report.written["/scooter/laser/scan"], 25);
    assert_eq!(report.written["/tf"], 25);
    assert!(report.bytes > 0);

    let r = Recording::open(&path).unwrap();
    let ch = r.channels();
    assert_eq!(ch["/scooter/laser/scan"].0, "foxglove.LaserScan");
    assert_eq!(ch["/tf"].0, "foxglove.FrameTransform");
    assert_eq!(ch["/scooter/odom"].0, "foxglove.PoseInFrame");
    assert_eq!(ch["/skeeter/ses"].0, "foxglove.SceneUpdate");
    assert_eq!(ch["/broadcasts"].0, "foxglove.Log");
    assert_eq!(ch["/scooter/serial/laser"].1["protocol"], "sick-lms");
    assert_eq!(ch["/scooter/serial/laser"].1["baud"], "9600");
    let (msgs, cut) = r.messages();
    assert_eq!(cut.0, None);
    let scans: Vec<_> = msgs
        .iter()
        .filter(|m| m.topic == "/scooter/laser/scan")
        .collect();
    assert_eq!(scans.len(), 25);
    let s = foxglove::messages::LaserScan::decode(&scans[0].data[..]).unwrap();
    assert_eq!(s.ranges.len(), 181);
    assert_eq!(s.frame_id, "scooter/laser");
    assert!((s.ranges[10] - 1.1).abs() < 1e-6);
    let raw = r.raw_stream("scooter/laser").unwrap();
    assert_eq!(raw.rx_bytes(), b"\x06\x02\x80");
    let dirs: Vec<Dir> = raw.chunks.iter().map(|c| c.1).collect();
    assert_eq!(dirs, [Dir::Tx, Dir::Baud, Dir::Rx]);
    // Stamps are in order.
    assert!(msgs.windows(2).all(|w| w[0].log_time <= w[1].log_time));
    // The stream by name is the one among all of them, by topic, port or robot/device.
    let all = r.raw_streams();
    assert_eq!(all.iter().find(|s| s.topic == raw.topic), Some(&raw));
    for name in [
        "/scooter/serial/laser",
        "scooter/serial/laser",
        &raw.port.port,
    ] {
        assert_eq!(r.raw_stream(name).unwrap(), raw, "{name}");
    }
    // Chunk by chunk, in file order: the same chunks, per stream in the same order; `false`
    // stops the reading.
    let mut per_topic: std::collections::BTreeMap<String, Vec<_>> = Default::default();
    let cut = r.each_raw_chunk(|c| {
        per_topic.entry(c.topic.to_owned()).or_default().push((
            c.log_time,
            c.dir,
            c.bytes.to_vec(),
        ));
        assert_eq!(
            all.iter().find(|s| s.topic == c.topic).unwrap().port,
            *c.port
        );
        true
    });
    assert_eq!(cut.0, None);
    // Read independently: every raw message, parsed.
    let mut from_messages: std::collections::BTreeMap<String, Vec<_>> = Default::default();
    for m in msgs.iter().filter(|m| m.topic.contains("/serial/")) {
        let c = match ima_record::raw::parse(&m.data).unwrap() {
            ima_record::raw::Chunk::Bytes(d, b) => (m.log_time, d, b.to_vec()),
            ima_record::raw::Chunk::Baud(b) => (m.log_time, Dir::Baud, b.to_le_bytes().to_vec()),
        };
        from_messages.entry(m.topic.clone()).or_default().push(c);
    }
    assert_eq!(per_topic, from_messages);
    let mut seen = 0;
    r.each_raw_chunk(|_| {
        seen += 1;
        false
    });
    assert_eq!(seen, 1);
    // One port's chunks as they are read: exactly that topic's, in file order.
    for name in ["scooter/laser", "/scooter/serial/laser", &raw.port.port] {
        let mut one = Vec::new();
        let cut = r
            .each_chunk_of(name, |c| {
                assert_eq!(c.topic, "/scooter/serial/laser");
                one.push((c.log_time, c.dir, c.bytes.to_vec()));
                true
            })
            .unwrap();
        assert_eq!(cut.0, None);
        assert_eq!(Some(&one), per_topic.get("/scooter/serial/laser"), "{name}");
    }
    let mut seen = 0;
    r.each_chunk_of("scooter/laser", |_| {
        seen += 1;
        false
    })
    .unwrap();
    assert_eq!(seen, 1);
    // Not there: every raw channel named, in topic order.
    let have: Vec<String> = all
        .iter()
        .map(|s| format!("{} ({})", s.topic, s.port.port))
        .collect();
    let have = format!(
        "no raw serial channel nothing in the recording; it has: {}",
        have.join(", ")
    );
    let e = r.raw_stream("nothing").unwrap_err().to_string();
    assert_eq!(e, have);
    let e = r
        .each_chunk_of("nothing", |_| true)
        .unwrap_err()
        .to_string();
    assert_eq!(e, have);
    // Finishing twice gives the same report.
    assert_eq!(rec.finish(Duration::from_secs(1)), report);
}

#[test]
fn a_full_queue_drops_and_counts_instead_of_blocking() {
    let path = tmp("b.mcap");
    let rec = record_to(&path, 4);
    for _ in 0..20_000 {
        rec.log_scan("scooter", &scan(361));
    }
    let report = rec.finish(Duration::from_secs(30));
    assert!(report.dropped > 0, "{report:?}");
    assert_eq!(
        report.written["/scooter/laser/scan"] + report.dropped,
        20_000
    );
    assert!(report.summary().contains("dropped"));
    let (msgs, _) = Recording::open(&path).unwrap().messages();
    assert_eq!(msgs.len() as u64, report.written["/scooter/laser/scan"]);
}

/// The callers' logging time is reported: what `timed` calls take (here a sleep of 20 ms
/// stands for a caller's work), and raw ports' logging besides; untimed logging adds nothing.
#[test]
fn the_callers_logging_time_is_counted() {
    let path = tmp("calls.mcap");
    let rec = record_to(&path, 0);
    rec.log_scan("scooter", &scan(361));
    let untimed = rec.finish(Duration::from_secs(30));
    assert_eq!(untimed.calls_time, Duration::ZERO, "{untimed:?}");

    let path = tmp("calls2.mcap");
    let rec = record_to(&path, 0);
    let got = rec.timed(|r| {
        r.log_scan("scooter", &scan(361));
        std::thread::sleep(Duration::from_millis(20));
        7
    });
    assert_eq!(got, 7);
    let timed = rec.clone().finish(Duration::from_secs(30)).calls_time;
    assert!(timed >= Duration::from_millis(20), "{timed:?}");
    assert!(
        rec.finish(Duration::ZERO)
            .summary()
            .contains("logging calls")
    );

    let path = tmp("calls3.mcap");
    let rec = record_to(&path, 0);
    let port = rec.raw_port(ima_record::raw::PortInfo {
        robot: "scooter".into(),
        device: "base".into(),
        port: "/dev/ttyS0".into(),
        baud: 9600,
        protocol: "p2os".into(),
        params: Default::default(),
    });
    port.rx(&[0xFA, 0xFB, 0x03, 0x00, 0x00, 0x00]);
    port.tx(&[]);
    let r = rec.finish(Duration::from_secs(30));
    assert!(r.calls_time > Duration::ZERO, "{r:?}");
    assert_eq!(r.total(), 1);
}

#[test]
fn a_burst_wakes_the_recorder_before_its_tick() {
    // A file-only recorder drains its queue every 500 ms; 64 places fill after 64 messages.
    // Sent over ~300 ms, 150 messages would lose at least 86 if nothing woke the thread
    // early; a quarter-full queue does.
    let path = tmp("burst.mcap");
    let rec = record_to(&path, 64);
    for _ in 0..150 {
        rec.log_scan("scooter", &scan(181));
        std::thread::sleep(Duration::from_millis(2));
    }
    let report = rec.finish(Duration::from_secs(30));
    assert_eq!(report.written["/scooter/laser/scan"] + report.dropped, 150);
    assert!(report.dropped < 86, "{report:?}");
}

#[test]
fn an_existing_file_is_refused_and_named() {
    let path = tmp("c.mcap");
    std::fs::write(&path, b"x").unwrap();
    let e = Recorder::start(&Options {
        mcap: Some(path.clone()),
        ..Options::default()
    })
    .unwrap_err();
    assert!(e.to_string().contains("c.mcap"), "{e}");
    let e = Recording::open(&path).unwrap_err();
    assert!(e.to_string().contains("not an MCAP file"), "{e}");
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// Connect a Foxglove client to the live view on `port` and read its advertisements until
/// `topic`'s channel is seen; `check` looks at every channel advertised on the way. Returns
/// the connection, the channel's id and whether `serverInfo` came first.
async fn connect_to(
    port: u16,
    topic: &str,
    mut check: impl FnMut(&serde_json::Value),
) -> (Ws, u64, bool) {
    let mut req = format!("ws://127.0.0.1:{port}")
        .into_client_request()
        .unwrap();
    req.headers_mut()
        .insert("sec-websocket-protocol", "foxglove.sdk.v1".parse().unwrap());
    let (mut ws, _) = tokio_tungstenite::connect_async(req).await.unwrap();
    let mut id = None;
    let mut saw_server_info = false;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    while id.is_none() {
        let msg = tokio::time::timeout_at(deadline, ws.next())
            .await
            .expect("an advertisement")
            .unwrap()
            .unwrap();
        let WsMessage::Text(t) = msg else { continue };
        let v: serde_json::Value = serde_json::from_str(&t).unwrap();
        match v["op"].as_str() {
            Some("serverInfo") => saw_server_info = true,
            Some("advertise") => {
                for c in v["channels"].as_array().unwrap() {
                    check(c);
                    if c["topic"] == topic {
                        id = c["id"].as_u64();
                    }
                }
            }
            _ => {}
        }
    }
    (ws, id.unwrap(), saw_server_info)
}

/// Subscribe `ws` to `channel` as subscription `sub`.
async fn subscribe(ws: &mut Ws, sub: u32, channel: u64) {
    let msg = serde_json::json!({"op": "subscribe",
        "subscriptions": [{"id": sub, "channelId": channel}]});
    ws.send(WsMessage::Text(msg.to_string().into()))
        .await
        .unwrap();
}

/// The next message-data payload on `ws` within `wait` (checked to be of subscription
/// `sub`), or `None`.
async fn next_data(ws: &mut Ws, sub: u32, wait: Duration) -> Option<Vec<u8>> {
    let deadline = tokio::time::Instant::now() + wait;
    loop {
        match tokio::time::timeout_at(deadline, ws.next()).await {
            Ok(Some(Ok(WsMessage::Binary(b)))) => {
                // opcode 1 (message data), subscription id, timestamp, payload.
                assert_eq!(b[0], 1);
                assert_eq!(u32::from_le_bytes(b[1..5].try_into().unwrap()), sub);
                return Some(b[13..].to_vec());
            }
            Ok(Some(Ok(_))) => {}
            Err(_) => return None,
            Ok(other) => panic!("connection ended: {other:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_websocket_client_sees_the_channels_and_receives_a_scan() {
    let rec = Recorder::start(&Options {
        foxglove: Some("127.0.0.1:0".parse().unwrap()),
        name: "test".into(),
        ..Options::default()
    })
    .unwrap();
    let port = rec.server_port().unwrap();
    // Channels exist once something was logged on them.
    rec.log_scan("scooter", &scan(181));
    rec.log_broadcast("skeeter", "hello");
    tokio::time::sleep(Duration::from_millis(200)).await;
    let (mut ws, laser, saw_server_info) = connect_to(port, "/scooter/laser/scan", |c| {
        if c["topic"] == "/scooter/laser/scan" {
            assert_eq!(c["schemaName"], "foxglove.LaserScan");
            assert_eq!(c["encoding"], "protobuf");
        }
        assert!(
            !c["topic"].as_str().unwrap().contains("/serial/"),
            "raw channels stay off the live view"
        );
    })
    .await;
    assert!(saw_server_info);
    subscribe(&mut ws, 7, laser).await;
    // Keep logging until a scan arrives.
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    let got = loop {
        rec.log_scan("scooter", &scan(181));
        if let Some(b) = next_data(&mut ws, 7, Duration::from_millis(200)).await {
            break b;
        }
        assert!(tokio::time::Instant::now() < deadline, "no scan arrived");
    };
    let s = foxglove::messages::LaserScan::decode(&got[..]).unwrap();
    assert_eq!(s.ranges.len(), 181);
    let report = rec.finish(Duration::from_secs(5));
    assert_eq!(report.server_port, Some(port));
}

/// A client that subscribes after a topic was logged gets the last message of each of the
/// topic's streams (here two `/tf` pairs, one of them logged twice) at once, oldest first;
/// a later subscriber gets them too, and the first one nothing twice.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_subscriber_gets_the_last_message_of_each_stream() {
    use foxglove::messages::FrameTransform;
    let rec = Recorder::start(&Options {
        foxglove: Some("127.0.0.1:0".parse().unwrap()),
        ..Options::default()
    })
    .unwrap();
    let port = rec.server_port().unwrap();
    let at = |x_m| Pose2 {
        x_m,
        ..Pose2::default()
    };
    rec.log_transform("map", "odom", at(1.0));
    rec.log_transform("map", "odom", at(2.0));
    rec.log_transform("odom", "base_link", at(3.0));
    tokio::time::sleep(Duration::from_millis(200)).await;
    let got = |b: Vec<u8>| {
        let t = FrameTransform::decode(&b[..]).unwrap();
        (t.child_frame_id, t.translation.unwrap().x)
    };
    let (mut first, tf, _) = connect_to(port, "/tf", |_| {}).await;
    subscribe(&mut first, 1, tf).await;
    let wait = Duration::from_secs(10);
    let a = next_data(&mut first, 1, wait)
        .await
        .expect("the first pair");
    let b = next_data(&mut first, 1, wait)
        .await
        .expect("the second pair");
    assert_eq!(got(a), ("odom".to_owned(), 2.0));
    assert_eq!(got(b), ("base_link".to_owned(), 3.0));
    let (mut second, tf2, _) = connect_to(port, "/tf", |_| {}).await;
    assert_eq!(tf, tf2);
    subscribe(&mut second, 9, tf).await;
    let a = next_data(&mut second, 9, wait)
        .await
        .expect("the first pair");
    assert_eq!(got(a), ("odom".to_owned(), 2.0));
    let quiet = Duration::from_millis(500);
    assert_eq!(next_data(&mut first, 1, quiet).await, None, "sent twice");
    // A live message still reaches both.
    rec.log_transform("map", "odom", at(4.0));
    let live = next_data(&mut first, 1, wait)
        .await
        .expect("a live message");
    assert_eq!(got(live), ("odom".to_owned(), 4.0));
    let mut seen = Vec::new();
    while let Some(b) = next_data(&mut second, 9, quiet).await {
        seen.push(got(b));
    }
    assert_eq!(seen.last(), Some(&("odom".to_owned(), 4.0)), "{seen:?}");
    rec.finish(Duration::from_secs(5));
}

/// A log topic keeps its recent lines per name, not only the last: a client that subscribes
/// after the first batch (all logged before anyone could subscribe) gets every line, in
/// order.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_subscriber_gets_the_recent_lines_of_a_log_topic() {
    use foxglove::messages::Log;
    let rec = Recorder::start(&Options {
        foxglove: Some("127.0.0.1:0".parse().unwrap()),
        ..Options::default()
    })
    .unwrap();
    let port = rec.server_port().unwrap();
    let lines = [
        "commander: waiting",
        "scooter: connected",
        "commander: red sent",
    ];
    for l in lines {
        let (name, text) = l.split_once(": ").unwrap();
        rec.log_text("/events", foxglove::messages::log::Level::Info, name, text);
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let (mut ws, events, _) = connect_to(port, "/events", |_| {}).await;
    subscribe(&mut ws, 2, events).await;
    for l in lines {
        let b = next_data(&mut ws, 2, Duration::from_secs(10))
            .await
            .expect(l);
        let m = Log::decode(&b[..]).unwrap();
        assert_eq!(format!("{}: {}", m.name, m.message), l);
    }
    rec.finish(Duration::from_secs(5));
}

#[test]
fn camera_frames_count_against_the_byte_budget_and_every_message_is_accounted_for() {
    let path = tmp("d.mcap");
    let rec = record_to(&path, 0);
    let frame = ima_hal::camera::Frame::black(320, 240, Some(2)).unwrap();
    for _ in 0..400 {
        rec.log_image("skeeter", &frame);
    }
    let report = rec.finish(Duration::from_secs(60));
    assert_eq!(
        report
            .written
            .get("/skeeter/camera/2")
            .copied()
            .unwrap_or(0)
            + report.dropped,
        400
    );
    let (msgs, _) = Recording::open(&path).unwrap().messages();
    let img = msgs
        .iter()
        .find(|m| m.topic == "/skeeter/camera/2")
        .unwrap();
    assert_eq!(img.schema, "foxglove.RawImage");
    let f = foxglove::messages::RawImage::decode(&img.data[..]).unwrap();
    assert_eq!(
        (f.width, f.height, f.step, f.encoding.as_str()),
        (320, 240, 960, "rgb8")
    );
    assert_eq!(f.data.len(), 320 * 240 * 3);
}

/// Every recorded frame is exactly the frame logged (the `RawImage` that
/// `convert::raw_image` builds), whatever the frames before it were: a smaller frame after a
/// larger one, an empty one (guards any reuse of frame buffers).
#[test]
fn frames_in_reused_buffers_are_recorded_exactly() {
    use ima_hal::camera::Frame;
    let path = tmp("frames.mcap");
    let rec = record_to(&path, 0);
    let frame = |w: u32, h: u32, seed: u8| {
        let mut f = Frame::black(w, h, Some(3)).unwrap();
        for (i, p) in f.pixels.iter_mut().enumerate() {
            *p = (i as u8).wrapping_mul(31).wrapping_add(seed);
        }
        f
    };
    let frames: Vec<Frame> = (0..24u8)
        .map(|k| match k % 3 {
            0 => frame(320, 240, k),
            1 => frame(16, 8, k),
            _ => frame(0, 0, k),
        })
        .collect();
    for (k, f) in frames.iter().enumerate() {
        rec.log_image("skeeter", f);
        if k % 5 == 4 {
            // Let the recorder write between bursts.
            std::thread::sleep(Duration::from_millis(600));
        }
    }
    let report = rec.finish(Duration::from_secs(30));
    assert_eq!(report.dropped, 0);
    let (msgs, _) = Recording::open(&path).unwrap().messages();
    let got: Vec<foxglove::messages::RawImage> = msgs
        .iter()
        .filter(|m| m.topic == "/skeeter/camera/3")
        .map(|m| foxglove::messages::RawImage::decode(&m.data[..]).unwrap())
        .collect();
    assert_eq!(got.len(), frames.len());
    for (g, f) in got.iter().zip(&frames) {
        // Each camera's own optical frame.
        let want = ima_record::convert::raw_image("skeeter/camera/3", 0, f);
        assert_eq!(
            (&g.frame_id, g.width, g.height, &g.encoding, g.step),
            (
                &want.frame_id,
                want.width,
                want.height,
                &want.encoding,
                want.step
            )
        );
        assert_eq!(g.data, want.data, "{}×{} frame", f.width, f.height);
        assert!(g.timestamp.is_some());
    }
}

/// Structured state (the SAN, the Peer Agents) goes on JSON channels with a JSON Schema.
#[test]
fn json_messages_get_a_json_channel_with_their_schema() {
    let path = tmp("json.mcap");
    let rec = record_to(&path, 0);
    let schema = serde_json::json!({"type": "object", "properties": {"n": {"type": "integer"}}});
    for n in 0..3 {
        rec.log_json(
            "/state",
            "test.State",
            || schema.clone(),
            &serde_json::json!({"n": n}),
        );
    }
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!(report.written["/state"], 3);
    let bytes = std::fs::read(&path).unwrap();
    let mut seen = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        assert_eq!(m.channel.message_encoding, "json");
        let s = m.channel.schema.as_ref().unwrap();
        assert_eq!(
            (s.name.as_str(), s.encoding.as_str()),
            ("test.State", "jsonschema")
        );
        let sv: serde_json::Value = serde_json::from_slice(&s.data).unwrap();
        assert_eq!(sv, schema);
        let v: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        seen.push(v["n"].as_u64().unwrap());
    }
    assert_eq!(seen, [0, 1, 2]);
}

/// A sonar scan becomes a point cloud in `base_link`: one point per echo, on its beam.
#[test]
fn a_sonar_scan_is_a_point_cloud_of_its_echoes() {
    use ima_hal::sonar::{SonarReading, SonarScan, SonarTransducer};
    let t = |x: f64, angle: f64| SonarTransducer {
        pose: ima_hal::Isometry2::new(ima_hal::nalgebra::Vector2::new(x, 0.0), angle),
        min_range_m: 0.1,
        max_range_m: 5.0,
        beam_width_rad: 0.26,
    };
    let transducers = [
        t(0.1, 0.0),
        t(0.0, std::f64::consts::FRAC_PI_2),
        t(0.0, 0.0),
    ];
    let mut scan = SonarScan::default();
    for (index, range_m) in [(0, 1.5), (1, 2.0), (2, 5.0), (9, 1.0)] {
        scan.upsert(SonarReading {
            index,
            range_m,
            at: ima_hal::Instant::ZERO,
        });
    }
    let c = ima_record::convert::sonar_cloud("scooter/base_link", 1, &transducers, &scan);
    assert_eq!(c.frame_id, "scooter/base_link");
    let names: Vec<_> = c.fields.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["x", "y", "z", "range"]);
    // Transducer 2 heard no echo (max range), 9 does not exist: two points.
    let pts: Vec<[f32; 4]> = c
        .data
        .chunks(c.point_stride as usize)
        .map(|p| {
            std::array::from_fn(|i| f32::from_le_bytes(p[i * 4..i * 4 + 4].try_into().unwrap()))
        })
        .collect();
    assert_eq!(pts.len(), 2);
    let near = |a: [f32; 4], b: [f32; 4]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5);
    assert!(near(pts[0], [1.6, 0.0, 0.0, 1.5]), "{pts:?}");
    assert!(near(pts[1], [0.0, 2.0, 0.0, 2.0]), "{pts:?}");
}

/// `Images::Png`: frames go out as PNG `foxglove.CompressedImage` that decodes to the
/// same pixels.
#[test]
fn png_frames_decode_to_the_same_pixels() {
    let path = tmp("png.mcap");
    let rec = Recorder::start(&Options {
        mcap: Some(path.clone()),
        images: ima_record::Images::Png,
        ..Options::default()
    })
    .unwrap();
    let mut frame = ima_hal::camera::Frame::black(64, 48, Some(3)).unwrap();
    for (i, p) in frame.pixels.iter_mut().enumerate() {
        *p = (i * 7 % 251) as u8;
    }
    rec.log_image("skeeter", &frame);
    // Pixels that do not make the frame: not an empty image, a count.
    let mut short = frame.clone();
    short.pixels.truncate(100);
    rec.log_image("skeeter", &short);
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!(report.written["/skeeter/camera/3"], 1);
    assert_eq!((report.dropped, report.unwritten), (0, 1));
    let (msgs, _) = Recording::open(&path).unwrap().messages();
    assert_eq!(msgs[0].schema, "foxglove.CompressedImage");
    let img = foxglove::messages::CompressedImage::decode(&msgs[0].data[..]).unwrap();
    assert_eq!(
        (img.format.as_str(), img.frame_id.as_str()),
        ("png", "skeeter/camera/3")
    );
    let mut reader = png::Decoder::new(std::io::Cursor::new(&img.data[..]))
        .read_info()
        .unwrap();
    let mut pixels = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut pixels).unwrap();
    assert_eq!((info.width, info.height), (64, 48));
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(&pixels[..info.buffer_size()], &frame.pixels[..]);
    // Pixels that do not make the frame's size are refused, however large the size.
    use ima_record::convert::png;
    assert!(png(2, 2, &[0; 12]).is_some());
    assert_eq!(png(2, 2, &[0; 11]), None);
    assert_eq!(png(u32::MAX, u32::MAX, &[0; 3]), None);
    assert_eq!(png(0, 0, &[]), None);
}

fn test_frame() -> ima_hal::camera::Frame {
    ima_hal::camera::Frame::black(32, 24, Some(3)).unwrap()
}

fn exclude(patterns: &[&str]) -> ima_record::filter::TopicFilter {
    ima_record::filter::TopicFilter::new(patterns.iter().map(|p| p.parse().unwrap()).collect())
}

/// `Options::exclude`: left-out topics (here the cameras and one raw port) are not in the file,
/// not counted as written or dropped, and named in the report and the file's metadata; the
/// rest is recorded as usual.
#[test]
fn excluded_topics_stay_out_of_the_file() {
    let path = tmp("exclude.mcap");
    let rec = Recorder::start(&Options {
        mcap: Some(path.clone()),
        exclude: exclude(&["/*/camera", "/scooter/serial/laser"]),
        ..Options::default()
    })
    .unwrap();
    assert!(!rec.wants("/skeeter/camera/3"));
    assert!(rec.wants("/scooter/laser/scan"));
    let port = |device: &str| PortInfo {
        robot: "scooter".into(),
        device: device.into(),
        port: format!("/dev/pts/{device}"),
        baud: 9600,
        protocol: "test".into(),
        params: Default::default(),
    };
    let laser = rec.raw_port(port("laser"));
    let base = rec.raw_port(port("base"));
    for _ in 0..5 {
        rec.log_image("skeeter", &test_frame());
        rec.log_scan("scooter", &scan(181));
        laser.rx(b"\x06");
        base.rx(b"\xfa\xfb");
    }
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!(report.dropped, 0);
    assert_eq!(report.written["/scooter/laser/scan"], 5);
    assert_eq!(report.written["/scooter/serial/base"], 5);
    assert!(
        !report.written.keys().any(|t| t.contains("camera")),
        "{report:?}"
    );
    assert!(!report.written.contains_key("/scooter/serial/laser"));
    assert!(
        report
            .summary()
            .contains("(left out: /*/camera, /scooter/serial/laser)"),
        "{}",
        report.summary()
    );

    let r = Recording::open(&path).unwrap();
    let ch = r.channels();
    assert!(ch.contains_key("/scooter/laser/scan"));
    assert!(ch.contains_key("/scooter/serial/base"));
    assert!(
        !ch.keys()
            .any(|t| t.contains("camera") || t.ends_with("laser"))
    );
    assert_eq!(r.messages().0.len(), 10);
    let meta = r.ima_metadata().unwrap();
    assert_eq!(meta["exclude"], "/*/camera, /scooter/serial/laser");
    let e = r.raw_stream("scooter/laser").unwrap_err().to_string();
    assert!(
        e.ends_with("(the recording left out: /*/camera, /scooter/serial/laser)"),
        "{e}"
    );
}

/// With a live view, a topic left out of the file is still built and served: only the file
/// goes without it.
#[test]
fn a_live_view_still_gets_what_the_file_leaves_out() {
    let path = tmp("exclude-live.mcap");
    let rec = Recorder::start(&Options {
        mcap: Some(path.clone()),
        foxglove: Some("127.0.0.1:0".parse().unwrap()),
        exclude: exclude(&["/*/camera"]),
        ..Options::default()
    })
    .unwrap();
    assert!(rec.wants("/skeeter/camera/3"));
    rec.log_image("skeeter", &test_frame());
    rec.log_scan("scooter", &scan(181));
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!(report.dropped, 0);
    assert_eq!(report.written.len(), 1, "{report:?}");
    let ch = Recording::open(&path).unwrap().channels();
    assert_eq!(ch.keys().collect::<Vec<_>>(), ["/scooter/laser/scan"]);
}

/// A live view alone does not take raw serial bytes (it never serves them): they are not
/// built, and the end line's count of messages published leaves them out (it counted 2,587
/// rFLEX chunks a viewer never got).
#[test]
fn a_live_view_alone_takes_no_raw_bytes() {
    let rec = Recorder::start(&Options {
        foxglove: Some("127.0.0.1:0".parse().unwrap()),
        ..Options::default()
    })
    .unwrap();
    assert!(!rec.wants("/scooter/serial/base"));
    assert!(rec.wants("/scooter/laser/scan"));
    let port = rec.raw_port(PortInfo {
        robot: "scooter".into(),
        device: "base".into(),
        port: "/dev/pts/9".into(),
        baud: 115_200,
        protocol: "rflex".into(),
        params: Default::default(),
    });
    port.rx(b"\x1b\x02");
    rec.log_scan("scooter", &scan(181));
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!(
        report.written.keys().collect::<Vec<_>>(),
        ["/scooter/laser/scan"],
        "{report:?}"
    );
    assert!(
        report.summary().starts_with("published 1 messages"),
        "{}",
        report.summary()
    );
}

/// A camera's mount: its optical frame under `base_link` (z along the lens, x to the image's
/// right, y down), and a pinhole calibration from its field of view.
#[test]
fn a_camera_mount_places_its_optical_frame_and_calibration() {
    use foxglove::messages::{CameraCalibration, FrameTransform};
    let path = tmp("mount.mcap");
    let rec = record_to(&path, 0);
    let mount = ima_record::convert::CameraMount {
        channel: Some(3),
        yaw_rad: std::f64::consts::FRAC_PI_2,
        hfov_rad: 60f64.to_radians(),
        width: 320,
        height: 240,
    };
    rec.log_camera_mount("skeeter", &mount);
    rec.finish(Duration::from_secs(10));
    let (msgs, _) = Recording::open(&path).unwrap().messages();
    let tf = msgs.iter().find(|m| m.topic == "/tf").unwrap();
    let tf = FrameTransform::decode(&tf.data[..]).unwrap();
    assert_eq!(
        (tf.parent_frame_id.as_str(), tf.child_frame_id.as_str()),
        ("skeeter/base_link", "skeeter/camera/3")
    );
    // Rotate the optical axes into base_link with the transform's quaternion.
    let q = tf.rotation.unwrap();
    let rot = |v: [f64; 3]| {
        let (x, y, z, w) = (q.x, q.y, q.z, q.w);
        let t = [
            2.0 * (y * v[2] - z * v[1]),
            2.0 * (z * v[0] - x * v[2]),
            2.0 * (x * v[1] - y * v[0]),
        ];
        [
            v[0] + w * t[0] + (y * t[2] - z * t[1]),
            v[1] + w * t[1] + (z * t[0] - x * t[2]),
            v[2] + w * t[2] + (x * t[1] - y * t[0]),
        ]
    };
    let near = |a: [f64; 3], b: [f64; 3]| a.iter().zip(b).all(|(a, b)| (a - b).abs() < 1e-12);
    // Looking left (yaw 90°): the lens (optical z) along +y, the image's right (optical x)
    // towards the robot's front (+x), the image's down (optical y) down (−z).
    assert!(
        near(rot([0.0, 0.0, 1.0]), [0.0, 1.0, 0.0]),
        "{:?}",
        rot([0.0, 0.0, 1.0])
    );
    assert!(
        near(rot([1.0, 0.0, 0.0]), [1.0, 0.0, 0.0]),
        "{:?}",
        rot([1.0, 0.0, 0.0])
    );
    assert!(
        near(rot([0.0, 1.0, 0.0]), [0.0, 0.0, -1.0]),
        "{:?}",
        rot([0.0, 1.0, 0.0])
    );
    let cal = msgs
        .iter()
        .find(|m| m.topic == "/skeeter/camera/3/calibration")
        .unwrap();
    let cal = CameraCalibration::decode(&cal.data[..]).unwrap();
    assert_eq!(
        (cal.frame_id.as_str(), cal.width, cal.height),
        ("skeeter/camera/3", 320, 240)
    );
    // 60° across 320 pixels: f = 160 / tan 30°.
    let f = 160.0 / 30f64.to_radians().tan();
    assert!(
        (cal.k[0] - f).abs() < 1e-9 && (cal.k[4] - f).abs() < 1e-9,
        "{:?}",
        cal.k
    );
    assert_eq!((cal.k[2], cal.k[5]), (160.0, 120.0));
    // A field of view no pinhole has: no calibration (its focal length would be negative).
    let wide = ima_record::convert::CameraMount {
        hfov_rad: 200f64.to_radians(),
        ..mount
    };
    assert!(wide.calibration("skeeter", 0).is_none());
}

/// Each message the recorder's thread fills in from a compact record is exactly the message
/// the `convert` builders make from the same reading, stamped with its log time.
#[test]
fn every_reading_is_recorded_as_its_convert_message() {
    use foxglove::messages::{FrameTransform, LaserScan as FxScan, Log, PointCloud, PoseInFrame};
    use ima_hal::sonar::{SonarReading, SonarScan, SonarTransducer};
    use ima_record::convert;
    let path = tmp("kinds.mcap");
    let rec = record_to(&path, 0);
    let s = scan(181);
    let p = Pose2 {
        x_m: 1.5,
        y_m: -0.25,
        theta_rad: 2.0,
    };
    let transducers: Vec<SonarTransducer> = (0..3)
        .map(|i| SonarTransducer {
            pose: ima_hal::Isometry2::new(ima_hal::Vector2::new(0.1, 0.0), f64::from(i)),
            min_range_m: 0.1,
            max_range_m: 5.0,
            beam_width_rad: 0.4,
        })
        .collect();
    let mut sonar = SonarScan::default();
    for (i, r) in [1.0, 5.0, 2.5].into_iter().enumerate() {
        sonar
            .readings
            .push(SonarReading {
                index: i as u8,
                range_m: r,
                at: ima_hal::Instant::ZERO,
            })
            .unwrap();
    }
    rec.log_scan("scooter", &s);
    rec.log_odometry("scooter", p);
    // Scooter's odometry frame 2 m east and 1 m north of the map's origin.
    let origin = Pose2 {
        x_m: 2.0,
        y_m: 1.0,
        theta_rad: 0.0,
    };
    rec.log_odom_origin("scooter", origin);
    rec.log_ground_truth("skeeter", p);
    rec.log_compass("scooter", 0.75);
    rec.log_sonar("skeeter", &transducers, &sonar);
    rec.log_pose("/scooter/belief", "map", p);
    rec.log_text(
        "/events",
        ima_record::messages::log::Level::Warning,
        "skeeter",
        "scan {\"seen\":[\"red\"]}",
    );
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!((report.dropped, report.total()), (0, 9));
    let (msgs, _) = Recording::open(&path).unwrap().messages();
    let on = |topic: &str| {
        let m: Vec<_> = msgs.iter().filter(|m| m.topic == topic).collect();
        m
    };
    let one = |topic: &str| {
        let m = on(topic);
        assert_eq!(m.len(), 1, "{topic}");
        (m[0].log_time, m[0].data.clone())
    };
    let (t, d) = one("/scooter/laser/scan");
    assert_eq!(
        FxScan::decode(&d[..]).unwrap(),
        convert::laser_scan("scooter/laser", t, &s)
    );
    let tf: Vec<FrameTransform> = on("/tf")
        .iter()
        .map(|m| FrameTransform::decode(&m.data[..]).unwrap())
        .collect();
    let tf_t: Vec<u64> = on("/tf").iter().map(|m| m.log_time).collect();
    assert_eq!(
        tf_t[0],
        one("/scooter/odom").0,
        "odometry's transform and pose share one stamp"
    );
    assert_eq!(
        tf,
        [
            convert::transform("scooter/odom", "scooter/base_link", tf_t[0], p),
            convert::transform("map", "scooter/odom", tf_t[1], origin)
        ]
    );
    for (topic, frame, pose) in [
        ("/scooter/odom", "scooter/odom", p),
        ("/skeeter/truth", "map", p),
        ("/scooter/belief", "map", p),
        // Where the robot is (odometry from the odometry frame's origin), turned to the
        // heading: it was drawn at the map's origin.
        (
            "/scooter/compass",
            "map",
            Pose2 {
                x_m: 3.5,
                y_m: 0.75,
                theta_rad: 0.75,
            },
        ),
    ] {
        let (t, d) = one(topic);
        assert_eq!(
            PoseInFrame::decode(&d[..]).unwrap(),
            convert::pose_in_frame(frame, t, pose),
            "{topic}"
        );
    }
    let (t, d) = one("/skeeter/sonar");
    let cloud = PointCloud::decode(&d[..]).unwrap();
    assert_eq!(
        cloud,
        convert::sonar_cloud("skeeter/base_link", t, &transducers, &sonar)
    );
    assert_eq!(cloud.data.len(), 2 * 16, "the 5 m reading is no echo");
    let (t, d) = one("/events");
    assert_eq!(
        Log::decode(&d[..]).unwrap(),
        convert::log_line(
            t,
            ima_record::messages::log::Level::Warning,
            "skeeter",
            "scan {\"seen\":[\"red\"]}"
        )
    );
}

/// A value whose `Serialize` fails is counted as not written (not as dropped for a full
/// queue), leaves nothing half-written in the queue, and the messages around it go on.
#[test]
fn a_value_that_cannot_be_serialised_is_counted_and_the_rest_goes_on() {
    struct Broken;
    impl serde::Serialize for Broken {
        fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
            use serde::ser::{Error, SerializeMap};
            let mut m = s.serialize_map(None)?;
            m.serialize_entry("half", &1)?;
            Err(S::Error::custom("cannot"))
        }
    }
    let path = tmp("broken.mcap");
    let rec = record_to(&path, 0);
    let schema = || serde_json::json!({"type": "object"});
    rec.log_json("/state", "test.State", schema, &serde_json::json!({"n": 1}));
    rec.log_json("/state", "test.State", schema, &Broken);
    rec.log_json("/state", "test.State", schema, &serde_json::json!({"n": 2}));
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!((report.dropped, report.unwritten), (0, 1));
    assert_eq!(report.written["/state"], 2);
    assert!(
        report.summary().contains("1 could not be encoded"),
        "{}",
        report.summary()
    );
    let (msgs, _) = Recording::open(&path).unwrap().messages();
    let got: Vec<serde_json::Value> = msgs
        .iter()
        .filter(|m| m.topic == "/state")
        .map(|m| serde_json::from_slice(&m.data).unwrap())
        .collect();
    assert_eq!(
        got,
        [serde_json::json!({"n": 1}), serde_json::json!({"n": 2})]
    );
}

/// What is logged once the recording has finished is not left in a queue nobody reads: it
/// is counted as dropped.
#[test]
fn what_is_logged_after_the_end_is_counted_as_dropped() {
    let path = tmp("late.mcap");
    let rec = record_to(&path, 0);
    rec.log_scan("scooter", &scan(10));
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!((report.total(), report.dropped), (1, 0));
    rec.log_scan("scooter", &scan(10));
    rec.log_broadcast("skeeter", "late");
    assert_eq!(rec.dropped(), 2);
    assert_eq!(rec.finish(Duration::from_secs(1)), report);
}

/// A stream's first message runs its schema closure outside the recorder's lock: a closure
/// that logs (or takes long) holds up no other thread.
#[test]
fn a_schema_closure_may_log_itself() {
    let path = tmp("nested.mcap");
    let rec = record_to(&path, 0);
    let (tx, rx) = std::sync::mpsc::channel();
    let r = rec.clone();
    std::thread::spawn(move || {
        r.log_json(
            "/state",
            "test.State",
            || {
                r.log_broadcast("skeeter", "from inside the schema");
                serde_json::json!({"type": "object"})
            },
            &serde_json::json!({"n": 1}),
        );
        let _ = tx.send(());
    });
    rx.recv_timeout(Duration::from_secs(10))
        .expect("log_json returned");
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!(report.written["/state"], 1);
    assert_eq!(report.written["/broadcasts"], 1);
}

/// Streams are told apart by every part of their key, whatever characters the parts hold.
#[test]
fn streams_with_look_alike_keys_stay_apart() {
    let path = tmp("keys.mcap");
    let rec = record_to(&path, 0);
    let p = Pose2::default();
    rec.log_pose("/x\u{1f}y", "f", p);
    rec.log_pose("/x", "y\u{1f}f", p);
    rec.log_transform("a:1", "b", p);
    rec.log_transform("a", "1:b", p);
    let report = rec.finish(Duration::from_secs(10));
    assert_eq!(report.written["/x\u{1f}y"], 1);
    assert_eq!(report.written["/x"], 1);
    let (msgs, _) = Recording::open(&path).unwrap().messages();
    let frames: Vec<String> = msgs
        .iter()
        .filter(|m| m.topic == "/x" || m.topic == "/x\u{1f}y")
        .map(|m| {
            foxglove::messages::PoseInFrame::decode(&m.data[..])
                .unwrap()
                .frame_id
        })
        .collect();
    assert_eq!(frames.len(), 2);
    assert!(frames.contains(&"f".to_owned()) && frames.contains(&"y\u{1f}f".to_owned()));
    let parents: Vec<String> = msgs
        .iter()
        .filter(|m| m.topic == "/tf")
        .map(|m| {
            let t = foxglove::messages::FrameTransform::decode(&m.data[..]).unwrap();
            format!("{}>{}", t.parent_frame_id, t.child_frame_id)
        })
        .collect();
    assert_eq!(parents, ["a:1>b", "a>1:b"]);
}
