//! Latched streams for the live view: the last message of every served stream, sent to a
//! client when it subscribes to that stream's channel.
//!
//! The Foxglove server sends a message only to the clients subscribed when it is logged. A
//! channel is advertised when its first message is logged, so no client can have subscribed
//! to it yet: without a latch every client missed each channel's first message, and a topic
//! that is logged only when it changes (the arena, the SES, the commander's queue) stayed
//! empty for a client that joined later until it changed again. With it, a new subscriber
//! gets the last message of each stream on the channel at once (each `/tf` pair, each
//! camera), oldest first, and only it: other clients and the file see nothing twice.
//!
//! A log stream (`foxglove.Log`: `/events`, `/broadcasts`, one stream per name) keeps its
//! last [`LOG_DEPTH`] lines instead of one, so a log panel opened late shows the recent
//! history, and the lines of the first batch (all logged before the channel could be
//! subscribed to) reach a client that connected first.
//!
//! Order: the recorder's thread logs a message and keeps it under one lock, and a
//! subscriber's replay takes the same lock. The SDK starts sending a new subscriber live
//! messages just before it calls the listener, so a message logged in that gap arrives live
//! first and then again among the replayed ones, after it in time order (once per
//! subscription, at most the messages of one recorder tick).
//!
//! Memory is bounded: a message over [`MAX_MESSAGE`] is not kept, nor one that would take
//! the whole over [`MAX_BYTES`]; either way the stream's older copies are dropped, so what a
//! subscriber gets is never older than what it would have got.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex, PoisonError};

use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{ChannelId, PartialMetadata, RawChannel, SinkId};

/// The largest message kept (a 640 × 480 `rgb8` frame is 0.9 MiB).
pub(crate) const MAX_MESSAGE: usize = 4 << 20;
/// The most bytes kept over every stream.
pub(crate) const MAX_BYTES: usize = 64 << 20;
/// Lines kept per log stream.
pub(crate) const LOG_DEPTH: usize = 100;

/// The last messages of every served stream, by channel.
#[derive(Default)]
pub(crate) struct Latch {
    state: Mutex<State>,
}

#[derive(Default)]
struct State {
    channels: HashMap<ChannelId, Kept>,
    bytes: usize,
}

/// A stream's last messages as (log time, message), oldest first.
type Last = VecDeque<(u64, Vec<u8>)>;

/// A channel and the last messages of each of its streams.
struct Kept {
    chan: Arc<RawChannel>,
    /// (stream id, its last messages); few streams share a channel.
    streams: Vec<(u32, Last)>,
}

impl Latch {
    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Log `msg` of `stream` on `chan` to every sink, and keep it among the stream's last
    /// `depth` messages.
    pub(crate) fn log(
        &self,
        chan: &Arc<RawChannel>,
        stream: u32,
        depth: usize,
        msg: &[u8],
        log_time: u64,
    ) {
        let mut st = self.state();
        chan.log_with_meta(msg, PartialMetadata::with_log_time(log_time));
        let State { channels, bytes } = &mut *st;
        let kept = channels.entry(chan.id()).or_insert_with(|| Kept {
            chan: Arc::clone(chan),
            streams: Vec::new(),
        });
        let i = match kept.streams.iter().position(|(s, _)| *s == stream) {
            Some(i) => i,
            None => {
                kept.streams.push((stream, VecDeque::new()));
                kept.streams.len() - 1
            }
        };
        let Some((_, last)) = kept.streams.get_mut(i) else {
            return;
        };
        // Room for it: the oldest go first (all of them if it cannot be kept).
        let fits = msg.len() <= MAX_MESSAGE;
        let mut spare = None;
        while !last.is_empty()
            && (!fits || last.len() >= depth.max(1) || *bytes + msg.len() > MAX_BYTES)
        {
            if let Some((_, m)) = last.pop_front() {
                *bytes -= m.len();
                spare = Some(m);
            }
        }
        if fits && *bytes + msg.len() <= MAX_BYTES {
            // The buffer of the message that just went (no allocation per frame).
            let mut m = spare.unwrap_or_default();
            m.clear();
            m.extend_from_slice(msg);
            last.push_back((log_time, m));
            *bytes += msg.len();
        }
    }

    /// Send `sink` the last messages of every stream on `channel`, oldest first.
    pub(crate) fn replay(&self, channel: ChannelId, sink: SinkId) {
        let st = self.state();
        let Some(kept) = st.channels.get(&channel) else {
            return;
        };
        let mut all: Vec<&(u64, Vec<u8>)> = kept.streams.iter().flat_map(|(_, l)| l).collect();
        all.sort_by_key(|&&(t, _)| t);
        for (t, m) in all {
            let meta = PartialMetadata::with_log_time(*t);
            kept.chan.log_with_meta_to_sink(m, meta, Some(sink));
        }
    }

    /// Bytes kept.
    #[cfg(test)]
    fn bytes(&self) -> usize {
        self.state().bytes
    }

    /// The messages kept of `stream` on `chan`.
    #[cfg(test)]
    fn kept(&self, chan: &RawChannel, stream: u32) -> Vec<(u64, Vec<u8>)> {
        let st = self.state();
        let streams = st.channels.get(&chan.id()).map(|k| &k.streams);
        streams
            .and_then(|s| s.iter().find(|(id, _)| *id == stream))
            .map(|(_, l)| l.iter().cloned().collect())
            .unwrap_or_default()
    }
}

/// The server's listener: replays the latch to each new subscription.
pub(crate) struct Replay(pub(crate) Arc<Latch>);

impl ServerListener for Replay {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        if let Some(sink) = client.sink_id() {
            self.0.replay(channel.id(), sink);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn channel(ctx: &Arc<foxglove::Context>, topic: &str) -> Arc<RawChannel> {
        ctx.channel_builder(topic)
            .message_encoding("json")
            .build_raw()
            .unwrap()
    }

    #[test]
    fn each_stream_keeps_its_last_messages_within_the_bounds() {
        let ctx = foxglove::Context::new();
        let tf = channel(&ctx, "/tf");
        let latch = Latch::default();
        latch.log(&tf, 1, 1, b"a1", 10);
        latch.log(&tf, 2, 1, b"b1", 11);
        latch.log(&tf, 1, 1, b"a22", 12);
        assert_eq!(latch.bytes(), 5);
        assert_eq!(latch.kept(&tf, 1), [(12, b"a22".to_vec())]);
        assert_eq!(latch.kept(&tf, 2), [(11, b"b1".to_vec())]);
        // A log stream keeps its depth, oldest out first.
        let log = channel(&ctx, "/events");
        for t in 0..5u8 {
            latch.log(&log, 3, 3, &[t], u64::from(t));
        }
        assert_eq!(
            latch.kept(&log, 3),
            [(2, vec![2]), (3, vec![3]), (4, vec![4])]
        );
        assert_eq!(latch.bytes(), 8);
        // Too large: the stream's older copies go too, and the count follows.
        latch.log(&tf, 1, 1, &vec![0; MAX_MESSAGE + 1], 13);
        assert_eq!(latch.bytes(), 5);
        assert!(latch.kept(&tf, 1).is_empty());
        // The whole is bounded: streams past the budget are not kept.
        let cam = channel(&ctx, "/cam");
        let frame = vec![0; MAX_MESSAGE];
        for s in 0..40 {
            latch.log(&cam, s, 1, &frame, 20);
        }
        assert!(latch.bytes() <= MAX_BYTES, "{}", latch.bytes());
        assert_eq!(
            latch.bytes(),
            5 + (MAX_BYTES - 5) / MAX_MESSAGE * MAX_MESSAGE
        );
    }
}
