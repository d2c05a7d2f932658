//! Fuzz-target bodies, kept in the crate so `cargo test` can replay the committed corpora
//! (`agents/tests/fuzz_corpus.rs`) and `fuzz/fuzz_targets/*.rs` stay one-liners.
#![allow(clippy::panic)]

use crate::ses::shared::SharedForm;

/// `ses_shared_form`: parse any bytes as a shared form; must never panic. When the bytes
/// parse, asserts the round trip: re-encoding succeeds, the re-encoding parses back to the
/// same form, and it equals the input except for the CRC (which fuzz builds do not check).
///
/// A decoded form is also handed to a [`ScooterBrain`](crate::mission::scooter::ScooterBrain)
/// with a target, as Skeeter's SES sample would be: the brain's next command must be finite.
pub fn ses_shared_form(data: &[u8]) {
    let Ok(form) = SharedForm::decode(data) else {
        return;
    };
    scooter_takes(&form);
    let bytes = match form.to_bytes() {
        Ok(b) => b,
        Err(e) => panic!("a decoded form must re-encode: {e}"),
    };
    let again = SharedForm::decode(&bytes);
    assert_eq!(
        again.as_ref(),
        Ok(&form),
        "decode(encode(decode(x))) != decode(x)"
    );
    let body = |b: &[u8]| {
        b.len()
            .checked_sub(2)
            .and_then(|n| b.get(..n))
            .map(<[u8]>::to_vec)
    };
    assert_eq!(body(&bytes), body(data), "re-encoding changed the body");
}

/// Feeds a received SES form to a Scooter brain that is looking for `red` and steps it.
fn scooter_takes(form: &SharedForm) {
    use crate::mission::scooter::{ScooterBrain, ScooterConfig};
    use ima_hal::Instant;
    let mut brain = ScooterBrain::new(ScooterConfig::default());
    let t0 = Instant::from_millis(1_000);
    brain.set_target("red", t0);
    let _ = brain.handle_ses(form, t0);
    for ms in [1_100, 1_200, 6_000] {
        let out = brain.step(Instant::from_millis(ms));
        assert!(
            out.command.v_m_s.is_finite() && out.command.omega_rad_s.is_finite(),
            "non-finite command {:?}",
            out.command
        );
    }
}

/// A broadcast message as the mission sees it: typed conversion, then both brains hear it.
fn mission_hears(msg: &crate::peer::wire::Msg) {
    use crate::mission::msg::Broadcast;
    use crate::mission::scooter::{ScooterBrain, ScooterConfig};
    use crate::mission::skeeter::{SkeeterBrain, SkeeterConfig};
    use ima_hal::Instant;
    let Ok(b) = Broadcast::from_wire(msg) else {
        return;
    };
    let now = Instant::from_millis(1_000);
    let mut scooter = ScooterBrain::new(ScooterConfig::default());
    let _ = scooter.handle_broadcast(&b, now);
    let out = scooter.step(Instant::from_millis(1_100));
    assert!(out.command.v_m_s.is_finite() && out.command.omega_rad_s.is_finite());
    if let Ok(mut skeeter) = SkeeterBrain::new(SkeeterConfig::default()) {
        skeeter.start(now);
        skeeter.handle_broadcast(&b, now);
        while skeeter.poll_output().is_some() {}
    }
}

/// Group key of the `peer_frames` target and its corpus.
pub const PEER_FUZZ_KEY: &[u8] = b"ima peer fuzz group key 32 bytes";

