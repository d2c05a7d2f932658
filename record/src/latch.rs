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
//! Order: the recorder's thread logs a message and keeps it under one lock, and a
//! subscriber's replay takes the same lock, so a subscriber never gets a replayed message
//! after a newer live one (at worst the newest twice).
//!
//! Memory is bounded: a message over [`MAX_MESSAGE`] is not kept (its stream's older copy is
//! dropped), nor one that would take the whole over [`MAX_BYTES`].

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};

use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{ChannelId, PartialMetadata, RawChannel, SinkId};

/// The largest message kept (a 640 × 480 `rgb8` frame is 0.9 MiB).
pub(crate) const MAX_MESSAGE: usize = 4 << 20;
/// The most bytes kept over every stream.
pub(crate) const MAX_BYTES: usize = 64 << 20;

/// The last message of every served stream, by channel.
#[derive(Default)]
pub(crate) struct Latch {
    state: Mutex<State>,
}

#[derive(Default)]
struct State {
    channels: HashMap<ChannelId, Kept>,
    bytes: usize,
}

/// A channel and the last message of each of its streams.
struct Kept {
    chan: Arc<RawChannel>,
    /// (stream id, log time, message); few streams share a channel.
    last: Vec<(u32, u64, Vec<u8>)>,
}

impl Latch {
    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Log `msg` of `stream` on `chan` to every sink, and keep it as the stream's last.
    pub(crate) fn log(&self, chan: &Arc<RawChannel>, stream: u32, msg: &[u8], log_time: u64) {
        let mut st = self.state();
        chan.log_with_meta(msg, PartialMetadata::with_log_time(log_time));
        let State { channels, bytes } = &mut *st;
        let kept = channels.entry(chan.id()).or_insert_with(|| Kept {
            chan: Arc::clone(chan),
            last: Vec::new(),
        });
        let old = kept.last.iter().position(|(s, _, _)| *s == stream);
        let old_len = old
            .and_then(|i| kept.last.get(i))
            .map_or(0, |(_, _, m)| m.len());
        let fits = msg.len() <= MAX_MESSAGE && *bytes - old_len + msg.len() <= MAX_BYTES;
        match (old, fits) {
            (Some(i), true) => {
                if let Some((_, t, m)) = kept.last.get_mut(i) {
                    *t = log_time;
                    m.clear();
                    m.extend_from_slice(msg);
                }
            }
            (None, true) => kept.last.push((stream, log_time, msg.to_vec())),
            (Some(i), false) => drop(kept.last.swap_remove(i)),
            (None, false) => {}
        }
        *bytes = *bytes - old_len + if fits { msg.len() } else { 0 };
    }

    /// Send `sink` the last message of every stream on `channel`, oldest first.
    pub(crate) fn replay(&self, channel: ChannelId, sink: SinkId) {
        let mut st = self.state();
        let Some(kept) = st.channels.get_mut(&channel) else {
            return;
        };
        kept.last.sort_by_key(|&(_, t, _)| t);
        for (_, t, m) in &kept.last {
            let meta = PartialMetadata::with_log_time(*t);
            kept.chan.log_with_meta_to_sink(m, meta, Some(sink));
        }
    }

    /// Bytes kept.
    #[cfg(test)]
    fn bytes(&self) -> usize {
        self.state().bytes
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
    fn each_stream_keeps_its_last_message_within_the_bounds() {
        let ctx = foxglove::Context::new();
        let tf = channel(&ctx, "/tf");
        let latch = Latch::default();
        latch.log(&tf, 1, b"a1", 10);
        latch.log(&tf, 2, b"b1", 11);
        latch.log(&tf, 1, b"a22", 12);
        assert_eq!(latch.bytes(), 5);
        {
            let st = latch.state();
            let kept = &st.channels[&tf.id()].last;
            assert_eq!(kept.len(), 2);
            assert!(kept.contains(&(1, 12, b"a22".to_vec())));
        }
        // Too large: the stream's older copy goes too, and the count follows.
        latch.log(&tf, 1, &vec![0; MAX_MESSAGE + 1], 13);
        assert_eq!(latch.bytes(), 2);
        assert_eq!(latch.state().channels[&tf.id()].last.len(), 1);
        // The whole is bounded: streams past the budget are not kept.
        let cam = channel(&ctx, "/cam");
        let frame = vec![0; MAX_MESSAGE];
        for s in 0..40 {
            latch.log(&cam, s, &frame, 20);
        }
        assert!(latch.bytes() <= MAX_BYTES, "{}", latch.bytes());
        assert_eq!(
            latch.bytes(),
            2 + (MAX_BYTES - 2) / MAX_MESSAGE * MAX_MESSAGE
        );
    }
}
