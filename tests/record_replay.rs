//! Issue 16: `ima demo --record` read back with the `mcap` crate's reader (channels, schemas,
//! counts against the demo's own report), `ima replay` re-decoding the raw bytes into the
//! same scans message by message (and a recording of the replay into the same again), and a
//! recording cut short by SIGKILL still readable.

mod common;
use std::collections::BTreeMap;

use common::{ima, json_lines};
use ima_record::Decode;
use ima_record::read::Recording;

/// A scratch directory for one test (removed at its end unless it failed).
fn scratch(test: &str) -> common::Scratch {
    common::Scratch::new(&format!("record-replay-{test}"))
}

/// Every `recorded` item is among the `replayed` ones, in order (a replay also has what came
/// before the stack read it).
fn in_order<T: std::fmt::Debug>(
    what: &str,
    recorded: &[T],
    replayed: &[T],
    same: impl Fn(&T, &T) -> bool,
) {
    let mut next = 0;
    for (i, r) in recorded.iter().enumerate() {
        let at = replayed
            .get(next..)
            .unwrap_or_default()
            .iter()
            .position(|x| same(r, x))
            .unwrap_or_else(|| panic!("recorded {what} {i} {r:?} is not among the replayed ones"));
        next += at + 1;
    }
}

/// `ima replay --speed 0 --json FILE`: its output, and its stderr as text.
fn replay_json(file: &std::path::Path) -> (std::process::Output, String) {
    let out = ima()
        .args(["replay", "--speed", "0", "--json"])
        .arg(file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    (out, err)
}

/// `ima demo --json` at ×10 for the red target with `extra` arguments, recorded to
/// `NAME.mcap` (the trajectory to `NAME.svg`): its output, its summary line and the file.
fn recorded_demo(
    dir: &std::path::Path,
    name: &str,
    extra: &[&str],
) -> (std::process::Output, serde_json::Value, std::path::PathBuf) {
    let file = dir.join(format!("{name}.mcap"));
    let out = ima()
        .args(common::SHORT_DEMO)
        .args(extra)
        .arg("--svg")
        .arg(dir.join(format!("{name}.svg")))
        .arg("--record")
        .arg(&file)
        .output()
        .unwrap();
    let summary = common::demo_summary(&out);
    (out, summary, file)
}

#[test]
fn a_recorded_demo_reads_back_and_replays_into_the_same_scans() {
    let dir = scratch("demo");
    let (out, summary, file) = recorded_demo(&dir, "demo", &[]);
    assert!(out.status.success(), "{summary}");
    let written: BTreeMap<String, u64> =
        serde_json::from_value(summary["recording"]["written"].clone()).unwrap();
    assert_eq!(summary["recording"]["dropped"], 0, "{summary}");
    assert_eq!(summary["recording"]["unwritten"], 0, "{summary}");

    let rec = Recording::open(&file).unwrap();
    let (msgs, cut) = rec.messages();
    assert_eq!(cut.0, None, "a finished recording reads to its end");
    // Counts per topic match the demo's report.
    let mut counted: BTreeMap<String, u64> = BTreeMap::new();
    for m in &msgs {
        *counted.entry(m.topic.clone()).or_default() += 1;
    }
    assert_eq!(counted, written);
    // … and the drivers' own counters (the pipeline is lossless: nothing was dropped).
    let drivers = &summary["drivers"];
    let count = |robot: &str, key: &str| {
        drivers[robot][key]
            .as_u64()
            .unwrap_or_else(|| panic!("drivers.{robot}.{key}: {drivers}"))
    };
    assert_eq!(
        written["/scooter/laser/scan"],
        count("scooter", "laser_scans_read"),
        "every scan the runtime read is recorded once"
    );
    assert!(count("scooter", "laser_scans_read") <= count("scooter", "laser_scans"));
    let images = msgs
        .iter()
        .filter(|m| m.topic.starts_with("/skeeter/camera/") && m.schema.ends_with("Image"))
        .count() as u64;
    assert_eq!(images, count("skeeter", "camera_frames"));
    // Each with its camera's calibration.
    let calibrations = msgs
        .iter()
        .filter(|m| m.topic.ends_with("/calibration"))
        .count() as u64;
    assert_eq!(calibrations, images);
    assert!(images > 0);
    // Re-decoding each raw channel gives exactly what its driver decoded.
    let kinds = |port: &str| {
        let out = ima()
            .args(["decode", "--port", port, "--mcap"])
            .arg(&file)
            .output()
            .unwrap();
        assert!(out.status.success(), "{port}");
        let mut k: BTreeMap<String, u64> = BTreeMap::new();
        for l in json_lines(&out.stdout) {
            *k.entry(l["kind"].as_str().unwrap().to_owned()).or_default() += 1;
        }
        k
    };
    // Exact when the driver's framer lost nothing; a partial frame it abandoned after a gap
    // in the bytes (a loaded machine) may still decode whole from the recording, so then up
    // to that many more. `closing`: packets that arrive while the driver closes its session
    // (recorded, no longer decoded by it).
    let within = |what: &str, decoded: u64, counted: u64, lost: u64, closing: u64| {
        assert!(
            counted <= decoded && decoded <= counted + lost + closing,
            "{what}: {decoded} re-decoded, the driver counted {counted} (lost {lost}): {drivers}"
        );
    };
    let frames = |k: &BTreeMap<String, u64>| {
        k.iter()
            .filter(|(k, _)| !matches!(k.as_str(), "error" | "ack"))
            .map(|(_, n)| n)
            .sum::<u64>()
    };
    let laser = kinds("scooter/laser");
    let lost = count("scooter", "laser_framer_drops");
    within(
        "scans",
        laser["scan"],
        count("scooter", "laser_scans"),
        lost,
        0,
    );
    let base = kinds("scooter/base");
    assert_eq!(drivers["scooter"]["base"], "rflex");
    let lost = count("scooter", "base_framer_drops");
    // rFLEX acks are frames too.
    let all = frames(&base) + base.get("ack").copied().unwrap_or(0);
    within(
        "rFLEX frames",
        all,
        count("scooter", "base_frames"),
        lost,
        0,
    );
    assert!(base["motion"] > 0);
    let base = kinds("skeeter/base");
    let lost = count("skeeter", "base_framer_drops");
    within(
        "P2OS frames",
        frames(&base),
        count("skeeter", "base_frames"),
        lost,
        0,
    );
    within("SIPs", base["sip"], count("skeeter", "base_sips"), lost, 2);

    // The SAN's and the Peer Agents' state as JSON topics with the expected fields.
    let json_of = |topic: &str| -> Vec<serde_json::Value> {
        msgs.iter()
            .filter(|m| m.topic == topic)
            .map(|m| serde_json::from_slice(&m.data).unwrap())
            .collect()
    };
    for robot in ["skeeter", "scooter"] {
        let san = json_of(&format!("/san/{robot}"));
        assert!(!san.is_empty(), "/san/{robot}");
        for v in &san {
            assert_eq!(v["robot"], robot);
            let modules = v["modules"].as_array().unwrap();
            assert!(!modules.is_empty(), "{v}");
            for m in modules {
                let name = m["name"].as_str().unwrap();
                let key = name.replace('-', "_");
                assert_eq!(v["activation"][&key], m["activation"], "{v}");
                assert_eq!(v["executable"][&key], m["executable"], "{v}");
                assert!(m["executable"].is_boolean(), "{v}");
            }
            assert!(
                v["selected"].is_string() && v["threshold"].is_number(),
                "{v}"
            );
        }
        let peer = json_of(&format!("/peer/{robot}/status"));
        assert!(!peer.is_empty(), "/peer/{robot}/status");
        assert!(
            peer.iter()
                .all(|v| v["robot"] == robot && v["broadcast"]["sent"].is_u64())
        );
    }
    // Skeeter's manager lists its `ses` source and, once granted, Scooter's grant of it.
    let skeeter = json_of("/peer/skeeter/status");
    assert!(skeeter.iter().all(|v| {
        v["sources"]
            .as_array()
            .unwrap()
            .iter()
            .any(|s| s["name"] == "ses")
    }));
    assert!(
        skeeter.iter().any(|v| v["clients"]
            .as_array()
            .unwrap()
            .iter()
            .any(|c| c["robot"] == "scooter" && c["granted"][0] == "ses")),
        "{:?}",
        skeeter.last()
    );
    // Link health: Skeeter's manager's links, Scooter's own client of Skeeter's `ses`.
    assert!(skeeter.last().unwrap()["links"].is_array());
    let scooter = json_of("/peer/scooter/status");
    assert!(
        scooter.iter().any(|v| v["client"]["source"] == "ses"),
        "{:?}",
        scooter.last()
    );
    assert!(!json_of("/commander/queue").is_empty());
    // Every message of a JSON topic fits its channel's schema (a null where the schema said
    // "number" failed a JSON Schema validator; Foxglove's panels read the schema).
    let schemas = rec.json_schemas();
    assert!(schemas.len() >= 6, "{:?}", schemas.keys());
    for (topic, schema) in &schemas {
        assert!(schema.is_object(), "{topic}: its schema does not parse");
        for v in json_of(topic) {
            if let Err(at) = fits(&v, schema, topic) {
                panic!("{at}: {v}");
            }
        }
    }

    // Channels and schemas.
    let ch = rec.channels();
    let schema = |t: &str| ch.get(t).map(|c| c.0.as_str()).unwrap_or("(none)");
    assert_eq!(schema("/scooter/laser/scan"), "foxglove.LaserScan");
    assert_eq!(schema("/tf"), "foxglove.FrameTransform");
    assert_eq!(schema("/skeeter/ses"), "foxglove.SceneUpdate");
    assert_eq!(schema("/broadcasts"), "foxglove.Log");
    assert_eq!(schema("/scooter/truth"), "foxglove.PoseInFrame");
    // Scooter's belief is in `map` where its truth is (it was measured from its start, 4 m
    // off the robot in the 3D view): its first one, at the start, within 0.3 m of the truth.
    let first_pose = |topic: &str| {
        let m = msgs.iter().find(|m| m.topic == topic).unwrap();
        let p = ima_record::messages::PoseInFrame::decode(&m.data[..]).unwrap();
        assert_eq!(p.frame_id, "map", "{topic}");
        let pos = p.pose.unwrap().position.unwrap();
        (pos.x, pos.y)
    };
    let (b, t) = (first_pose("/scooter/belief"), first_pose("/scooter/truth"));
    assert!(
        (b.0 - t.0).hypot(b.1 - t.1) < 0.3,
        "belief {b:?}, truth {t:?}"
    );
    // Both robots' odometry, though Skeeter's runtime never reads its own (it had none, so
    // nothing placed `skeeter/base_link`, where its sonar and SES are drawn).
    for robot in ["skeeter", "scooter"] {
        assert_eq!(schema(&format!("/{robot}/odom")), "foxglove.PoseInFrame");
        assert!(written[&format!("/{robot}/odom")] > 0);
    }
    assert_eq!(schema("/san/scooter"), "ima.SanState");
    assert_eq!(schema("/peer/skeeter/status"), "ima.PeerStatus");
    assert!(
        ch.values().any(|c| c.0 == "foxglove.RawImage"),
        "camera frames: {ch:?}"
    );
    // One raw channel per serial port of both robots, with port, baud and protocol.
    let raw: BTreeMap<&str, &str> = ch
        .iter()
        .filter(|(t, _)| t.contains("/serial/"))
        .map(|(t, c)| (t.as_str(), c.1["protocol"].as_str()))
        .collect();
    assert_eq!(
        raw,
        BTreeMap::from([
            ("/scooter/serial/base", "rflex"),
            ("/scooter/serial/compass", "compass-kvh"),
            ("/scooter/serial/laser", "sick-lms"),
            ("/skeeter/serial/base", "p2os"),
            ("/skeeter/serial/video_mux", "video-mux-extron"),
        ])
    );
    for t in raw.keys() {
        assert!(ch[*t].1["port"].starts_with("/dev/"), "{t}: {:?}", ch[*t].1);
        assert!(ch[*t].1["baud"].parse::<u32>().is_ok());
    }
    // The rFLEX's channel carries the time scale its driver ran with (×10 here): a replay
    // integrates its odometry with the same plausibility limits (with the real-time ones,
    // a fast replay rejected most motion reports).
    assert_eq!(ch["/scooter/serial/base"].1["time_scale"], "10");

    // Replay: the raw laser bytes re-decode into the recorded scans, one by one, in order.
    let (out, err) = replay_json(&file);
    assert!(out.status.success(), "{err}");
    let replayed: Vec<Vec<Option<f32>>> = json_lines(&out.stdout)
        .iter()
        .filter(|l| l["kind"] == "scan" && l["robot"] == "scooter")
        .map(|l| {
            l["ranges_m"]
                .as_array()
                .unwrap()
                .iter()
                .map(|r| r.as_f64().map(|x| x as f32))
                .collect()
        })
        .collect();
    let recorded: Vec<Vec<Option<f32>>> = msgs
        .iter()
        .filter(|m| m.topic == "/scooter/laser/scan")
        .map(|m| {
            let s = ima_record::messages::LaserScan::decode(&m.data[..]).unwrap();
            s.ranges
                .iter()
                .map(|r| (!r.is_nan()).then_some(*r as f32))
                .collect()
        })
        .collect();
    assert!(!recorded.is_empty());
    // The stack reads every scan the driver decodes once it runs; the replay also has the
    // scans that streamed before Scooter's stack started.
    in_order("scan", &recorded, &replayed, |a, b| a == b);
    // How many scans streamed before the stack started depends on timing: no ratio asserted.
    assert!(recorded.len() >= 10, "{} recorded", recorded.len());
    // Both bases' odometry comes back from their raw bytes: every recorded pose, in order,
    // among the re-decoded ones. The rFLEX's was integrated by a model of the replay's own
    // (each translation with the previous cycle's rotation, no midpoint): 69 of 583 recorded
    // poses came back, heading up to 6° off; it now goes through the driver's machine.
    for robot in ["skeeter", "scooter"] {
        let replayed: Vec<[f64; 3]> = json_lines(&out.stdout)
            .iter()
            .filter(|l| l["kind"] == "odometry" && l["robot"] == robot)
            .map(|l| {
                let f = |k: &str| l[k].as_f64().unwrap();
                [f("x_m"), f("y_m"), f("theta_rad")]
            })
            .collect();
        let recorded: Vec<[f64; 3]> = msgs
            .iter()
            .filter(|m| m.topic == format!("/{robot}/odom"))
            .map(|m| {
                let p = ima_record::messages::PoseInFrame::decode(&m.data[..]).unwrap();
                let pose = p.pose.unwrap();
                let (pos, q) = (pose.position.unwrap(), pose.orientation.unwrap());
                [pos.x, pos.y, 2.0 * q.z.atan2(q.w)]
            })
            .collect();
        assert!(recorded.len() >= 10, "{robot}: {} recorded", recorded.len());
        let same = |a: &[f64; 3], b: &[f64; 3]| {
            let turn = (a[2] - b[2] + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9 && turn.abs() < 1e-9
        };
        in_order(&format!("{robot}'s pose"), &recorded, &replayed, same);
    }

    // A recording of the replay carries every raw channel as recorded (port metadata, stamps,
    // both directions, line speeds): it replays into the same readings. It used to hold only
    // the readings, so "no raw serial channel to re-decode" ended the trail there.
    let again = file.with_file_name("replayed.mcap");
    let rerecorded = ima()
        .args(["replay", "--speed", "0", "--record"])
        .arg(&again)
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&rerecorded.stderr);
    assert!(rerecorded.status.success(), "{err}");
    let original = Recording::open(&file).unwrap().raw_streams();
    let copied = Recording::open(&again).unwrap().raw_streams();
    assert_eq!(copied.len(), 5, "{err}");
    for (c, o) in copied.iter().zip(&original) {
        assert_eq!((&c.topic, &c.port), (&o.topic, &o.port));
        assert_eq!(c.chunks.len(), o.chunks.len(), "{}", c.topic);
        if let Some(i) = c.chunks.iter().zip(&o.chunks).position(|(a, b)| a != b) {
            panic!(
                "{}: chunk {i}: {:?} against {:?}",
                c.topic, c.chunks[i], o.chunks[i]
            );
        }
    }
    // Skeeter's sonar comes back from its SIPs too: every recorded cloud, in order, among the
    // re-recorded ones (a replay had none).
    let clouds = |f: &std::path::Path| -> Vec<Vec<u8>> {
        let (msgs, _) = Recording::open(f).unwrap().messages();
        msgs.iter()
            .filter(|m| m.topic == "/skeeter/sonar")
            .map(|m| {
                let c = ima_record::messages::PointCloud::decode(&m.data[..]).unwrap();
                c.data.to_vec()
            })
            .collect()
    };
    let (live, replayed_clouds) = (clouds(&file), clouds(&again));
    assert!(live.len() >= 10, "{} sonar clouds recorded", live.len());
    in_order("sonar cloud", &live, &replayed_clouds, |a, b| a == b);
    // The compass comes back as recorded, orientation for orientation: a replay did not wrap
    // its yaw into (−π, π], so 40 of 146 came back as the same rotation with the opposite
    // quaternion. (Each pose sits where the robot was when it came, which the replay's
    // interleaving of the two ports decides: the position is not compared.)
    let compass = |f: &std::path::Path| -> Vec<[f64; 6]> {
        let (msgs, _) = Recording::open(f).unwrap().messages();
        msgs.iter()
            .filter(|m| m.topic == "/scooter/compass")
            .map(|m| {
                let p = ima_record::messages::PoseInFrame::decode(&m.data[..]).unwrap();
                let pose = p.pose.unwrap();
                let (at, q) = (pose.position.unwrap(), pose.orientation.unwrap());
                [at.x, at.y, q.x, q.y, q.z, q.w]
            })
            .collect()
    };
    let (live, replayed_compass) = (compass(&file), compass(&again));
    assert!(live.len() >= 10, "{} compass poses recorded", live.len());
    in_order("compass pose", &live, &replayed_compass, |a, b| {
        a.iter().zip(b).skip(2).all(|(x, y)| (x - y).abs() < 1e-9)
    });
    // The fixed transforms come along, so the replayed readings have a place in `map` (a
    // replay's scans could not be shown by a viewer following `map`).
    let fixed = Recording::open(&file).unwrap().fixed_transforms();
    assert!(
        fixed
            .iter()
            .any(|(p, c, _)| p == "map" && c == "scooter/odom")
            && fixed
                .iter()
                .any(|(p, c, _)| p == "scooter/base_link" && c == "scooter/laser"),
        "{fixed:?}"
    );
    let again_fixed = Recording::open(&again).unwrap().fixed_transforms();
    assert_eq!(again_fixed.len(), fixed.len(), "{again_fixed:?}");
    for ((p, c, v), (p2, c2, v2)) in fixed.iter().zip(&again_fixed) {
        assert_eq!((p, c), (p2, c2));
        assert!(
            v.iter().zip(v2).all(|(a, b)| (a - b).abs() < 1e-9),
            "{v:?} {v2:?}"
        );
    }
    // Stamped on the recording's clock, as every replayed message, and sent again every
    // recorded second: they were stamped with the time of the replay (the re-recording
    // spanned 258 s for 16 s of data) and sent once at `--speed 0`.
    let span = |f: &std::path::Path| {
        let (msgs, _) = Recording::open(f).unwrap().messages();
        let t = |m: &ima_record::read::Message| m.log_time;
        let (lo, hi) = (
            msgs.iter().map(t).min().unwrap(),
            msgs.iter().map(t).max().unwrap(),
        );
        let map_odom = |m: &&ima_record::read::Message| {
            let t = ima_record::messages::FrameTransform::decode(&m.data[..]).unwrap();
            t.parent_frame_id == "map" && t.child_frame_id == "scooter/odom"
        };
        let tf = msgs
            .iter()
            .filter(|m| m.topic == "/tf")
            .filter(map_odom)
            .count();
        (lo, hi, tf)
    };
    let (lo, hi, _) = span(&file);
    let (lo2, hi2, sends) = span(&again);
    assert!(lo2 >= lo && hi2 <= hi, "{lo}..{hi} against {lo2}..{hi2}");
    let seconds = (hi - lo) / 1_000_000_000;
    assert!(
        sends as u64 >= seconds.saturating_sub(1),
        "map → scooter/odom sent {sends} times in {seconds} s"
    );
    let (out2, _) = replay_json(&again);
    assert!(out2.status.success());
    let (first, second) = (json_lines(&out.stdout), json_lines(&out2.stdout));
    assert!(
        first == second,
        "the replay of the replay differs: {} readings against {}",
        second.len(),
        first.len()
    );

    // `ima decode --mcap` reads one port.
    let out = ima()
        .args(["decode", "--port", "scooter/laser", "--mcap"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(out.status.success());
    let scans = json_lines(&out.stdout)
        .iter()
        .filter(|l| l["kind"] == "scan")
        .count();
    assert_eq!(scans, replayed.len());
    // Decoded chunk by chunk as the file is read, exactly as the port's bytes decode whole.
    let bytes = Recording::open(&file)
        .unwrap()
        .raw_stream("scooter/laser")
        .unwrap()
        .rx_bytes();
    let capture = file.with_extension("laser.bin");
    std::fs::write(&capture, &bytes).unwrap();
    let whole = ima()
        .args(["decode", "sick-lms"])
        .arg(&capture)
        .output()
        .unwrap();
    assert!(whole.status.success() && scans > 0);
    assert!(
        out.stdout == whole.stdout,
        "decoded from the recording and from its {} bytes whole differ",
        bytes.len()
    );
    let out = ima()
        .args(["decode", "--port", "nowhere", "--mcap"])
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("/scooter/serial/laser"),
        "{err}"
    );
}

#[test]
fn a_killed_recording_is_still_readable() {
    let dir = scratch("killed");
    let file = dir.join("killed.mcap");
    let mut child = common::Child(
        ima()
            .args(["demo", "--json", "--speed", "10", "--svg"])
            .arg(dir.join("killed.svg"))
            .arg("--record")
            .arg(&file)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap(),
    );
    // Wait until the file has grown past a few chunks (flushed every second), then SIGKILL.
    let mut waited = 0;
    while std::fs::metadata(&file).map_or(0, |m| m.len()) < 400_000 && waited < 600 {
        std::thread::sleep(std::time::Duration::from_millis(100));
        waited += 1;
    }
    child.0.kill().unwrap();
    let _ = child.0.wait();
    let rec = Recording::open(&file).unwrap();
    let (msgs, cut) = rec.messages();
    assert!(cut.0.is_some(), "a killed recording has no summary");
    assert_early_topics(&msgs);
    // It replays: the damage said once (found on opening, or by the reading when the file
    // stops inside its last record header), and the bases' odometry from their raw bytes.
    let (out, err) = replay_json(&file);
    assert!(out.status.success(), "{err}");
    assert_eq!(err.matches("ima replay: the recording").count(), 1, "{err}");
    assert!(
        (err.contains("ima replay: the recording is damaged (")
            && err.contains("replaying what it holds"))
            || (err.contains("ima replay: the recording ends early (")
                && err.contains("replayed what it holds")),
        "{err}"
    );
    assert!(
        json_lines(&out.stdout)
            .iter()
            .any(|l| l["kind"] == "odometry"),
        "{err}"
    );
    // Cut inside its first chunk: the damage is found on opening and said before the replay,
    // and a replay that found nothing at all fails (it used to end with status 0).
    let bytes = std::fs::read(&file).unwrap();
    let mut at = 8; // the magic
    while bytes[at] != 0x06 {
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap());
        at += 9 + usize::try_from(len).unwrap();
    }
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..at + 20]).unwrap();
    let (out, err) = replay_json(&cut);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.matches("ima replay: the recording").count(), 1, "{err}");
    assert!(
        err.contains("ima replay: the recording is damaged (it ends early: ")
            && err.contains("replaying what it holds")
            && err.contains("nothing to replay in ")
            && err.contains("cut.mcap: the recording is damaged (it ends early"),
        "{err}"
    );
    assert!(out.stdout.is_empty());
}

