//! What a driver saw while it looked for its device: per line rate, how often it tried, how
//! many bytes came back and how many of them made valid frames.
//!
//! Drivers fill a [`ProbeReport`] while they connect (the SICK LMS and P2OS probe several
//! rates; the rFLEX and the compasses listen at one) and put it in the error they return when
//! nothing answered, so a failure can say *what* was seen: `received 1,204 bytes at 9600
//! baud, no valid frame` points at a wrong rate or a wrong device, `silence at every rate
//! tried (9600, 38400, 19200)` at a cable, a power switch or a wrong port.
//!
//! Sans-IO and `no_std` like the rest of the crate: the caller says which rate is on the line
//! and what it received; the report only counts.

use core::fmt;

/// Most rates a report keeps (P2OS probes 5, the SICK LMS 4); later rates are not counted.
pub const MAX_RATES: usize = 8;

/// What happened at one line rate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RateTally {
    /// The line rate, bits per second.
    pub baud: u32,
    /// Times the driver started a handshake or probe at this rate.
    pub attempts: u32,
    /// Bytes received at this rate.
    pub bytes: u64,
    /// Valid frames (checksum and syntax good) received at this rate.
    pub frames: u64,
    /// Frames that failed their checksum or did not parse.
    pub bad_frames: u64,
}

/// Per-rate counters of a connection attempt. See the [module docs](self).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ProbeReport {
    rates: heapless::Vec<RateTally, MAX_RATES>,
    current: Option<u32>,
}

impl ProbeReport {
    /// An empty report (nothing tried yet).
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    fn tally(&mut self, baud: u32) -> Option<&mut RateTally> {
        if !self.rates.iter().any(|t| t.baud == baud) {
            let _ = self.rates.push(RateTally {
                baud,
                ..RateTally::default()
            });
        }
        self.rates.iter_mut().find(|t| t.baud == baud)
    }

    /// The line is now at `baud` (later bytes and frames count there); no attempt is counted.
    pub fn set_rate(&mut self, baud: u32) {
        self.current = Some(baud);
        let _ = self.tally(baud);
    }

    /// An attempt starts at `baud` (the line is at that rate from now on).
    pub fn attempt(&mut self, baud: u32) {
        self.current = Some(baud);
        if let Some(t) = self.tally(baud) {
            t.attempts = t.attempts.saturating_add(1);
        }
    }

    /// `n` bytes arrived at the current rate.
    pub fn received(&mut self, n: usize) {
        if let Some(b) = self.current
            && let Some(t) = self.tally(b)
        {
            t.bytes = t.bytes.saturating_add(n as u64);
        }
    }

    /// `good` valid and `bad` invalid frames arrived at the current rate.
    pub fn framed(&mut self, good: u64, bad: u64) {
        if let Some(b) = self.current
            && let Some(t) = self.tally(b)
        {
            t.frames = t.frames.saturating_add(good);
            t.bad_frames = t.bad_frames.saturating_add(bad);
        }
    }

    /// The rate the line is at, if any was set.
    #[must_use]
    pub fn current(&self) -> Option<u32> {
        self.current
    }

    /// The tally of the current rate.
    #[must_use]
    pub fn current_tally(&self) -> Option<&RateTally> {
        let b = self.current?;
        self.rates.iter().find(|t| t.baud == b)
    }

    /// Every rate tried, in the order first tried.
    #[must_use]
    pub fn rates(&self) -> &[RateTally] {
        &self.rates
    }

    /// Bytes received at every rate.
    #[must_use]
    pub fn total_bytes(&self) -> u64 {
        self.rates.iter().map(|t| t.bytes).sum()
    }

    /// Valid frames received at every rate.
    #[must_use]
    pub fn total_frames(&self) -> u64 {
        self.rates.iter().map(|t| t.frames).sum()
    }
}

/// A count with thousands separators for messages: `Thousands(1204)` displays `1,204`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Thousands(pub u64);

impl fmt::Display for Thousands {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut groups = [0u16; 7];
        let mut n = self.0;
        let mut len = 0;
        loop {
            if let Some(g) = groups.get_mut(len) {
                *g = (n % 1000) as u16;
            }
            len += 1;
            n /= 1000;
            if n == 0 || len == groups.len() {
                break;
            }
        }
        for (i, g) in groups.iter().take(len).rev().enumerate() {
            if i == 0 {
                write!(f, "{g}")?;
            } else {
                write!(f, ",{g:03}")?;
            }
        }
        Ok(())
    }
}

/// What a line carried while a driver listened at one rate, for messages: `silence on the
/// line (base on? right port?)`, or `received 1,204 bytes, no valid frame (3 bad) (wrong
/// rate or wrong device?)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Heard {
    /// Bytes received.
    pub bytes: u64,
    /// Valid units (frames, lines) among them.
    pub valid: u64,
    /// Units dropped as bad.
    pub bad: u64,
    /// What a unit is called (`frame`, `line`).
    pub unit: &'static str,
    /// What to check when the line was silent (`base on? right port?`).
    pub silence_hint: &'static str,
}

