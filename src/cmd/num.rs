//! Range-checked numeric flags: every number the command line takes goes through one of these
//! parsers, so NaN, infinities and absurd magnitudes are refused at parse time with a message
//! naming the accepted range (clap adds the flag's name), and no later `Duration` conversion,
//! allocation or speed can be out of range.

use std::time::Duration;

/// The longest duration any flag accepts: one day.
pub const MAX_SECONDS: f64 = 86_400.0;

fn number(s: &str) -> Result<f64, String> {
    let v: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(format!("{s} is not a finite number"))
    }
}

fn within(s: &str, lo: f64, hi: f64, unit: &str) -> Result<f64, String> {
    let v = number(s).map_err(|e| format!("{e} (accepted: {lo}–{hi}{unit})"))?;
    if (lo..=hi).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{} is out of range: {lo}–{hi}{unit}", s.trim()))
    }
}

/// A duration in seconds, 0 to one day.
pub fn seconds(s: &str) -> Result<f64, String> {
    within(s, 0.0, MAX_SECONDS, " s")
}

/// A timeout in seconds: more than zero, at most one hour.
pub fn timeout_seconds(s: &str) -> Result<f64, String> {
    const ACCEPTED: &str = "more than 0, at most 3600 s";
    let v = number(s).map_err(|e| format!("{e} (accepted: {ACCEPTED})"))?;
    if v <= 0.0 {
        Err("a timeout must be more than 0 s".into())
    } else if v > 3_600.0 {
        Err(format!("{} is out of range: {ACCEPTED}", s.trim()))
    } else {
        Ok(v)
    }
}

/// A forward speed in m/s, −10 to 10 (a robot's own maximum caps it further, with a warning).
pub fn speed_m_s(s: &str) -> Result<f64, String> {
    within(s, -10.0, 10.0, " m/s")
}

/// A turn rate in rad/s, −10 to 10 (capped further by the robot's maximum, with a warning).
pub fn turn_rad_s(s: &str) -> Result<f64, String> {
    within(s, -10.0, 10.0, " rad/s")
}

/// A simulated world's time factor: from 20 times slower (0.05) to 20 times faster than real
/// time. (A factor near 0 froze the world, and below about 1e-290 overflowed a `Duration`.)
pub fn time_factor(s: &str) -> Result<f64, String> {
    within(s, 0.05, 20.0, "×")
}

/// A cruise velocity in m/s: more than 0, at most 1.
pub fn cruise_m_s(s: &str) -> Result<f64, String> {
    positive_up_to(s, 1.0, " m/s")
}

/// A mission timeout in seconds: more than 0, at most one day.
pub fn mission_seconds(s: &str) -> Result<f64, String> {
    positive_up_to(s, MAX_SECONDS, " s")
}

/// A length in metres for a test drive: more than 0, at most 3.
pub fn side_m(s: &str) -> Result<f64, String> {
    positive_up_to(s, 3.0, " m")
}

/// An angle in degrees, −360 to 360.
pub fn degrees(s: &str) -> Result<f64, String> {
    within(s, -360.0, 360.0, "°")
}

/// A camera's field of view in degrees: 1 to 179.
pub fn fov_degrees(s: &str) -> Result<f64, String> {
    within(s, 1.0, 179.0, "°")
}

/// A short delay in seconds: 0 to 10.
pub fn short_seconds(s: &str) -> Result<f64, String> {
    within(s, 0.0, 10.0, " s")
}

fn positive_up_to(s: &str, hi: f64, unit: &str) -> Result<f64, String> {
    let v = number(s).map_err(|e| format!("{e} (accepted: more than 0, at most {hi}{unit})"))?;
    if v > 0.0 && v <= hi {
        Ok(v)
    } else {
        Err(format!(
            "{} is out of range: more than 0, at most {hi}{unit}",
            s.trim()
        ))
    }
}

