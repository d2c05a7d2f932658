//! Property tests: emit → parse round trips for every message of both dialects, and the
//! framers never lose a good reply behind noise.

use ima_video_mux::framer::{Frame, KramerFramer, LineFramer};
use ima_video_mux::wire::{
    ExtronCommand, ExtronError, ExtronReply, Instruction, KramerMessage, Signals, TieKind,
};
use proptest::prelude::*;

fn kind() -> impl Strategy<Value = TieKind> {
    prop_oneof![
        Just(TieKind::All),
        Just(TieKind::Video),
        Just(TieKind::Audio)
    ]
}

fn command() -> impl Strategy<Value = ExtronCommand> {
    prop_oneof![
        (any::<u16>(), kind()).prop_map(|(input, kind)| ExtronCommand::Select { input, kind }),
        (any::<u16>(), any::<u16>(), kind()).prop_map(|(input, output, kind)| {
            ExtronCommand::Tie {
                input,
                output,
                kind,
            }
        }),
        Just(ExtronCommand::QueryInput),
        Just(ExtronCommand::SignalStatus),
        any::<bool>().prop_map(ExtronCommand::VideoMute),
    ]
}

fn digits(n: u16) -> u8 {
    n.to_string().len() as u8
}

fn reply() -> impl Strategy<Value = ExtronReply> {
    prop_oneof![
        (any::<u16>(), kind(), 0u8..=5).prop_map(|(input, kind, d)| ExtronReply::Input {
            input,
            kind,
            digits: d.max(digits(input)),
        }),
        (any::<u16>(), any::<u16>(), kind()).prop_map(|(output, input, kind)| {
            ExtronReply::Tie {
                output,
                input,
                kind,
            }
        }),
        any::<u16>().prop_map(ExtronReply::Current),
        (1u8..=32, any::<u32>()).prop_map(|(count, mask)| {
            let mask = if count == 32 {
                mask
            } else {
                mask & ((1 << count) - 1)
            };
            ExtronReply::Signals(Signals { mask, count })
        }),
        any::<bool>().prop_map(ExtronReply::Mute),
        (0u8..=99).prop_map(|c| ExtronReply::Error(ExtronError::from_code(c))),
        Just(ExtronReply::Banner),
        (
            any::<u16>(),
            any::<u16>(),
            proptest::option::of(0u8..=9),
            proptest::option::of(any::<bool>()),
            proptest::option::of(any::<bool>()),
        )
            .prop_map(|(video, audio, mode, video_mute, audio_mute)| {
                ExtronReply::Information {
                    video,
                    audio,
                    mode,
                    video_mute,
                    audio_mute,
                }
            }),
        (any::<u16>(), 0u8..=99)
            .prop_map(|(major, hundredths)| ExtronReply::Firmware { major, hundredths }),
        any::<u8>().prop_map(ExtronReply::Verbose),
    ]
}

fn kramer() -> impl Strategy<Value = KramerMessage> {
    (0u8..64, any::<bool>(), 0u8..128, 0u8..128, 0u8..128).prop_map(
        |(code, from_switcher, input, output, machine)| KramerMessage {
            instruction: Instruction::from_code(code),
            from_switcher,
            input,
            output,
            machine,
        },
    )
}

proptest! {
    #[test]
    fn extron_command_round_trip(c in command()) {
        let mut buf = [0u8; 16];
        let n = c.emit(&mut buf).unwrap();
        prop_assert_eq!(ExtronCommand::command_end(&buf[..n]), Some(n));
        prop_assert_eq!(ExtronCommand::parse(&buf[..n]), Ok(c));
    }

    #[test]
    fn extron_reply_round_trip(r in reply()) {
        let mut buf = [0u8; 96];
        let n = r.emit(&mut buf).unwrap();
        prop_assert_eq!(&buf[n - 2..n], b"\r\n");
        prop_assert_eq!(ExtronReply::parse(&buf[..n]), Ok(r));
    }

    #[test]
    fn kramer_round_trip(m in kramer()) {
        let mut buf = [0u8; 4];
        prop_assert_eq!(m.emit(&mut buf), Ok(4));
        prop_assert_eq!(KramerMessage::parse(&buf), Ok(m));
    }

    /// After any noise and a line break, a good reply is delivered, whatever the chunking.
    #[test]
    fn extron_framer_never_loses_a_reply(
        items in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..120), reply()), 1..6),
        chunk in 1usize..17,
    ) {
        let mut stream = Vec::new();
        let mut want = Vec::new();
        for (noise, r) in &items {
            stream.extend_from_slice(noise);
            stream.extend_from_slice(b"\r\n");
            let mut buf = [0u8; 96];
            let n = r.emit(&mut buf).unwrap();
            stream.extend_from_slice(&buf[..n]);
            want.push(buf[..n - 2].to_vec());
        }
        let mut fr = LineFramer::<96>::default();
        let mut got = Vec::new();
        for c in stream.chunks(chunk) {
            fr.push(c, |f| if let Frame::Line(l) = f { got.push(l.to_vec()) });
        }
        let mut it = got.iter();
        for w in &want {
            prop_assert!(it.any(|g| g == w), "lost {:?}", String::from_utf8_lossy(w));
        }
    }

    /// Any noise before a good Protocol 2000 message: the message is delivered.
    #[test]
    fn kramer_framer_never_loses_a_message(
        items in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..12), kramer()), 1..8),
        chunk in 1usize..9,
    ) {
        let mut stream = Vec::new();
        let mut want = Vec::new();
        for (noise, m) in &items {
            stream.extend_from_slice(noise);
            let b = m.to_bytes().unwrap();
            stream.extend_from_slice(&b);
            want.push(b);
        }
        let mut fr = KramerFramer::new();
        let mut got = Vec::new();
        for c in stream.chunks(chunk) {
            fr.push(c, |m| got.push(m));
        }
        let mut it = got.iter();
        for w in &want {
            prop_assert!(it.any(|g| g == w), "lost {:02x?}", w);
        }
    }
}

/// The answers to the SIS information requests the mock gives (`I`, `Q`, `ESC 3CV`), and a
/// model's longer `I` answer (MTP SW6: `Exe`, not kept); a banner that starts with a digit
/// is still a banner.
#[test]
fn information_firmware_and_verbose_replies() {
    assert_eq!(
        ExtronReply::parse(b"V3 A3 F1 Vmt0 Amt0\r\n"),
        Ok(ExtronReply::Information {
            video: 3,
            audio: 3,
            mode: Some(1),
            video_mute: Some(false),
            audio_mute: Some(false),
        })
    );
    assert_eq!(
        ExtronReply::parse(b"V2 A5 F2 Vmt1 Amt0 Exe1"),
        Ok(ExtronReply::Information {
            video: 2,
            audio: 5,
            mode: Some(2),
            video_mute: Some(true),
            audio_mute: Some(false),
        })
    );
    assert_eq!(
        ExtronReply::parse(b"1.23"),
        Ok(ExtronReply::Firmware {
            major: 1,
            hundredths: 23
        })
    );
    assert_eq!(ExtronReply::parse(b"Vrb3"), Ok(ExtronReply::Verbose(3)));
    assert_eq!(
        ExtronReply::parse(b"2002 Extron Electronics"),
        Ok(ExtronReply::Banner)
    );
    assert!(ExtronReply::parse(b"1.2").is_err());
    assert!(ExtronReply::parse(b"V3").is_err());
}
