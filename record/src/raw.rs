//! Raw serial bytes: one MCAP channel per port, both directions.
//!
//! Topic: `/<robot>/serial/<device>` (e.g. `/scooter/serial/laser`). Message encoding
//! [`ENCODING`], no schema. Each message is one read or one write: a direction byte
//! ([`Dir`]) followed by the bytes; a line-speed change is [`Dir::Baud`] followed by the new
//! rate as 4 bytes little-endian. The channel metadata name the `robot`, `device`, `port`,
//! `baud` (at opening), `protocol` and this `format`.

use std::collections::BTreeMap;
use std::sync::Arc;

use crate::Recorder;

/// The message encoding of raw serial channels.
pub const ENCODING: &str = "ima.serial";

/// The format, as written into each raw channel's metadata.
pub const FORMAT: &str = "byte 0: 0 = device to host, 1 = host to device (bytes follow), \
2 = line speed change (u32 little-endian follows)";

/// Direction of a raw chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Dir {
    /// Device → host (what the driver read).
    Rx = 0,
    /// Host → device (what the driver wrote).
    Tx = 1,
    /// The host changed the line speed.
    Baud = 2,
}

impl Dir {
    /// The direction of a marker byte.
    pub fn from_byte(b: u8) -> Option<Self> {
        match b {
            0 => Some(Self::Rx),
            1 => Some(Self::Tx),
            2 => Some(Self::Baud),
            _ => None,
        }
    }
}

/// A decoded raw message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Chunk<'a> {
    /// Bytes in one direction.
    Bytes(Dir, &'a [u8]),
    /// A line-speed change.
    Baud(u32),
}

/// Decode one raw message (`None`: not a raw message of this format).
pub fn parse(msg: &[u8]) -> Option<Chunk<'_>> {
    let (&d, rest) = msg.split_first()?;
    match Dir::from_byte(d)? {
        Dir::Baud => {
            let b: [u8; 4] = rest.try_into().ok()?;
            Some(Chunk::Baud(u32::from_le_bytes(b)))
        }
        dir => Some(Chunk::Bytes(dir, rest)),
    }
}

/// Encode one raw message.
pub fn encode(dir: Dir, bytes: &[u8]) -> Vec<u8> {
    let mut v = Vec::with_capacity(bytes.len() + 1);
    v.push(dir as u8);
    v.extend_from_slice(bytes);
    v
}

/// What a serial port is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PortInfo {
    /// The robot (`skeeter`, `scooter`, or the command's name).
    pub robot: String,
    /// The device on the port (`base`, `laser`, `compass`, `video_mux`).
    pub device: String,
    /// The port's path.
    pub port: String,
    /// The line speed at opening.
    pub baud: u32,
    /// The protocol spoken (`p2os`, `rflex`, `sick-lms`, `compass-kvh`, …).
    pub protocol: String,
    /// What else re-decoding the bytes as the driver did needs (`time_scale`, an rFLEX's `kd`
    /// and `ka`): more entries of the channel's metadata.
    pub params: BTreeMap<String, String>,
}

impl PortInfo {
    /// The channel's topic.
    pub fn topic(&self) -> String {
        format!("/{}/serial/{}", self.robot, self.device)
    }

    /// The channel's metadata.
    pub fn metadata(&self) -> BTreeMap<String, String> {
        let mut m = self.params.clone();
        m.extend([
            ("robot".to_owned(), self.robot.clone()),
            ("device".to_owned(), self.device.clone()),
            ("port".to_owned(), self.port.clone()),
            ("baud".to_owned(), self.baud.to_string()),
            ("protocol".to_owned(), self.protocol.clone()),
            ("format".to_owned(), FORMAT.to_owned()),
        ]);
        m
    }

    /// Read back from a channel's metadata (`None` when a field is missing).
    pub fn from_metadata(m: &BTreeMap<String, String>) -> Option<Self> {
        const FIXED: [&str; 6] = ["robot", "device", "port", "baud", "protocol", "format"];
        Some(Self {
            robot: m.get("robot")?.clone(),
            device: m.get("device")?.clone(),
            port: m.get("port")?.clone(),
            baud: m.get("baud")?.parse().ok()?,
            protocol: m.get("protocol")?.clone(),
            params: (m.iter())
                .filter(|(k, _)| !FIXED.contains(&k.as_str()))
                .map(|(k, v)| (k.clone(), v.clone()))
                .collect(),
        })
    }
}

/// Records one port's bytes (cheap to clone).
#[derive(Debug, Clone)]
pub struct RawPort {
    rec: Recorder,
    stream: crate::StreamId,
    topic: Arc<str>,
}

impl RawPort {
    pub(crate) fn new(rec: Recorder, stream: crate::StreamId, topic: Arc<str>) -> Self {
        Self { rec, stream, topic }
    }

    /// Record one chunk as [`RawStream::chunks`](crate::read::RawStream::chunks) holds it:
    /// bytes in `dir`, or for [`Dir::Baud`] the rate as 4 bytes little-endian (a replay
    /// copies a recording's chunks with this).
    pub fn chunk(&self, dir: Dir, bytes: &[u8]) {
        // Something takes this channel ([`Recorder::wants`]); if not, bytes are not even
        // copied.
        if !self.stream.wanted {
            return;
        }
        let kind = crate::queue::Kind::Encoded;
        self.rec.timed(|rec| {
            rec.push(self.stream, kind, bytes.len() + 1, |b| {
                b.push(dir as u8);
                b.extend_from_slice(bytes);
                true
            })
        });
    }

    /// Bytes read from the device.
    pub fn rx(&self, bytes: &[u8]) {
        if !bytes.is_empty() {
            self.chunk(Dir::Rx, bytes);
        }
    }

    /// Bytes written to the device.
    pub fn tx(&self, bytes: &[u8]) {
        if !bytes.is_empty() {
            self.chunk(Dir::Tx, bytes);
        }
    }

    /// The line speed changed.
    pub fn baud(&self, baud: u32) {
        self.chunk(Dir::Baud, &baud.to_le_bytes());
    }

    /// The channel's topic.
    pub fn topic(&self) -> &str {
        &self.topic
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn raw_messages_round_trip() {
        assert_eq!(
            parse(&encode(Dir::Rx, b"abc")),
            Some(Chunk::Bytes(Dir::Rx, b"abc"))
        );
        assert_eq!(
            parse(&encode(Dir::Tx, b"")),
            Some(Chunk::Bytes(Dir::Tx, b""))
        );
        assert_eq!(
            parse(&encode(Dir::Baud, &38400u32.to_le_bytes())),
            Some(Chunk::Baud(38400))
        );
        assert_eq!(parse(&[2, 1, 2]), None);
        assert_eq!(parse(&[7, 1]), None);
        assert_eq!(parse(&[]), None);
    }

    #[test]
    fn port_info_round_trips_through_metadata() {
        let p = PortInfo {
            robot: "scooter".into(),
            device: "laser".into(),
            port: "/dev/pts/3".into(),
            baud: 9600,
            protocol: "sick-lms".into(),
            params: Default::default(),
        };
        assert_eq!(p.topic(), "/scooter/serial/laser");
        assert_eq!(PortInfo::from_metadata(&p.metadata()), Some(p));
    }
}
