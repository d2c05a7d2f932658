//! The framer before its bulk search (byte-at-a-time hunting, byte-at-a-time skip after a
//! failed candidate), kept verbatim but for names as the reference `framer_bulk` compares with.

#![allow(dead_code)]

use core::time::Duration;

use ima_hal::Instant;
use ima_sick_lms::framer::{Counters, Direction, Item, PARTIAL_TIMEOUT, Pushed};
use ima_sick_lms::wire::{
    ACK, Command, Frame, MAX_LEN, MAX_TELEGRAM, NAK, Reply, STX, WireError, is_known_command,
    is_known_reply,
};

enum Check {
    Complete(usize),
    NeedMore(usize),
    Failed,
}

#[derive(Debug, Clone)]
pub struct RefFramer {
    direction: Direction,
    buf: [u8; MAX_TELEGRAM],
    start: usize,
    end: usize,
    last_input: Instant,
    counters: Counters,
    partial_timeout: Duration,
    report_bad_checksums: bool,
    bad_checksum_seen: bool,
}

impl RefFramer {
    pub const fn new(direction: Direction) -> Self {
        Self {
            direction,
            buf: [0; MAX_TELEGRAM],
            start: 0,
            end: 0,
            last_input: Instant::ZERO,
            counters: Counters {
                dropped_bytes: 0,
                bad_checksums: 0,
                bad_headers: 0,
                bad_payloads: 0,
                expired: 0,
                frames: 0,
                acks: 0,
                naks: 0,
            },
            partial_timeout: PARTIAL_TIMEOUT,
            report_bad_checksums: false,
            bad_checksum_seen: false,
        }
    }

    pub const fn with_partial_timeout(mut self, timeout: Duration) -> Self {
        self.partial_timeout = timeout;
        self
    }

    pub const fn report_bad_checksums(mut self, on: bool) -> Self {
        self.report_bad_checksums = on;
        self
    }

    pub const fn replies() -> Self {
        Self::new(Direction::Replies)
    }

    pub const fn commands() -> Self {
        Self::new(Direction::Commands)
    }

    pub const fn counters(&self) -> Counters {
        self.counters
    }

    pub const fn buffered(&self) -> usize {
        self.end - self.start
    }

    pub fn poll_timeout(&self) -> Option<Instant> {
        (self.buffered() > 0).then(|| self.last_input + self.partial_timeout)
    }

    pub fn clear(&mut self) {
        let held = self.buffered() as u64;
        self.counters.dropped_bytes = self.counters.dropped_bytes.saturating_add(held);
        self.start = 0;
        self.end = 0;
    }