/// An rFLEX conversion factor (`--kd`, `--ka`): within a quarter and four times the
/// ATRV-Jr's (`default`, `name` saying what it is). Every speed is sent as speed × factor and
/// every odometry reading divided by it, so a wrong factor scales the robot's true speed,
/// the speed cap with it, and the readout hides it (one extra digit in `--kd`: 3 m/s sent
/// for a capped 0.3 m/s, shown as 0.1 m/s).
fn rflex_factor(s: &str, default: f64, name: &str) -> Result<f64, String> {
    let (lo, hi) = (default / 4.0, default * 4.0);
    let v = number(s).map_err(|e| format!("{e} (accepted: {lo}–{hi})"))?;
    if (lo..=hi).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "{} is not a plausible {name}: an rFLEX base's is near the ATRV-Jr's {default} \
             ({lo}–{hi} accepted); a wrong factor scales every speed sent, the speed cap with \
             it, and the odometry shown",
            s.trim()
        ))
    }
}

/// `--kd`: translation units per metre ([`rflex_factor`]).
pub fn rflex_kd(s: &str) -> Result<f64, String> {
    rflex_factor(s, 90_810.0, "translation factor (units per metre)")
}

/// `--ka`: rotation units per radian ([`rflex_factor`]).
pub fn rflex_ka(s: &str) -> Result<f64, String> {
    rflex_factor(s, 37_000.0, "rotation factor (units per radian)")
}

/// A replay's pace: 0 (as fast as it goes), or 0.001 to 1000 times the recorded pace.
pub fn replay_speed(s: &str) -> Result<f64, String> {
    const ACCEPTED: &str = "0 for no pacing, or 0.001–1000×";
    let v = number(s).map_err(|e| format!("{e} (accepted: {ACCEPTED})"))?;
    if v == 0.0 || (0.001..=1000.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{} is out of range: {ACCEPTED}", s.trim()))
    }
}

/// A serial line speed in baud, 50 to 4,000,000.
pub fn baud(s: &str) -> Result<u32, String> {
    let t = s.trim();
    if !is_whole(t) {
        return Err(format!(
            "{t:?} is not a line speed in baud (accepted: a whole number, 50–4000000)"
        ));
    }
    int_in::<u32, 50, 4_000_000>(t).map_err(|e| format!("{e} baud"))
}

/// A whole number in `LO..=HI`, as any integer type that holds the range. A whole number
/// outside it, negative or too large for any integer type, is "out of range"; anything else
/// is "not a whole number" (both said "not a whole number in …" for `-1`).
pub fn int_in<T, const LO: u64, const HI: u64>(s: &str) -> Result<T, String>
where
    T: TryFrom<u64>,
{
    let t = s.trim();
    let out = || format!("{t} is out of range: {LO}–{HI}");
    match t.parse::<u64>() {
        Ok(v) if (LO..=HI).contains(&v) => T::try_from(v).map_err(|_| out()),
        Ok(_) => Err(out()),
        Err(_) if is_whole(t) => Err(out()),
        Err(_) => Err(format!("{t:?} is not a whole number (accepted: {LO}–{HI})")),
    }
}

/// Whether `t` is a whole number in decimal, of any sign or size.
fn is_whole(t: &str) -> bool {
    let digits = t.strip_prefix(['-', '+']).unwrap_or(t);
    !digits.is_empty() && digits.bytes().all(|b| b.is_ascii_digit())
}

/// A seed for a random source: any whole number 0–18446744073709551615.
pub fn seed(s: &str) -> Result<u64, String> {
    int_in::<u64, 0, { u64::MAX }>(s)
}

/// Text a Peer frame carries (a behaviour, a colour, an emergency's text): at most
/// [`MAX_STR_LEN`](ima_agents::peer::wire::MAX_STR_LEN) bytes of UTF-8.
pub fn wire_text(s: &str) -> Result<String, String> {
    let max = ima_agents::peer::wire::MAX_STR_LEN;
    if s.len() > max {
        return Err(format!(
            "{} bytes is too long: a broadcast carries at most {max} bytes",
            s.len()
        ));
    }
    Ok(s.to_owned())
}

/// A robot's name as broadcasts carry it: 1 to 255 bytes (an empty one names no robot, and
/// `--wait-for ""` waited for one that cannot exist).
pub fn robot_name(s: &str) -> Result<String, String> {
    if s.trim().is_empty() {
        return Err("an empty name names no robot".into());
    }
    wire_text(s)
}

