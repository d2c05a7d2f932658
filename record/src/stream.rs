//! Streams: what a channel's messages share (topic, schema, frame ids, names), kept once by
//! the recorder's thread, so that a record only carries what changes from one message to the
//! next ([`crate::queue::Kind`]). The thread fills the stream's message in place and encodes
//! it into one reused buffer: no allocation per message there either.

use std::collections::BTreeMap;
use std::sync::Arc;

use foxglove::messages::{
    CompressedImage, FrameTransform, LaserScan, Log, PointCloud, PoseInFrame, RawImage,
};
use foxglove::{Encode, Schema};

use crate::convert::{self, Pose2};
use crate::queue::{Kind, f64s};

/// What the messages of one stream share.
#[derive(Debug, Clone)]
pub(crate) enum Proto {
    /// Records hold the encoded message.
    Encoded {
        schema: Option<Schema>,
        encoding: String,
        metadata: BTreeMap<String, String>,
    },
    Scan(LaserScan),
    Transform(FrameTransform),
    Pose(PoseInFrame),
    /// `rgb8` frames as `RawImage`, or as PNG `CompressedImage`s (`png`).
    Image {
        raw: RawImage,
        png: bool,
    },
    Cloud(PointCloud),
    Text(Log),
}

/// One stream, as registered by the first message logged on it.
#[derive(Debug)]
pub(crate) struct Stream {
    pub(crate) topic: Arc<str>,
    /// Something takes its messages (a live view, or a file that does not leave it out).
    pub(crate) wanted: bool,
    pub(crate) proto: Proto,
}

impl Proto {
    /// The channel's schema, message encoding and metadata.
    pub(crate) fn channel(&self) -> (Option<Schema>, String, BTreeMap<String, String>) {
        fn of<T: Encode>() -> (Option<Schema>, String, BTreeMap<String, String>) {
            (T::get_schema(), T::get_message_encoding(), BTreeMap::new())
        }
        match self {
            Self::Encoded {
                schema,
                encoding,
                metadata,
            } => (schema.clone(), encoding.clone(), metadata.clone()),
            Self::Scan(_) => of::<LaserScan>(),
            Self::Transform(_) => of::<FrameTransform>(),
            Self::Pose(_) => of::<PoseInFrame>(),
            Self::Image { png: false, .. } => of::<RawImage>(),
            Self::Image { png: true, .. } => of::<CompressedImage>(),
            Self::Cloud(_) => of::<PointCloud>(),
            Self::Text(_) => of::<Log>(),
        }
    }

    /// Fill the message from a record's payload and encode it into `out` (cleared first);
    /// `None` if the payload does not fit the stream (nothing is written then).
    pub(crate) fn encode(
        &mut self,
        kind: Kind,
        at_ns: u64,
        payload: &[u8],
        out: &mut Vec<u8>,
    ) -> Option<()> {
        out.clear();
        let stamp = Some(convert::stamp(at_ns));
        match (self, kind) {
            (Self::Encoded { .. }, Kind::Encoded) => out.extend_from_slice(payload),
            (Self::Scan(s), Kind::Scan) => {
                let ([start, step], ranges) = f64s::<2>(payload)?;
                s.timestamp = stamp;
                s.ranges.clear();
                s.ranges.extend(
                    ranges
                        .chunks_exact(4)
                        .filter_map(|c| c.try_into().ok())
                        .map(|c| f64::from(f32::from_le_bytes(c))),
                );
                s.start_angle = start;
                let last = s.ranges.len().saturating_sub(1);
                s.end_angle = start + step * last as f64;
                encode(&*s, out);
            }
            (Self::Transform(t), Kind::Pose) => {
                let q = pose(payload)?;
                t.timestamp = stamp;
                t.translation = q.position;
                t.rotation = q.orientation;
                encode(&*t, out);
            }
            (Self::Pose(p), Kind::Pose) => {
                p.timestamp = stamp;
                p.pose = Some(pose(payload)?);
                encode(&*p, out);
            }
            (Self::Image { raw, png }, Kind::Image) => {
                let (w, rest) = payload.split_first_chunk::<4>()?;
                let (h, pixels) = rest.split_first_chunk::<4>()?;
                let (w, h) = (u32::from_le_bytes(*w), u32::from_le_bytes(*h));
                if *png {
                    let img = CompressedImage {
                        timestamp: stamp,
                        frame_id: raw.frame_id.clone(),
                        data: convert::png(w, h, pixels)?.into(),
                        format: "png".to_owned(),
                    };
                    encode(&img, out);
                } else {
                    raw.timestamp = stamp;
                    raw.width = w;
                    raw.height = h;
                    raw.step = w.saturating_mul(3);
                    // The message without its pixels, then the pixels as field 6 (`data`,
                    // length-delimited) straight from the record: protobuf fields may come
                    // in any order, and no copy of the frame is made for the encoder.
                    encode(&*raw, out);
                    bytes_field(6, pixels, out);
                }
            }
            (Self::Cloud(c), Kind::Cloud) => {
                // As for frames: the points (field 6, `data`) straight from the record.
                c.timestamp = stamp;
                encode(&*c, out);
                bytes_field(6, payload, out);
            }
            (Self::Text(l), Kind::Text) => {
                let (level, text) = payload.split_first()?;
                l.timestamp = stamp;
                l.level = i32::from(*level);
                l.message.clear();
                l.message.push_str(std::str::from_utf8(text).ok()?);
                encode(&*l, out);
            }
            _ => return None,
        }
        Some(())
    }
}

fn encode<T: Encode>(msg: &T, out: &mut Vec<u8>) {
    // Encoding into a Vec cannot run out of room.
    let _ = msg.encode(out);
}

/// Append a length-delimited protobuf field `tag` holding `b` (nothing when `b` is empty, as
/// an encoder leaves out an empty `bytes` field).
fn bytes_field(tag: u32, b: &[u8], out: &mut Vec<u8>) {
    if b.is_empty() {
        return;
    }
    varint(u64::from(tag) << 3 | 2, out);
    varint(b.len() as u64, out);
    out.extend_from_slice(b);
}

fn pose(payload: &[u8]) -> Option<foxglove::messages::Pose> {
    let ([x_m, y_m, theta_rad], _) = f64s::<3>(payload)?;
    Some(convert::pose3(Pose2 {
        x_m,
        y_m,
        theta_rad,
    }))
}

/// A protobuf base-128 varint.
fn varint(mut v: u64, out: &mut Vec<u8>) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn varints_are_protobuf_varints() {
        for (v, want) in [
            (0u64, &[0u8][..]),
            (1, &[1]),
            (127, &[0x7f]),
            (128, &[0x80, 0x01]),
            (230_400, &[0x80, 0x88, 0x0e]),
        ] {
            let mut out = Vec::new();
            varint(v, &mut out);
            assert_eq!(out, want, "{v}");
        }
    }
}
