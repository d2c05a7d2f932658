//! Property tests: emit → parse gives back every command and reply.

use ima_sick_lms::wire::*;
use proptest::prelude::*;

fn arb_baud() -> impl Strategy<Value = BaudRate> {
    prop_oneof![
        Just(BaudRate::B9600),
        Just(BaudRate::B19200),
        Just(BaudRate::B38400),
        Just(BaudRate::B500000),
    ]
}

fn arb_params() -> impl Strategy<Value = Params> {
    proptest::collection::vec(any::<u8>(), 0..=16).prop_map(|v| Params::from_slice(&v).unwrap())
}

fn arb_config() -> impl Strategy<Value = LmsConfig> {
    prop_oneof![
        proptest::collection::vec(any::<u8>(), 32),
        proptest::collection::vec(any::<u8>(), 34)
    ]
    .prop_map(|v| LmsConfig::from_bytes(&v).unwrap())
}

fn arb_mode() -> impl Strategy<Value = ModeRequest> {
    prop_oneof![
        any::<[u8; 8]>().prop_map(|password| ModeRequest::Installation { password }),
        Just(ModeRequest::Diagnostic),
        Just(ModeRequest::StreamAll),
        Just(ModeRequest::RequestOnly),
        any::<u8>().prop_map(|samples| ModeRequest::StreamMean { samples }),
        (any::<u16>(), any::<u16>())
            .prop_map(|(start, end)| ModeRequest::StreamSubrange { start, end }),
        (any::<u8>(), any::<u16>(), any::<u16>()).prop_map(|(samples, start, end)| {
            ModeRequest::MeanSubrange {
                samples,
                start,
                end,
            }
        }),
        Just(ModeRequest::StreamPartial),
        arb_baud().prop_map(ModeRequest::Baud),
        (
            any::<u8>().prop_filter("untyped", |c| !ModeRequest::is_typed_code(*c)),
            arb_params()
        )
            .prop_map(|(code, params)| ModeRequest::Other { code, params }),
    ]
}

fn arb_command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::Reset),
        arb_mode().prop_map(Command::SetMode),
        (any::<u8>(), arb_params())
            .prop_map(|(sub, params)| Command::RequestValues { sub, params }),
        Just(Command::Status),
        Just(Command::Errors),
        Just(Command::Type),
        (any::<u16>(), any::<u16>()).prop_map(|(angle_deg, res_centideg)| Command::Variant {
            angle_deg,
            res_centideg
        }),
        Just(Command::ReadConfig),
        arb_config().prop_map(Command::WriteConfig),
    ]
}

/// Owned material for a reply (replies borrow).
#[derive(Debug, Clone)]
enum Owned {
    Mode(u8, u8),
    Scan(u16, Vec<u16>, Option<(u8, u8)>, u8),
    Status(Vec<u8>, u8),
    Errors(Vec<u8>, u8),
    Type(Vec<u8>, u8),
    Variant(u8, u16, u16, u8),
    Config(LmsConfig, u8),
    Written(u8, LmsConfig, u8),
    PowerOn(Vec<u8>, u8),
    Reset(u8),
    Rejected(Vec<u8>, u8),
}

impl Owned {
    fn reply(&self) -> Reply<'_> {
        match self {
            Owned::Mode(result, s) => Reply::ModeChanged {
                result: *result,
                status: StatusByte(*s),
            },
            Owned::Scan(flags, v, idx, s) => Reply::Scan(Scan {
                count_word: CountWord((flags & !CountWord::COUNT_MASK) | v.len() as u16),
                values: Values::Words(v),
                indices: *idx,
                status: StatusByte(*s),
            }),
            Owned::Status(b, s) => Reply::Status {
                block: StatusBlock(b),
                status: StatusByte(*s),
            },
            Owned::Errors(b, s) => Reply::Errors {
                pairs: ErrorPairs::new(b).unwrap(),
                status: StatusByte(*s),
            },
            Owned::Type(t, s) => Reply::Type {
                text: t,
                status: StatusByte(*s),
            },
            Owned::Variant(a, b, c, s) => Reply::Variant {
                accepted: *a,
                angle_deg: *b,
                res_centideg: *c,
                status: StatusByte(*s),
            },
            Owned::Config(c, s) => Reply::Config {
                config: *c,
                status: StatusByte(*s),
            },
            Owned::Written(r, c, s) => Reply::ConfigWritten {
                result: *r,
                config: *c,
                status: StatusByte(*s),
            },
            Owned::PowerOn(t, s) => Reply::PowerOn {
                text: t,
                status: StatusByte(*s),
            },
            Owned::Reset(s) => Reply::ResetAck {
                status: StatusByte(*s),
            },
            Owned::Rejected(d, s) => Reply::Rejected {
                data: d,
                status: StatusByte(*s),
            },
        }
    }
}

