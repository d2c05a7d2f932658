//! Property tests: emit → parse round trips for every message, and the framer never loses a
//! good line behind noise.

use ima_compass::framer::{self, Frame};
use ima_compass::wire::{
    CalScore, Command, Decimal, EastWest, Hdg, Hdm, Hdt, KvhBaud, KvhCommand, KvhFormat, Line,
    NmeaBody, NmeaSentence, Offset, ParseOptions, Talker, Tcm2Command, Tcm2Data, Tcm2Format,
};
use proptest::prelude::*;

fn decimal() -> impl Strategy<Value = Decimal> {
    (-9_999_999i64..=9_999_999, 0u8..=4, 0u8..=5).prop_filter_map("too many digits", |(u, d, i)| {
        Decimal::with_int_digits(u, d, i)
    })
}

fn offset() -> impl Strategy<Value = Offset> {
    (decimal(), any::<bool>()).prop_map(|(degrees, east)| Offset {
        degrees,
        dir: if east { EastWest::East } else { EastWest::West },
    })
}

fn sentence() -> impl Strategy<Value = NmeaSentence> {
    let talker = (b'A'..=b'Z', b'A'..=b'Z').prop_map(|(a, b)| Talker([a, b]));
    let body = prop_oneof![
        (
            proptest::option::of(decimal()),
            proptest::option::of(offset()),
            proptest::option::of(offset())
        )
            .prop_map(|(heading, deviation, variation)| NmeaBody::Hdg(Hdg {
                heading,
                deviation,
                variation
            })),
        proptest::option::of(decimal()).prop_map(|heading| NmeaBody::Hdm(Hdm { heading })),
        proptest::option::of(decimal()).prop_map(|heading| NmeaBody::Hdt(Hdt { heading })),
    ];
    (talker, body).prop_map(|(talker, body)| NmeaSentence { talker, body })
}

fn tcm2() -> impl Strategy<Value = Tcm2Data> {
    let d = || proptest::option::of(decimal());
    (
        d(),
        d(),
        d(),
        d(),
        d(),
        d(),
        d(),
        proptest::option::of(any::<u16>()),
    )
        .prop_map(
            |(heading, pitch, roll, bx, by, bz, temperature, error)| Tcm2Data {
                heading,
                pitch,
                roll,
                bx,
                by,
                bz,
                temperature,
                error,
            },
        )
        .prop_filter("at least one field", |d| *d != Tcm2Data::default())
}

fn cal_score() -> impl Strategy<Value = CalScore> {
    (0u8..=9, 0u8..=9, decimal()).prop_map(|(h, v, m)| CalScore { h, v, m })
}

fn line() -> impl Strategy<Value = Line> {
    prop_oneof![
        sentence().prop_map(Line::Nmea),
        tcm2().prop_map(Line::Tcm2),
        cal_score().prop_map(Line::CalScore),
        Just(Line::Prompt),
    ]
}

fn command() -> impl Strategy<Value = Command> {
    use Tcm2Command as T;
    prop_oneof![
        prop_oneof![
            Just(KvhFormat::Nmea),
            Just(KvhFormat::Kvh),
            Just(KvhFormat::CorrectedXy),
            Just(KvhFormat::UncorrectedXy)
        ]
        .prop_map(|f| Command::Kvh(KvhCommand::OutputFormat(f))),
        any::<u16>().prop_map(|per_minute| Command::Kvh(KvhCommand::Rate { per_minute })),
        prop_oneof![Just(KvhBaud::B4800), Just(KvhBaud::B9600)]
            .prop_map(|b| Command::Kvh(KvhCommand::Baud(b))),
        any::<u8>().prop_map(|n| Command::Tcm2(T::SampleRate(n))),
        any::<bool>().prop_map(|b| Command::Tcm2(T::AutoCalibration(b))),
        prop_oneof![
            Just(T::Halt),
            Just(T::Go),
            Just(T::QueryOutput),
            Just(T::QueryCompass),
            Just(T::OutputFormat(Tcm2Format::Standard)),
            Just(T::OutputFormat(Tcm2Format::Nmea)),
            Just(T::OutputFormat(Tcm2Format::Mouse)),
            Just(T::ClearCalibration),
            Just(T::UserCalibrationOn),
            Just(T::UserCalibrationOff),
        ]
        .prop_map(Command::Tcm2),
    ]
}

const STRICT: ParseOptions = ParseOptions {
    allow_missing_checksum: false,
};

proptest! {
    #[test]
    fn line_round_trip(l in line()) {
        let mut buf = [0u8; 160];
        let n = l.emit(&mut buf).unwrap();
        prop_assert_eq!(Line::parse(&buf[..n], &STRICT), Ok(l));
    }

    #[test]
    fn command_round_trip(c in command()) {
        let mut buf = [0u8; 16];
        let n = c.emit(&mut buf).unwrap();
        prop_assert_eq!(buf[n - 1], b'\r');
        prop_assert_eq!(Command::parse(&buf[..n]), Ok(c));
    }

    #[test]
    fn decimal_value_matches_text(d in decimal()) {
        let mut buf = [0u8; 40];
        let n = Line::Tcm2(Tcm2Data { heading: Some(d), ..Tcm2Data::default() })
            .emit(&mut buf)
            .unwrap();
        // "$C<number>*hh\r\n"
        let text = std::str::from_utf8(&buf[2..n - 5]).unwrap();
        let v: f64 = text.parse().unwrap();
        prop_assert!((v - d.to_f64()).abs() <= 1e-9 * v.abs().max(1.0));
    }

    /// Good sentences survive any noise between them and any chunking: each one is
    /// delivered, in order.
    #[test]
    fn framer_never_loses_a_good_line(
        items in proptest::collection::vec(
            (proptest::collection::vec(any::<u8>(), 0..40), sentence()), 1..6),
        chunk in 1usize..17,
    ) {
        let mut stream = Vec::new();
        let mut want = Vec::new();
        for (noise, s) in &items {
            stream.extend_from_slice(noise);
            let mut buf = [0u8; 96];
            let n = s.emit(&mut buf).unwrap();
            stream.extend_from_slice(&buf[..n]);
            want.push(buf[..n - 2].to_vec());
        }
        let mut fr = framer::framer::<96>();
        let mut got = Vec::new();
        for c in stream.chunks(chunk) {
            fr.push(c, |f| if let Frame::Line(l) = f { got.push(l.to_vec()) });
        }
        // `want` is a subsequence of `got` (noise may add lines of its own).
        let mut it = got.iter();
        for w in &want {
            prop_assert!(it.any(|g| g == w), "lost {:?}", String::from_utf8_lossy(w));
        }
    }
}