/// `peer_frames`: the first byte picks a mode, the rest is a byte stream. Must never panic.
///
/// 1. The whole rest is opened as one frame (every check: header, size, MAC, replay, body).
/// 2. If it parses without authentication, it is re-sealed with its own sender and counter:
///    that must succeed, open again to the same message, and give back the same header and
///    body bytes (the encoding is canonical).
/// 3. The rest is cut into frames with [`frame_len`](crate::peer::wire::frame_len) and fed
///    to a manager (session 1), a client, a broadcast receiver and both ends of a data
///    session, with timeouts in between.
///    With mode bit 0 set, every frame that parses is first re-sealed with the group key, so
///    the fuzzer reaches the state machines with authenticated messages.
pub fn peer_frames(data: &[u8]) {
    use crate::peer::broadcast::{BroadcastReceiver, ReceiverConfig};
    use crate::peer::client::{ClientConfig, PeerClient};
    use crate::peer::data::{DataClientSession, DataConfig, DataServerSession};
    use crate::peer::manager::{FixedSelfAgent, ManagerConfig, PeerManager};
    use crate::peer::wire::{
        DEFAULT_MAX_BODY, GroupKey, HEADER_LEN, Signer, SourceInfo, Verifier, frame_len,
        parse_unauthenticated,
    };
    use ima_hal::Instant;

    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let Some(key) = GroupKey::new(PEER_FUZZ_KEY) else {
        panic!("fuzz key too short");
    };
    let _ = Verifier::new(key.clone()).open(rest);
    if let Ok(o) = parse_unauthenticated(rest, DEFAULT_MAX_BODY) {
        mission_hears(&o.msg);
        let f = match Signer::new(key.clone(), o.sender, o.counter).seal_vec(&o.msg) {
            Ok(f) => f,
            Err(e) => panic!("a parsed message must re-seal: {e}"),
        };
        assert_eq!(Verifier::new(key.clone()).open(&f).as_ref(), Ok(&o));
        let signed = HEADER_LEN + (f.len() - HEADER_LEN - crate::peer::wire::MAC_LEN);
        assert_eq!(
            f.get(..signed),
            rest.get(..signed),
            "encoding not canonical"
        );
    }

    let src = |n: &str| SourceInfo {
        name: n.into(),
        kind: n.into(),
        schema: 1,
        rate_mhz: 1000,
    };
    let agent = FixedSelfAgent::new(mode >> 4, vec![src("ses"), src("sonar")]);
    let mut mcfg = ManagerConfig::new("skeeter", 1, "127.0.0.1:1");
    mcfg.max_grants_per_source = usize::from(mode >> 1 & 3) + 1;
    let mut m = PeerManager::new(mcfg, key.clone(), [1; 32], agent, Instant::ZERO);
    m.connect(1, Instant::ZERO);
    let mut c = PeerClient::new(
        ClientConfig::new("scooter", 2, 3),
        key.clone(),
        Instant::ZERO,
    );
    let _ = c.register();
    let mut rx = BroadcastReceiver::new(key.clone(), ReceiverConfig::default());
    let mut ds = DataServerSession::new(DataConfig::new(4), key.clone(), Instant::ZERO);
    let mut dc = DataClientSession::new(
        DataConfig::new(5),
        key.clone(),
        6,
        "ses",
        [0; 32],
        Instant::ZERO,
    );
    let mut resealer = Signer::new(key, 9, 1);
    let mut buf = vec![0u8; 70_000];
    let mut now = Instant::ZERO;
    let mut stream = rest;
    while let Ok(Some(n)) = frame_len(stream, DEFAULT_MAX_BODY) {
        let Some((frame, tail)) = stream.split_at_checked(n) else {
            break;
        };
        stream = tail;
        let owned;
        let frame = if mode & 1 == 1 {
            match parse_unauthenticated(frame, DEFAULT_MAX_BODY)
                .ok()
                .and_then(|o| resealer.seal_vec(&o.msg).ok())
            {
                Some(f) => {
                    owned = f;
                    &owned[..]
                }
                None => frame,
            }
        } else {
            frame
        };
        now = now + core::time::Duration::from_millis(u64::from(frame.len() as u8 % 64));
        if m.session_count() == 0 {
            m.connect(1, now);
        }
        m.handle_frame(1, frame, now);
        c.handle_frame(frame, now);
        let _ = rx.handle_datagram(frame, now);
        ds.handle_frame(frame, &mut m, now);
        ds.offer(now.as_micros(), frame);
        dc.handle_frame(frame, now);
        ds.handle_timeout(now);
        dc.handle_timeout(now);
        while ds.poll_transmit(&mut buf, now).is_some() {}
        while dc.poll_transmit(&mut buf, now).is_some() {}
        while ds.poll_event().is_some() || dc.poll_event().is_some() {}
        while dc.pop_sample().is_some() {}
        m.handle_timeout(now);
        c.handle_timeout(now);
        while m.poll_transmit(&mut buf).is_some() {}
        while m.poll_event().is_some() {}
        while c.poll_transmit(&mut buf).is_some() {}
        while c.poll_event().is_some() {}
        let _ = m.status();
    }
}