fn arb_reply() -> impl Strategy<Value = Owned> {
    let s = any::<u8>();
    prop_oneof![
        (any::<u8>(), s).prop_map(|(r, s)| Owned::Mode(r, s)),
        (
            any::<u16>(),
            proptest::collection::vec(any::<u16>(), 0..=MAX_VALUES),
            proptest::option::of(any::<(u8, u8)>()),
            any::<u8>()
        )
            .prop_map(|(f, v, i, s)| Owned::Scan(f, v, i, s)),
        (proptest::collection::vec(any::<u8>(), 0..=200), any::<u8>())
            .prop_map(|(b, s)| Owned::Status(b, s)),
        (
            proptest::collection::vec(any::<(u8, u8)>(), 0..50),
            any::<u8>()
        )
            .prop_map(|(p, s)| {
                Owned::Errors(p.into_iter().flat_map(|(a, b)| [a, b]).collect(), s)
            }),
        (proptest::collection::vec(any::<u8>(), 0..40), any::<u8>())
            .prop_map(|(t, s)| Owned::Type(t, s)),
        any::<(u8, u16, u16, u8)>().prop_map(|(a, b, c, s)| Owned::Variant(a, b, c, s)),
        (arb_config(), any::<u8>()).prop_map(|(c, s)| Owned::Config(c, s)),
        (any::<u8>(), arb_config(), any::<u8>()).prop_map(|(r, c, s)| Owned::Written(r, c, s)),
        (proptest::collection::vec(any::<u8>(), 0..40), any::<u8>())
            .prop_map(|(t, s)| Owned::PowerOn(t, s)),
        any::<u8>().prop_map(Owned::Reset),
        (proptest::collection::vec(any::<u8>(), 0..8), any::<u8>())
            .prop_map(|(d, s)| Owned::Rejected(d, s)),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn command_emit_parse(c in arb_command(), addr in 0u8..0x80) {
        let mut buf = [0u8; 64];
        let n = c.emit_to(addr, &mut buf).unwrap();
        prop_assert_eq!(n, c.buffer_len());
        let frame = Frame::new_checked(&buf[..n]).unwrap();
        prop_assert_eq!(frame.address(), addr);
        prop_assert_eq!(Command::parse(&buf[..n]).unwrap(), c.clone());
        // Emitting to too small a buffer fails cleanly.
        let mut small = vec![0u8; n - 1];
        prop_assert_eq!(c.emit_to(addr, &mut small), Err(WireError::BufferTooSmall));
    }

    #[test]
    fn reply_emit_parse(o in arb_reply(), addr in 0x80u8..=0xFF) {
        let r = o.reply();
        let mut buf = [0u8; MAX_TELEGRAM];
        let n = r.emit_from(addr, &mut buf).unwrap();
        let back = Reply::parse(&buf[..n]).unwrap();
        prop_assert_eq!(back, r);
        prop_assert_eq!(back.status(), r.status());
        prop_assert_eq!(Frame::new_checked(&buf[..n]).unwrap().address(), addr);
        // And emit of the parsed view is byte-identical.
        let mut again = [0u8; MAX_TELEGRAM];
        let m = back.emit_from(addr, &mut again).unwrap();
        prop_assert_eq!(&again[..m], &buf[..n]);
    }

    #[test]
    fn any_single_bit_flip_is_caught(o in arb_reply(), bit in any::<prop::sample::Index>()) {
        let r = o.reply();
        let mut buf = [0u8; MAX_TELEGRAM];
        let n = r.emit(&mut buf).unwrap();
        let i = bit.index(n * 8);
        buf[i / 8] ^= 1 << (i % 8);
        // A flipped bit never parses back to the same reply.
        if let Ok(p) = Reply::parse(&buf[..n]) {
            prop_assert_ne!(p, r);
        }
    }

    #[test]
    fn parse_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..900)) {
        let _ = Reply::parse(&bytes);
        let _ = Command::parse(&bytes);
    }
}