    pub fn push<'s>(&'s mut self, input: &[u8], now: Instant) -> Pushed<'s> {
        let mut consumed = 0usize;
        loop {
            if self.buffered() == 0 {
                self.start = 0;
                self.end = 0;
                // Hunt directly in the input: bytes here are between frames.
                let Some(&b) = input.get(consumed) else {
                    return Pushed {
                        consumed,
                        item: None,
                    };
                };
                consumed += 1;
                self.last_input = now;
                match b {
                    STX => {
                        if let Some(slot) = self.buf.get_mut(0) {
                            *slot = b;
                            self.end = 1;
                        }
                    }
                    ACK => {
                        self.counters.acks = self.counters.acks.saturating_add(1);
                        return Pushed {
                            consumed,
                            item: Some(Item::Ack),
                        };
                    }
                    NAK => {
                        self.counters.naks = self.counters.naks.saturating_add(1);
                        return Pushed {
                            consumed,
                            item: Some(Item::Nak),
                        };
                    }
                    _ => {
                        self.counters.dropped_bytes = self.counters.dropped_bytes.saturating_add(1);
                    }
                }
                continue;
            }
            match self.check() {
                Check::Complete(n) => {
                    let from = self.start;
                    let to = from + n;
                    self.start = to;
                    self.counters.frames = self.counters.frames.saturating_add(1);
                    // check() verified this exact slice.
                    let frame = self
                        .buf
                        .get(from..to)
                        .and_then(|b| Frame::new_checked(b).ok());
                    return Pushed {
                        consumed,
                        item: frame.map(Item::Frame),
                    };
                }
                Check::Failed => {
                    self.drop_one();
                    if core::mem::take(&mut self.bad_checksum_seen) && self.report_bad_checksums {
                        return Pushed {
                            consumed,
                            item: Some(Item::BadChecksum),
                        };
                    }
                }
                Check::NeedMore(k) => {
                    if now >= self.last_input + self.partial_timeout {
                        // Silence since the candidate's last byte: abandon it (spec §5 rule 3).
                        self.counters.expired = self.counters.expired.saturating_add(1);
                        self.drop_one();
                        continue;
                    }
                    let rest = input.get(consumed..).unwrap_or(&[]);
                    if rest.is_empty() {
                        return Pushed {
                            consumed,
                            item: None,
                        };
                    }
                    let take = k.min(rest.len());
                    self.append(rest.get(..take).unwrap_or(&[]));
                    consumed += take;
                    self.last_input = now;
                }
            }
        }
    }

    pub fn push_all(&mut self, mut input: &[u8], now: Instant, mut on_item: impl FnMut(Item<'_>)) {
        loop {
            let p = self.push(input, now);
            let consumed = p.consumed;
            let got = p.item.is_some();
            if let Some(item) = p.item {
                on_item(item);
            }
            input = input.get(consumed..).unwrap_or(&[]);
            if !got && consumed == 0 {
                break;
            }
        }
    }

    fn append(&mut self, bytes: &[u8]) {
        if self.end + bytes.len() > self.buf.len() {
            self.buf.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        let to = self.end + bytes.len();
        if let Some(dst) = self.buf.get_mut(self.end..to) {
            dst.copy_from_slice(bytes);
            self.end = to;
        }
    }

    fn drop_one(&mut self) {
        self.start += 1;
        self.counters.dropped_bytes = self.counters.dropped_bytes.saturating_add(1);
        while self.start < self.end && self.buf.get(self.start) != Some(&STX) {
            self.start += 1;
            self.counters.dropped_bytes = self.counters.dropped_bytes.saturating_add(1);
        }
    }

    fn check(&mut self) -> Check {
        let w = self.buf.get(self.start..self.end).unwrap_or(&[]);
        // w[0] is STX by construction.
        if let Some(&addr) = w.get(1) {
            let ok = match self.direction {
                Direction::Replies => addr >= 0x80,
                Direction::Commands => addr < 0x80,
            };
            if !ok {
                self.counters.bad_headers = self.counters.bad_headers.saturating_add(1);
                return Check::Failed;
            }
        }
        let len = match (w.get(2), w.get(3)) {
            (Some(&lo), Some(&hi)) => u16::from_le_bytes([lo, hi]),
            _ => return Check::NeedMore(4 - w.len()),
        };
        if len == 0 || len > MAX_LEN {
            self.counters.bad_headers = self.counters.bad_headers.saturating_add(1);
            return Check::Failed;
        }
        let Some(&code) = w.get(4) else {
            return Check::NeedMore(1);
        };
        let known = match self.direction {
            Direction::Replies => is_known_reply(code),
            Direction::Commands => is_known_command(code),
        };
        if !known {
            self.counters.bad_headers = self.counters.bad_headers.saturating_add(1);
            return Check::Failed;
        }
        let total = usize::from(len) + 6;
        let Some(candidate) = w.get(..total) else {
            return Check::NeedMore(total - w.len());
        };
        let verdict = Frame::new_checked(candidate).and_then(|f| match self.direction {
            Direction::Replies => Reply::from_frame(&f).map(|_| ()),
            Direction::Commands => Command::from_frame(&f).map(|_| ()),
        });
        match verdict {
            Ok(()) => Check::Complete(total),
            Err(WireError::BadChecksum { .. }) => {
                self.counters.bad_checksums = self.counters.bad_checksums.saturating_add(1);
                self.bad_checksum_seen = true;
                Check::Failed
            }
            Err(_) => {
                self.counters.bad_payloads = self.counters.bad_payloads.saturating_add(1);
                Check::Failed
            }
        }
    }
}