/// A target colour of a `--targets` list, without the blanks around it (`--targets "red,
/// blue"` refused " blue" as an unknown colour); an empty one is refused as such (`--targets
/// ""` said `unknown target colour ""`). Whether the colour is known is checked later,
/// against the colour database.
pub fn target_colour(s: &str) -> Result<String, String> {
    let c = s.trim();
    if c.is_empty() {
        return Err("an empty colour: give colours separated by commas, e.g. red,blue".into());
    }
    Ok(c.to_owned())
}

/// Seconds within `[0.1, 3600]` (liveness and similar periods).
pub fn period_seconds(s: &str) -> Result<f64, String> {
    within(s, 0.1, 3_600.0, " s")
}

/// A duration for `Duration::from_secs_f64` that cannot panic (values come from the parsers
/// above; anything else is clamped to 0–[`MAX_SECONDS`]).
#[must_use]
pub fn duration(secs: f64) -> Duration {
    if secs.is_finite() {
        Duration::from_secs_f64(secs.clamp(0.0, MAX_SECONDS))
    } else {
        Duration::ZERO
    }
}

/// Clamp a speed to a robot's maximum, warning on stderr when it had to.
#[must_use]
pub fn cap(flag: &str, value: f64, max: f64, unit: &str) -> f64 {
    if max.is_finite() && max > 0.0 && value.abs() > max {
        let capped = value.clamp(-max, max);
        eprintln!(
            "warning: {flag} {value} {unit} is beyond this robot's maximum of ±{max:.3} {unit}; using {capped:.3}"
        );
        capped
    } else {
        value
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_parser_refuses_nan_infinities_and_huge_values() {
        type Parser = fn(&str) -> Result<f64, String>;
        let parsers: [Parser; 7] = [
            seconds,
            timeout_seconds,
            speed_m_s,
            turn_rad_s,
            rflex_kd,
            rflex_ka,
            number,
        ];
        for p in parsers {
            for bad in ["NaN", "nan", "inf", "-inf", "infinity", "1e400", "x", ""] {
                assert!(p(bad).is_err(), "{bad} accepted");
            }
        }
        for p in &parsers[..6] {
            assert!(p("1e30").is_err());
            assert!(p("-1e30").is_err());
            // NaN is refused with the range, as an absurd value is.
            for bad in ["NaN", "x"] {
                let e = p(bad).unwrap_err();
                assert!(e.contains("(accepted: "), "{bad}: {e}");
            }
        }
        let e = cruise_m_s("NaN").unwrap_err();
        assert_eq!(
            e,
            "NaN is not a finite number (accepted: more than 0, at most 1 m/s)"
        );
        assert_eq!(
            speed_m_s("inf").unwrap_err(),
            "inf is not a finite number (accepted: -10–10 m/s)"
        );
        assert_eq!(
            timeout_seconds("x").unwrap_err(),
            "\"x\" is not a number (accepted: more than 0, at most 3600 s)"
        );
        assert_eq!(
            timeout_seconds("4000").unwrap_err(),
            "4000 is out of range: more than 0, at most 3600 s"
        );
    }

    #[test]
    fn ranges_and_messages() {
        assert_eq!(seconds("2.5"), Ok(2.5));
        assert!(seconds("-1").unwrap_err().contains("0–86400 s"));
        assert_eq!(
            timeout_seconds("0").unwrap_err(),
            "a timeout must be more than 0 s"
        );
        assert_eq!(speed_m_s("-0.2"), Ok(-0.2));
        assert!(speed_m_s("11").is_err());
        assert!(rflex_kd("0").is_err());
        assert_eq!(rflex_kd("90810"), Ok(90_810.0));
        assert_eq!(rflex_kd("45405"), Ok(45_405.0));
        let e = rflex_kd("908100").unwrap_err();
        assert!(
            e.contains("not a plausible translation factor") && e.contains("22702.5–363240"),
            "{e}"
        );
        assert!(rflex_ka("370000").is_err());
        assert_eq!(rflex_ka("9250"), Ok(9_250.0));
        assert_eq!(int_in::<u8, 1, 7>("7"), Ok(7));
        assert!(int_in::<u8, 1, 7>("8").unwrap_err().contains("1–7"));
        assert!(int_in::<u8, 0, 300>("300").is_err(), "does not fit a u8");
        assert!(int_in::<u64, 0, 5>("-1").is_err());
        assert!(int_in::<u64, 0, 5>("1e30").is_err());
        // A whole number is out of range, whatever its sign or size; a word is not one.
        for (v, want) in [
            ("-1", "-1 is out of range: 1–64"),
            (
                "99999999999999999999999",
                "99999999999999999999999 is out of range: 1–64",
            ),
            ("4294967296", "4294967296 is out of range: 1–64"),
            ("x", "\"x\" is not a whole number (accepted: 1–64)"),
            ("1.5", "\"1.5\" is not a whole number (accepted: 1–64)"),
            ("-", "\"-\" is not a whole number (accepted: 1–64)"),
        ] {
            assert_eq!(int_in::<u32, 1, 64>(v), Err(want.to_owned()));
        }
        assert_eq!(seed(&u64::MAX.to_string()), Ok(u64::MAX));
        assert!(
            seed("nan")
                .unwrap_err()
                .contains("(accepted: 0–18446744073709551615)")
        );
        assert_eq!(period_seconds("5"), Ok(5.0));
        assert_eq!(wire_text("idle"), Ok("idle".to_owned()));
        assert_eq!(robot_name("scooter"), Ok("scooter".to_owned()));
        assert!(robot_name(" ").unwrap_err().contains("names no robot"));
        assert_eq!(target_colour(" blue "), Ok("blue".to_owned()));
        assert!(target_colour("").unwrap_err().contains("an empty colour"));
        assert!(
            wire_text(&"é".repeat(128))
                .unwrap_err()
                .contains("256 bytes")
        );
        assert!(time_factor("0").unwrap_err().contains("0.05–20×"));
        assert!(time_factor("1e-300").is_err());
        assert_eq!(time_factor("0.05"), Ok(0.05));
        assert_eq!(time_factor("20"), Ok(20.0));
        assert!(time_factor("20.5").is_err());
        assert!(fov_degrees("180").is_err());
        assert!(short_seconds("-1").is_err());
        assert!(period_seconds("0").is_err());
        assert_eq!(duration(f64::NAN), Duration::ZERO);
        assert_eq!(duration(1e30), Duration::from_secs(86_400));
        assert!((cap("--vel", 3.0, 0.75, "m/s") - 0.75).abs() < 1e-12);
        assert!((cap("--vel", -3.0, 0.75, "m/s") + 0.75).abs() < 1e-12);
        assert!((cap("--vel", 0.5, 0.75, "m/s") - 0.5).abs() < 1e-12);
    }

    /// A line speed and a replay's pace name what they accept for a word as for a number
    /// out of range (they said only "a whole number" or gave examples).
    #[test]
    fn baud_and_replay_speed_name_their_ranges() {
        assert_eq!(baud(" 9600 "), Ok(9600));
        assert_eq!(
            baud("-5"),
            Err("-5 is out of range: 50–4000000 baud".to_owned())
        );
        assert_eq!(
            baud("49"),
            Err("49 is out of range: 50–4000000 baud".to_owned())
        );
        let e = baud("fast").unwrap_err();
        assert!(e.contains("(accepted: a whole number, 50–4000000)"), "{e}");
        assert_eq!(
            replay_speed(" 2 "),
            Ok(2.0),
            "spaces as every number flag takes them"
        );
        assert_eq!(replay_speed("0"), Ok(0.0));
        for bad in ["x", "NaN", "inf"] {
            let e = replay_speed(bad).unwrap_err();
            assert!(
                e.contains("(accepted: 0 for no pacing, or 0.001–1000×)"),
                "{e}"
            );
        }
        for bad in ["0.0001", "1001", "-1"] {
            let e = replay_speed(bad).unwrap_err();
            assert!(e.contains("is out of range: 0 for no pacing"), "{e}");
        }
    }
}