impl fmt::Display for Heard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let Self {
            bytes,
            valid,
            bad,
            unit,
            silence_hint,
        } = *self;
        if bytes == 0 {
            return write!(f, "silence on the line ({silence_hint})");
        }
        write!(f, "received {} bytes, ", Thousands(bytes))?;
        match valid {
            0 => write!(f, "no valid {unit}")?,
            1 => write!(f, "1 valid {unit}")?,
            n => write!(f, "{n} valid {unit}s")?,
        }
        if bad > 0 {
            write!(f, " ({bad} bad)")?;
        }
        if valid == 0 {
            f.write_str(" (wrong rate or wrong device?)")?;
        }
        Ok(())
    }
}

fn list_rates<'a>(
    f: &mut fmt::Formatter<'_>,
    rates: impl Iterator<Item = &'a RateTally>,
) -> fmt::Result {
    for (i, t) in rates.enumerate() {
        if i > 0 {
            f.write_str(", ")?;
        }
        write!(f, "{}", t.baud)?;
    }
    Ok(())
}

impl fmt::Display for ProbeReport {
    /// `silence at every rate tried (9600, 38400, 19200)`, or one clause per rate that got
    /// bytes (`received 1,204 bytes at 9600 baud, no valid frame (3 bad)`) then `silence at
    /// 19200, 38400 baud`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.rates.is_empty() {
            return f.write_str("no rate was tried");
        }
        let silent = self.rates.iter().filter(|t| t.bytes == 0).count();
        if silent == self.rates.len() {
            if self.rates.len() == 1 {
                f.write_str("silence at ")?;
                list_rates(f, self.rates.iter())?;
                return f.write_str(" baud");
            }
            f.write_str("silence at every rate tried (")?;
            list_rates(f, self.rates.iter())?;
            return f.write_str(")");
        }
        let mut first = true;
        for t in self.rates.iter().filter(|t| t.bytes > 0) {
            if !first {
                f.write_str("; ")?;
            }
            first = false;
            let s = if t.bytes == 1 { "" } else { "s" };
            write!(
                f,
                "received {} byte{s} at {} baud, ",
                Thousands(t.bytes),
                t.baud
            )?;
            match t.frames {
                0 => f.write_str("no valid frame")?,
                1 => f.write_str("1 valid frame")?,
                n => write!(f, "{} valid frames", Thousands(n))?,
            }
            if t.bad_frames > 0 {
                write!(f, " ({} bad)", Thousands(t.bad_frames))?;
            }
        }
        if silent > 0 {
            f.write_str("; silence at ")?;
            list_rates(f, self.rates.iter().filter(|t| t.bytes == 0))?;
            f.write_str(" baud")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use std::string::ToString;

    #[test]
    fn heard_says_what_one_rate_carried() {
        let h = |bytes, valid, bad| Heard {
            bytes,
            valid,
            bad,
            unit: "line",
            silence_hint: "powered?",
        };
        assert_eq!(h(0, 0, 0).to_string(), "silence on the line (powered?)");
        assert_eq!(
            h(1204, 0, 3).to_string(),
            "received 1,204 bytes, no valid line (3 bad) (wrong rate or wrong device?)"
        );
        assert_eq!(h(40, 1, 0).to_string(), "received 40 bytes, 1 valid line");
        assert_eq!(
            h(90, 2, 1).to_string(),
            "received 90 bytes, 2 valid lines (1 bad)"
        );
    }

    #[test]
    fn silence_names_every_rate_tried() {
        let mut r = ProbeReport::new();
        for b in [9600, 38400, 19200, 9600] {
            r.attempt(b);
        }
        assert_eq!(
            r.to_string(),
            "silence at every rate tried (9600, 38400, 19200)"
        );
        assert_eq!(r.rates()[0].attempts, 2);
        let mut one = ProbeReport::new();
        one.attempt(115_200);
        assert_eq!(one.to_string(), "silence at 115200 baud");
        assert_eq!(ProbeReport::new().to_string(), "no rate was tried");
    }

    #[test]
    fn bytes_and_frames_count_at_the_current_rate() {
        let mut r = ProbeReport::new();
        r.received(5); // before any rate: not counted
        r.attempt(9600);
        r.received(1200);
        r.received(4);
        r.framed(0, 3);
        r.attempt(19200);
        r.attempt(38400);
        r.received(1_234_567);
        r.framed(2, 0);
        assert_eq!(r.total_bytes(), 1_235_771);
        assert_eq!(r.total_frames(), 2);
        assert_eq!(r.current_tally().map(|t| t.bytes), Some(1_234_567));
        assert_eq!(
            r.to_string(),
            "received 1,204 bytes at 9600 baud, no valid frame (3 bad); \
             received 1,234,567 bytes at 38400 baud, 2 valid frames; silence at 19200 baud"
        );
    }

    #[test]
    fn thousands() {
        assert_eq!(Thousands(0).to_string(), "0");
        assert_eq!(Thousands(999).to_string(), "999");
        assert_eq!(Thousands(1000).to_string(), "1,000");
        assert_eq!(
            Thousands(u64::MAX).to_string(),
            "18,446,744,073,709,551,615"
        );
    }

    #[test]
    fn more_rates_than_room_are_ignored_not_a_panic() {
        let mut r = ProbeReport::new();
        for b in 0..20 {
            r.attempt(b);
            r.received(1);
        }
        assert_eq!(r.rates().len(), MAX_RATES);
    }
}