/// What a demo's recording cut short once its file has a written chunk must hold: both bases'
/// raw bytes (they stream from their connection on) and camera frames (which fill the chunk).
/// Not a scan: Scooter's runtime reads its first one only after its Peer link and first
/// odometry, and on a loaded machine Skeeter's frames can fill that chunk first (one
/// `.ci/run` found no scan in the file; beside two busy loops the first scan came ~1.45 s into
/// the recording, the first frame ~1.8 s).
fn assert_early_topics(msgs: &[ima_record::read::Message]) {
    for topic in ["/scooter/serial/base", "/skeeter/serial/base"] {
        assert!(
            msgs.iter().any(|m| m.topic == topic),
            "no {topic} in the {} messages",
            msgs.len()
        );
    }
    assert!(
        msgs.iter().any(|m| m.topic.starts_with("/skeeter/camera/")),
        "no camera frame in the {} messages",
        msgs.len()
    );
}

/// The next WebSocket message, `None` when the read timed out; any other error fails the test
/// at once (not after the deadline), saying `why`.
fn next<S: std::io::Read + std::io::Write>(
    ws: &mut tokio_tungstenite::tungstenite::WebSocket<S>,
    why: &mut impl FnMut(&str) -> String,
) -> Option<tokio_tungstenite::tungstenite::Message> {
    match ws.read() {
        Ok(m) => Some(m),
        Err(tokio_tungstenite::tungstenite::Error::Io(e))
            if matches!(
                e.kind(),
                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
            ) =>
        {
            None
        }
        Err(e) => panic!(
            "{}",
            why(&format!("the live view's connection failed: {e}"))
        ),
    }
}

#[test]
fn a_websocket_client_of_the_live_demo_gets_channels_and_a_scan() {
    let dir = scratch("live");
    use tokio_tungstenite::tungstenite::{self, Message, client::IntoClientRequest};
    // The demo's log, shown if no scan comes (a failure in `.ci/run` said only "no scan").
    let log = dir.join("demo.log");
    let mut demo = common::Child(
        ima()
            // Real-time speed: the mission outlasts a slow start on a loaded machine, so the
            // stream still flows when the client subscribes.
            .args(["demo", "--json", "--speed", "1", "--svg"])
            .arg(dir.join("live.svg"))
            // Port 0: the server binds a free port itself and prints it (a port picked here
            // and released could be taken by another test before the demo binds it).
            .args(["--foxglove", "0"])
            .stdout(std::process::Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    let mut why = |what: &str| {
        let status = demo.0.try_wait().ok().flatten();
        let log = std::fs::read_to_string(&log).unwrap_or_default();
        let tail: Vec<&str> = log.lines().rev().take(20).collect();
        format!(
            "{what}; the demo: {}; its last log lines (newest first):\n{}",
            status.map_or("still running".to_owned(), |s| s.to_string()),
            tail.join("\n")
        )
    };
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    let port: u16 = loop {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        let printed = text
            .split("live view for Foxglove on ws://127.0.0.1:")
            .nth(1)
            .and_then(|rest| rest.split(|c: char| !c.is_ascii_digit()).next())
            .and_then(|p| p.parse().ok());
        if let Some(p) = printed {
            break p;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "{}",
            why("the live view's address was not printed")
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    let stream = loop {
        match std::net::TcpStream::connect(("127.0.0.1", port)) {
            Ok(s) => break s,
            Err(e) => {
                assert!(
                    std::time::Instant::now() < deadline,
                    "{}",
                    why(&format!("no server: {e}"))
                );
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
        }
    };
    stream
        .set_read_timeout(Some(std::time::Duration::from_secs(5)))
        .unwrap();
    let mut req = format!("ws://127.0.0.1:{port}")
        .into_client_request()
        .unwrap();
    req.headers_mut()
        .insert("sec-websocket-protocol", "foxglove.sdk.v1".parse().unwrap());
    let (mut ws, _) = tungstenite::client(req, stream).unwrap();
    let mut schemas: BTreeMap<String, String> = BTreeMap::new();
    let mut laser = None;
    let mut encodings: BTreeMap<String, String> = BTreeMap::new();
    while laser.is_none() || !schemas.contains_key("/san/scooter") {
        assert!(
            std::time::Instant::now() < deadline,
            "{}",
            why(&format!("advertised: {schemas:?}"))
        );
        let Some(Message::Text(t)) = next(&mut ws, &mut why) else {
            continue;
        };
        let v: serde_json::Value = serde_json::from_str(&t).unwrap();
        if v["op"] == "advertise" {
            for c in v["channels"].as_array().unwrap() {
                let topic = c["topic"].as_str().unwrap().to_owned();
                if topic == "/scooter/laser/scan" {
                    laser = c["id"].as_u64();
                }
                let enc = c["schemaEncoding"].as_str().unwrap_or("").to_owned();
                encodings.insert(topic.clone(), enc);
                schemas.insert(topic, c["schemaName"].as_str().unwrap_or("").to_owned());
            }
        }
    }
    assert_eq!(schemas["/scooter/laser/scan"], "foxglove.LaserScan");
    // The SAN's state is served as JSON with its JSON Schema.
    assert_eq!(schemas["/san/scooter"], "ima.SanState");
    assert_eq!(encodings["/san/scooter"], "jsonschema");
    assert!(
        !schemas.keys().any(|t| t.contains("/serial/")),
        "raw bytes stay off the live view: {schemas:?}"
    );
    let sub = serde_json::json!({"op": "subscribe",
        "subscriptions": [{"id": 3, "channelId": laser.unwrap()}]});
    ws.send(Message::Text(sub.to_string().into())).unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    let mut other = 0;
    loop {
        assert!(
            std::time::Instant::now() < deadline,
            "{}",
            why(&format!("no scan arrived in 30 s ({other} other messages)"))
        );
        let Some(m) = next(&mut ws, &mut why) else {
            continue;
        };
        other += 1;
        if let Message::Binary(b) = m {
            assert_eq!(b[0], 1, "message data");
            assert_eq!(u32::from_le_bytes(b[1..5].try_into().unwrap()), 3);
            let s = ima_record::messages::LaserScan::decode(&b[13..]).unwrap();
            assert_eq!(s.frame_id, "scooter/laser");
            assert!(!s.ranges.is_empty());
            break;
        }
    }
}

/// `ima drive` against a mock P2OS robot, recorded; then `ima drive` against that recording
/// served by `ima replay --as-mock` connects the same way and reads the same odometry.
#[test]
fn the_p2os_driver_runs_against_a_recording_served_as_a_mock() {
    let dir = scratch("p2os");
    use std::io::BufRead;
    let file = dir.join("p2os.mcap");
    let (_mock, pty) = common::spawn_mock(&["p2os"]);
    let drive = |port: &str, record: Option<&std::path::Path>| {
        let mut cmd = ima();
        cmd.args([
            "drive", "--vel", "0.2", "--for", "1", "--json", "--port", port,
        ]);
        if let Some(f) = record {
            cmd.arg("--record").arg(f);
        }
        let out = cmd.output().unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        json_lines(&out.stdout)
            .iter()
            .map(|l| {
                (
                    l["x_m"].to_string(),
                    l["y_m"].to_string(),
                    l["theta_rad"].to_string(),
                )
            })
            .collect::<Vec<_>>()
    };
    let live = drive(&pty, Some(&file));
    assert!(live.len() >= 3, "{live:?}");
    // `ima drive` records the P2OS sonar too.
    let sonar = Recording::open(&file).unwrap().channels();
    assert_eq!(sonar["/robot/sonar"].0, "foxglove.PointCloud", "{sonar:?}");
    // The recording served on a pty, and the pty's path.
    let serve = |stderr: std::process::Stdio, speed: &str| {
        let mut served = common::Child(
            ima()
                .args(["replay", "--as-mock", "robot/base", "--speed", speed])
                .arg(&file)
                .stdout(std::process::Stdio::piped())
                .stderr(stderr)
                .spawn()
                .unwrap(),
        );
        let mut path = String::new();
        std::io::BufReader::new(served.0.stdout.take().unwrap())
            .read_line(&mut path)
            .unwrap();
        (served, path.trim().to_owned())
    };
    let (_served, path) = serve(std::process::Stdio::null(), "1");
    let replayed = drive(&path, None);
    // The same odometry in the same order; how many states each run prints within its `--for`
    // depends on timing, so one may have a state more than the other.
    let n = live.len().min(replayed.len());
    assert!(
        n >= 3 && live.len().abs_diff(replayed.len()) <= 2,
        "{live:?}\n{replayed:?}"
    );
    assert_eq!(replayed[..n], live[..n]);
    // A client that writes, then closes the port: the server ends at once, saying so (it went
    // on for each chunk's 2 s wait for a request, 69 s for an 8 s recording, into a pty
    // nobody had open).
    // As fast as possible too, where the write sees the close first (it failed with "Broken
    // pipe").
    for speed in ["1", "0"] {
        let (served, path) = serve(std::process::Stdio::piped(), speed);
        let mut client = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&path)
            .unwrap();
        std::io::Write::write_all(&mut client, &[0xFA, 0xFB, 0x03, 0x00, 0x00, 0x00]).unwrap();
        std::thread::sleep(std::time::Duration::from_millis(300));
        drop(client);
        let out = served.output_within(5);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success() && err.contains(&format!("the client closed {path}")),
            "--speed {speed}: {err}"
        );
    }
    // Ctrl-C while the recording is served (waiting for a host that never writes): it ends at
    // once as interrupted, saying what it served (it used to end with status 0, as if it had
    // served everything).
    let (mut served, path) = serve(std::process::Stdio::piped(), "1");
    assert!(path.starts_with("/dev/"), "{path}");
    served.signal("INT");
    let out = served.wait_output();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    assert!(
        err.contains("ima replay: served ")
            && err.contains("bytes of /robot/serial/base (p2os)")
            && err.contains("interrupted by SIGINT")
            && !err.contains("could move"),
        "{err}"
    );
    // Ctrl-C on a slow replay of the recording (after its first reading): it ends as
    // interrupted, without claiming to have stopped a device (it opened none; it said
    // "every device that could move was stopped").
    let mut replay = common::Child(
        ima()
            .args(["replay", "--json", "--speed", "0.05"])
            .arg(&file)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut first = String::new();
    let mut lines = std::io::BufReader::new(replay.0.stdout.take().unwrap());
    lines.read_line(&mut first).unwrap();
    assert!(first.contains("\"kind\""), "{first}");
    // Read the rest until it ends: a closed stdout would end it with 141 instead.
    let drain = std::thread::spawn(move || std::io::copy(&mut lines, &mut std::io::sink()));
    replay.signal("INT");
    let out = replay.wait_output();
    let _ = drain.join();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    assert!(
        err.contains("interrupted by SIGINT") && !err.contains("could move"),
        "{err}"
    );
    // Without `--json`, a replay says what it does as it starts (it showed nothing for as
    // long as the recording lasted), and how far it got when it is stopped.
    let mut replay = common::Child(
        ima()
            .args(["replay", "--speed", "0.05"])
            .arg(&file)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut errs = std::io::BufReader::new(replay.0.stderr.take().unwrap());
    let mut start = String::new();
    errs.read_line(&mut start).unwrap();
    assert!(
        start.starts_with("ima replay: re-decoding ")
            && start.contains("at ×0.05; `--json` prints each reading"),
        "{start}"
    );
    replay.signal("INT");
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut errs, &mut rest).unwrap();
    assert_eq!(replay.0.wait().unwrap().code(), Some(130), "{rest}");
    assert!(rest.contains("replayed before it stopped"), "{rest}");
}

/// Ctrl-C during a recorded demo: the guard closes the file, which then has its summary.
#[test]
fn an_interrupted_recording_is_closed_properly() {
    let dir = scratch("sigint");
    let file = dir.join("sigint.mcap");
    let mut child = common::Child(
        ima()
            .args(["demo", "--json", "--speed", "10", "--svg"])
            .arg(dir.join("sigint.svg"))
            .arg("--record")
            .arg(&file)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let mut waited = 0;
    while std::fs::metadata(&file).map_or(0, |m| m.len()) < 200_000 && waited < 600 {
        std::thread::sleep(std::time::Duration::from_millis(100));
        waited += 1;
    }
    child.signal("INT");
    let out = child.wait_output();
    assert_eq!(out.status.code(), Some(130));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("recorded") && err.contains("sigint.mcap"),
        "{err}"
    );
    // The demo ended on the signal itself, not when the guard's grace period ran out (the
    // forced exit prints no error line, and raced the recording's report).
    assert!(
        err.contains("interrupted by SIGINT; every device that could move was stopped"),
        "{err}"
    );
    // A halted base is reported once, not on every control tick (it was ~150 lines).
    assert!(
        err.lines()
            .filter(|l| l.contains("base: Disconnected"))
            .count()
            <= 1,
        "{err}"
    );
    let rec = Recording::open(&file).unwrap();
    let (msgs, cut) = rec.messages();
    assert_eq!(cut.0, None, "the file ends with its summary");
    assert_early_topics(&msgs);
}

/// Scooter on a P2OS base: both robots' sonar is recorded as point clouds in their
/// `base_link`, at ranges the transducers can measure, and Scooter's SIPs match its driver.
#[test]
fn a_p2os_demo_records_sonar_point_clouds() {
    let dir = scratch("p2os-demo");
    let (_, summary, file) = recorded_demo(&dir, "p2os-demo", &["--scooter-base", "p2os"]);
    assert_eq!(summary["drivers"]["scooter"]["base"], "p2os", "{summary}");
    let rec = Recording::open(&file).unwrap();
    let ch = rec.channels();
    let (msgs, _) = rec.messages();
    for robot in ["scooter", "skeeter"] {
        let topic = format!("/{robot}/sonar");
        assert_eq!(ch[&topic].0, "foxglove.PointCloud");
        let mut points = 0;
        for m in msgs.iter().filter(|m| m.topic == topic) {
            let c = ima_record::messages::PointCloud::decode(&m.data[..]).unwrap();
            assert_eq!(c.frame_id, format!("{robot}/base_link"));
            assert_eq!(c.point_stride, 16);
            let f32_at = |p: &[u8], i: usize| f32::from_le_bytes(p[i..i + 4].try_into().unwrap());
            for p in c.data.chunks(16) {
                let (x, y, range) = (f32_at(p, 0), f32_at(p, 4), f32_at(p, 12));
                // P2OS sonar: 0.1–5 m along the beam; the transducers sit within 0.3 m of
                // the robot's centre.
                assert!((0.099..5.0).contains(&range), "{range}");
                let d = x.hypot(y);
                assert!(
                    d > range - 0.35 && d < range + 0.35,
                    "({x}, {y}) at {range} m"
                );
                points += 1;
            }
        }
        assert!(points > 0, "{topic}: no echoes");
        // Each odometry reading once: at most one per SIP (Scooter's was logged twice, by its
        // runtime's reader and by the sonar task).
        let odom = msgs
            .iter()
            .filter(|m| m.topic == format!("/{robot}/odom"))
            .count() as u64;
        let sips = summary["drivers"][robot]["base_sips"].as_u64().unwrap();
        assert!(
            odom > 0 && odom <= sips,
            "/{robot}/odom: {odom}, {sips} SIPs"
        );
    }
    // Every topic the shipped layout opens is in the recording (`/robot/…`: drive and scan),
    // and its SAN plot's fields are in the messages.
    let layout: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/docs/foxglove-layout.json"
        ))
        .unwrap(),
    )
    .unwrap();
    let mut paths: Vec<String> = Vec::new();
    for (id, cfg) in layout["configById"].as_object().unwrap() {
        if let Some(t) = cfg["topics"].as_object() {
            paths.extend(t.keys().cloned());
        }
        for k in ["topicToRender", "topicPath"] {
            paths.extend(cfg[k].as_str().map(str::to_owned));
        }
        paths.extend(cfg["imageMode"]["imageTopic"].as_str().map(str::to_owned));
        for p in cfg["paths"].as_array().into_iter().flatten() {
            let v = p["value"].as_str().unwrap();
            if id.starts_with("Plot!ima-san") {
                let (topic, field) = v.split_once(".activation.").unwrap();
                let last = msgs.iter().rfind(|m| m.topic == topic).unwrap();
                let last: serde_json::Value = serde_json::from_slice(&last.data).unwrap();
                assert!(last["activation"][field].is_number(), "{v}: {last}");
            }
            paths.push(v.split('.').next().unwrap().to_owned());
        }
    }
    assert!(paths.len() > 10, "{paths:?}");
    // The arena's walls are drawn (the laser sees them; only the objects were).
    let arena = msgs.iter().find(|m| m.topic == "/world/arena").unwrap();
    let arena = ima_record::messages::SceneUpdate::decode(&arena.data[..]).unwrap();
    let walls = &arena.entities[0].lines[0];
    assert!(
        walls.points.len() >= 8 && walls.points.len() % 2 == 0,
        "{walls:?}"
    );
    for t in paths.iter().filter(|t| !t.starts_with("/robot/")) {
        assert!(
            ch.contains_key(t),
            "the layout opens {t}, which is not recorded"
        );
    }
    let out = ima()
        .args(["decode", "--port", "scooter/base", "--mcap"])
        .arg(&file)
        .output()
        .unwrap();
    let sips = json_lines(&out.stdout)
        .iter()
        .filter(|l| l["kind"] == "sip")
        .count() as u64;
    // As in the first test: SIPs arriving while the driver closes are recorded, not counted.
    let d = &summary["drivers"]["scooter"];
    let counted = d["base_sips"].as_u64().unwrap();
    let lost = d["base_framer_drops"].as_u64().unwrap();
    assert!(
        counted <= sips && sips <= counted + lost + 2,
        "{sips} SIPs: {d}"
    );
}

/// `--record-exclude`: `ima drive` recorded without its sonar and its raw port. The file has the
/// rest, the end line and the file's metadata name what was left out, and a malformed pattern is
/// refused before anything starts.
#[test]
fn record_exclude_leaves_topics_out_of_the_file() {
    let dir = scratch("exclude");
    let file = dir.join("exclude.mcap");
    let (_mock, pty) = common::spawn_mock(&["p2os"]);
    let out = ima()
        .args([
            "drive", "--vel", "0.1", "--for", "1", "--json", "--port", &pty, "--record",
        ])
        .arg(&file)
        .args(["--record-exclude", "/*/sonar"])
        .args(["--record-exclude", "/robot/serial"])
        .args(["--record-exclude", "/skeeter/serial/base"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    // A pattern that left nothing out (a typo: this drive's topics are /robot/…) is named.
    assert!(
        err.contains(
            "(left out: /*/sonar, /robot/serial, /skeeter/serial/base; no topic matched \
             /skeeter/serial/base)"
        ),
        "{err}"
    );
    let ch = Recording::open(&file).unwrap().channels();
    assert!(ch.contains_key("/robot/odom"), "{ch:?}");
    // `map` → `robot/odom`, so a viewer following `map` (the shipped layout) places the robot
    // (a drive had no `map` frame).
    let (msgs, _) = Recording::open(&file).unwrap().messages();
    assert!(
        msgs.iter().filter(|m| m.topic == "/tf").any(|m| {
            let t = ima_record::messages::FrameTransform::decode(&m.data[..]).unwrap();
            t.parent_frame_id == "map" && t.child_frame_id == "robot/odom"
        }),
        "no map → robot/odom"
    );
    assert!(
        !ch.keys()
            .any(|t| t.contains("sonar") || t.contains("serial")),
        "{ch:?}"
    );
    let meta = Recording::open(&file).unwrap().ima_metadata().unwrap();
    assert_eq!(
        meta["exclude"],
        "/*/sonar, /robot/serial, /skeeter/serial/base"
    );
    // Asked for the port it left out, a replay says why it is missing.
    let out = ima()
        .args(["replay", "--as-mock", "robot/base"])
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success()
            && err.contains(
                "it has: none (the recording left out: /*/sonar, /robot/serial, \
                 /skeeter/serial/base)"
            ),
        "{err}"
    );
    let out = ima()
        .args(["replay", "--speed", "0"])
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success()
            && err.contains(
                "no raw serial channel to re-decode in the recording \
                 (the recording left out: /*/sonar, /robot/serial, /skeeter/serial/base)"
            ),
        "{err}"
    );

    let out = ima()
        .args(["drive", "--port", &pty, "--record"])
        .arg(dir.join("never.mcap"))
        .args(["--record-exclude", "sonar"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("does not start with '/'"),
        "{err}"
    );
    assert!(!dir.join("never.mcap").exists());
}

/// Whether `v` fits `schema`, for the parts of JSON Schema the `ima.*` schemas use: `type`
/// (one or several), `properties` (undeclared ones allowed) and `items`. `Err` names where
/// it does not.
fn fits(v: &serde_json::Value, schema: &serde_json::Value, at: &str) -> Result<(), String> {
    use serde_json::Value;
    let is = |t: &str| match t {
        "number" => v.is_number(),
        "integer" => v.is_i64() || v.is_u64(),
        "string" => v.is_string(),
        "boolean" => v.is_boolean(),
        "object" => v.is_object(),
        "array" => v.is_array(),
        "null" => v.is_null(),
        _ => true,
    };
    let ok = match &schema["type"] {
        Value::String(t) => is(t),
        Value::Array(ts) => ts.iter().filter_map(Value::as_str).any(is),
        _ => true,
    };
    if !ok {
        return Err(format!("{at} is not {}", schema["type"]));
    }
    if let (Some(props), Some(obj)) = (schema["properties"].as_object(), v.as_object()) {
        for (k, s) in props {
            if let Some(x) = obj.get(k) {
                fits(x, s, &format!("{at}.{k}"))?;
            }
        }
    }
    if let (Some(items), Some(arr)) = (schema.get("items"), v.as_array()) {
        for (i, x) in arr.iter().enumerate() {
            fits(x, items, &format!("{at}[{i}]"))?;
        }
    }
    Ok(())
}

/// `--foxglove` on an address in use fails before the recording's file is made (it left an
/// empty file behind, which the next try refused to overwrite); bound to every address, the
/// live view names a URL a client can open and warns that anyone may watch.
#[test]
fn the_live_view_is_bound_before_the_file_is_made() {
    let dir = scratch("busy");
    let held = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let busy = held.local_addr().unwrap().to_string();
    let file = dir.join("busy.mcap");
    let out = ima()
        .args(["demo", "--speed", "20", "--foxglove", &busy, "--record"])
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains(&format!("--foxglove {busy}")),
        "{err}"
    );
    assert!(!file.exists(), "an empty recording was left behind");
    let mut demo = common::Child(
        ima()
            .args(["demo", "--speed", "20", "--foxglove", "0.0.0.0:0"])
            .arg("--svg")
            .arg(dir.join("any.svg"))
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let (lines, _reader) = common::line_channel(demo.0.stderr.take().unwrap());
    let url = loop {
        let l = lines
            .recv_timeout(std::time::Duration::from_secs(30))
            .expect("the live view's line");
        if let Some(rest) = l.strip_prefix("ima: live view for Foxglove on ") {
            break rest.to_owned();
        }
    };
    assert!(url.starts_with("ws://127.0.0.1:"), "{url}");
    // Among the next lines (another thread's may come first), each waited for at most 10 s.
    let warned = (0..20)
        .map_while(|_| lines.recv_timeout(std::time::Duration::from_secs(10)).ok())
        .any(|l| l.contains("served on 0.0.0.0, beyond loopback, with no token"));
    assert!(warned, "no warning for 0.0.0.0");
}

/// A file that cannot grow (here a file-size limit: `write` fails with EFBIG, as a full disk
/// fails with ENOSPC) stops the recording, not the robots: one error line names the file's
/// own error at the moment it happens (no warning per message after it), the mission runs to
/// its end, the report and the command's exit status say the recording is incomplete, and
/// the file holds its chunks up to the failure, as many messages as the report says.
#[test]
fn a_recording_that_cannot_be_written_says_so_once_and_fails_the_command() {
    let dir = scratch("full");
    let file = dir.join("full.mcap");
    // 2048 blocks of 512 bytes (POSIX `sh`): 1 MiB; SIGXFSZ ignored, so writes get EFBIG.
    let out = std::process::Command::new("sh")
        .args(["-c", "ulimit -f 2048 && trap '' XFSZ && exec \"$0\" \"$@\""])
        .arg(env!("CARGO_BIN_EXE_ima"))
        .args(common::SHORT_DEMO)
        .arg("--svg")
        .arg(dir.join("full.svg"))
        .arg("--record")
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    let summary = common::demo_summary(&out);
    assert_eq!(summary["targets"][0]["state"], "done", "{summary}");
    let why = summary["recording"]["error"].as_str().unwrap_or_default();
    assert!(why.contains("File too large"), "{summary}");
    let at_once = err
        .lines()
        .filter(|l| l.contains("writing stopped after"))
        .count();
    assert_eq!(at_once, 1, "{err}");
    assert!(!err.contains("AttemptedWriteAfterFailure"), "{err}");
    // Not the SDK's line in Rust's debug form beside it (`McapError(Io(Os { … }))`).
    assert!(!err.contains("error logging message"), "{err}");
    assert!(
        err.lines()
            .last()
            .is_some_and(|l| l.contains("is incomplete (File too large")),
        "{err}"
    );
    let size = std::fs::metadata(&file).unwrap().len();
    assert!(size <= 1 << 20, "{size}");
    let rec = Recording::open(&file).unwrap();
    let (msgs, cut) = rec.messages();
    assert!(cut.0.is_some(), "an incomplete recording has no summary");
    assert_early_topics(&msgs);
    // The counts are what the file holds, not the messages lost with the chunk being written
    // when it failed (they were counted as they went into it: 5,227 said, 2,736 held).
    let held = rec.count_by_topic();
    let said: std::collections::BTreeMap<String, u64> =
        serde_json::from_value(summary["recording"]["written"].clone()).unwrap();
    assert_eq!(said, held);
}

/// `ima demo square --record` records the robot's raw bytes (as Skeeter's base), its odometry
/// and the ground truth, with its odometry frame at the start pose in `map`; the replay gives
/// back every recorded pose. (`--record` was refused: the square demo had no recorder.)
#[test]
fn the_square_demo_records_and_replays() {
    let dir = scratch("square");
    let file = dir.join("square.mcap");
    let out = ima()
        .args(["demo", "square", "--side", "0.3", "--vel", "1", "--record"])
        .arg(&file)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    let rec = Recording::open(&file).unwrap();
    let ch = rec.channels();
    for topic in [
        "/skeeter/serial/base",
        "/skeeter/odom",
        "/skeeter/truth",
        "/tf",
    ] {
        assert!(ch.contains_key(topic), "{topic}: {:?}", ch.keys());
    }
    let (msgs, _) = rec.messages();
    let poses: Vec<(f64, f64)> = msgs
        .iter()
        .filter(|m| m.topic == "/skeeter/odom")
        .map(|m| {
            let p = ima_record::messages::PoseInFrame::decode(&m.data[..]).unwrap();
            let pos = p.pose.unwrap().position.unwrap();
            (pos.x, pos.y)
        })
        .collect();
    assert!(poses.len() >= 10, "{} poses", poses.len());
    let (out, _) = replay_json(&file);
    assert!(out.status.success());
    let replayed: Vec<(f64, f64)> = json_lines(&out.stdout)
        .iter()
        .filter(|l| l["kind"] == "odometry")
        .map(|l| (l["x_m"].as_f64().unwrap(), l["y_m"].as_f64().unwrap()))
        .collect();
    in_order("pose", &poses, &replayed, |a, b| {
        (a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 1e-9
    });
}

/// `ima decode --mcap` converts a recorded rFLEX port with the driver's own factors (its
/// channel's `kd`), not the ATRV-Jr's defaults: a drive at 0.3 m/s with `--kd` halved shows
/// 0.3 m/s, not 0.15.
#[test]
fn decode_mcap_converts_an_rflex_port_with_its_recorded_factors() {
    let dir = scratch("rflex-kd");
    let file = dir.join("kd.mcap");
    let (_mock, pty) = common::spawn_mock(&["rflex", "--seed", "3"]);
    common::run_ok(
        ima()
            .args([
                "drive", "--robot", "atrv-jr", "--kd", "45405", "--port", &pty,
            ])
            .args([
                "--vel", "0.3", "--turn", "0", "--for", "1", "--json", "--record",
            ])
            .arg(&file),
    );
    let out = common::run_ok(
        ima()
            .args(["decode", "--port", "robot/base", "--from", "host", "--mcap"])
            .arg(&file),
    );
    let speeds: Vec<f64> = json_lines(&out.stdout)
        .iter()
        .filter(|l| l["kind"] == "set_dir" && l["axis"] == 0)
        .filter_map(|l| l["v_m_s"].as_f64())
        .collect();
    let top = speeds.iter().copied().fold(0.0, f64::max);
    assert!((top - 0.3).abs() < 1e-3, "{speeds:?}");
}

/// A P2OS drive told its parameter table (`--params p2dx`, which overrides the robot's SYNC2
/// reply, here a P2-AT's) records it in the channel, and `ima decode --mcap` and `ima replay`
/// read the SIPs in those units (0.84 mm per count), as the driver did, not the P2-AT's (1.32).
#[test]
fn a_p2os_table_the_driver_was_told_is_recorded_and_decoded_with() {
    let dir = scratch("p2os-params");
    let file = dir.join("p2dx.mcap");
    let (_mock, pty) = common::spawn_mock(&["p2os"]);
    let out = common::run_ok(
        ima()
            .args(["drive", "--params", "p2dx", "--port", &pty])
            .args(["--vel", "0.2", "--for", "1", "--json", "--record"])
            .arg(&file),
    );
    let driven = json_lines(&out.stdout)
        .last()
        .and_then(|l| l["x_m"].as_f64())
        .unwrap();
    let ch = Recording::open(&file).unwrap().channels();
    assert_eq!(ch["/robot/serial/base"].1["params"], "p2dx");
    let out = common::run_ok(
        ima()
            .args(["decode", "--port", "robot/base", "--mcap"])
            .arg(&file),
    );
    let lines = json_lines(&out.stdout);
    let sips: Vec<_> = lines.iter().filter(|l| l["kind"] == "sip").collect();
    assert!(sips.len() > 5, "{} SIPs", sips.len());
    for s in sips {
        let (raw, x) = (s["x_raw"].as_i64().unwrap(), s["x_m"].as_f64().unwrap());
        assert!((x - raw as f64 * 0.84 / 1000.0).abs() < 1e-9, "{s}");
    }
    let (out, err) = replay_json(&file);
    assert!(out.status.success(), "{err}");
    let replayed: Vec<f64> = json_lines(&out.stdout)
        .iter()
        .filter(|l| l["kind"] == "odometry")
        .filter_map(|l| l["x_m"].as_f64())
        .collect();
    // The pose the drive printed last is among the replayed ones (the P2-AT's table would
    // make every one half as large again).
    assert!(driven > 0.05, "drove {driven} m");
    assert!(
        replayed.iter().any(|x| (x - driven).abs() < 1e-9),
        "{driven} not in {replayed:?}"
    );
}

/// `--as-mock` serves bytes and re-decodes nothing: a `--record` or `--foxglove` beside it is
/// refused (the file was never created, the server never started, without a word).
#[test]
fn as_mock_refuses_record_and_foxglove() {
    for extra in [["--record", "never.mcap"], ["--foxglove", "127.0.0.1:0"]] {
        let out = ima()
            .args(["replay", "--as-mock", "robot/base"])
            .args(extra)
            .arg("missing.mcap")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{err}");
        assert!(err.contains("cannot be used with"), "{err}");
    }
}
