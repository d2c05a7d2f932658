//! Cutting frames out of a TCP byte stream (header-checked, bounded).

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::sync::mpsc;

/// Read chunk of a session that has not yet sent a whole frame: a stranger's connection
/// costs little memory until it sends a frame that passes the header check.
const FIRST_CHUNK: usize = 1024;
/// Read chunk once frames flow.
const CHUNK: usize = 16 * 1024;

use crate::peer::wire::{self, HEADER_LEN, MAC_LEN};

/// Bytes written to a socket in one call at most (frames are batched up to this).
pub(crate) const WRITE_BATCH: usize = 64 * 1024;

/// Buffer size for one maximum frame plus slack.
pub(crate) fn max_frame(max_body: usize) -> usize {
    HEADER_LEN + max_body + MAC_LEN
}

/// Accumulates stream bytes and yields whole frames. A bad header (magic, version, size
/// limit) yields the header bytes once, so the core can count and close; after that the
/// reader yields nothing more (the session is closed, no resynchronisation).
pub(crate) struct FrameReader {
    buf: Vec<u8>,
    start: usize,
    max_body: usize,
    poisoned: bool,
    chunk: usize,
    /// The first bytes ever read, and how many (to say what a stranger sent).
    head: ([u8; 8], u8),
}

impl FrameReader {
    pub(crate) fn new(max_body: usize) -> Self {
        Self {
            buf: Vec::new(),
            start: 0,
            max_body,
            poisoned: false,
            chunk: FIRST_CHUNK,
            head: ([0; 8], 0),
        }
    }

    /// The first bytes read from the stream (up to 8, whether or not they made a frame) and
    /// how many of them there are.
    pub(crate) fn head(&self) -> ([u8; 8], u8) {
        self.head
    }

    /// Keep the stream's first bytes, once `n` more were appended to the buffer.
    fn note_head(&mut self, n: usize) {
        let have = usize::from(self.head.1);
        if have < self.head.0.len() && n > 0 {
            let new = self.buf.len().saturating_sub(n);
            for (d, s) in self
                .head
                .0
                .iter_mut()
                .skip(have)
                .zip(self.buf.iter().skip(new))
            {
                *d = *s;
                self.head.1 += 1;
            }
        }
    }

    fn make_room(&mut self) {
        if self.start > 0 && (self.start == self.buf.len() || self.start > self.buf.len() / 2) {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.reserve(self.chunk);
    }

    /// Whether a bad header was met (the session is over; nothing more is read).
    #[cfg(test)]
    pub(crate) fn is_poisoned(&self) -> bool {
        self.poisoned
    }

    /// Reads more bytes (cancel-safe). `Ok(0)` is end of stream; once poisoned (a bad
    /// header was yielded) this reads nothing more and answers `Ok(0)` at once, so a
    /// sender of garbage cannot keep the session's task busy.
    pub(crate) async fn read_from<R: AsyncRead + Unpin>(
        &mut self,
        r: &mut R,
    ) -> std::io::Result<usize> {
        if self.poisoned {
            return Ok(0);
        }
        self.make_room();
        let n = r.read_buf(&mut self.buf).await?;
        self.note_head(n);
        Ok(n)
    }

    /// Takes what the socket already holds, without waiting: `Ok(None)` when nothing is
    /// pending, `Ok(Some(0))` at the end of the stream (or once poisoned). Used before a
    /// timeout is handled, so that a starved task does not declare a live peer lost.
    pub(crate) fn try_read_from(&mut self, r: &OwnedReadHalf) -> std::io::Result<Option<usize>> {
        if self.poisoned {
            return Ok(Some(0));
        }
        self.make_room();
        match r.try_read_buf(&mut self.buf) {
            Ok(n) => {
                self.note_head(n);
                Ok(Some(n))
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => Ok(None),
            Err(e) => Err(e),
        }
    }

    /// The next complete frame (or a bad header), if buffered.
    pub(crate) fn next_frame(&mut self) -> Option<&[u8]> {
        if self.poisoned {
            return None;
        }
        let pending = self.buf.get(self.start..)?;
        match wire::frame_len(pending, self.max_body) {
            Ok(None) => None,
            Ok(Some(n)) if pending.len() >= n => {
                self.chunk = CHUNK;
                let s = self.start;
                self.start += n;
                self.buf.get(s..s + n)
            }
            Ok(Some(_)) => None,
            Err(_) => {
                self.poisoned = true;
                let s = self.start;
                self.start = self.buf.len();
                self.buf.get(s..s + HEADER_LEN)
            }
        }
    }
}

/// Writes the frames of `rx`, batched, until the channel closes; then shuts the socket
/// down (the remote sees the end of the stream). A write that does not complete within
/// `limit` (the loss window: the peer reads nothing) ends the task and closes the socket;
/// the session's owner then sees its queue closed.
pub(crate) async fn write_frames(
    mut wr: OwnedWriteHalf,
    mut rx: mpsc::Receiver<Vec<u8>>,
    limit: std::time::Duration,
) {
    let mut batch = Vec::with_capacity(WRITE_BATCH);
    while let Some(f) = rx.recv().await {
        batch.clear();
        batch.extend_from_slice(&f);
        while batch.len() < WRITE_BATCH {
            match rx.try_recv() {
                Ok(f) => batch.extend_from_slice(&f),
                Err(_) => break,
            }
        }
        match tokio::time::timeout(limit, wr.write_all(&batch)).await {
            Ok(Ok(())) => {}
            Ok(Err(_)) | Err(_) => return,
        }
    }
    let _ = tokio::time::timeout(limit, wr.shutdown()).await;
}

/// Drains a data session's pending frames (`poll` is its `poll_transmit` at one instant)
/// into `out`, up to [`WRITE_BATCH`] bytes, and writes them in one call bounded by `limit`
/// (the loss window: a peer that reads nothing is lost, and the task does not hang on it).
/// `out` is left holding what was written; `false` means the write failed or timed out.
pub(crate) async fn write_batch<W: tokio::io::AsyncWrite + Unpin>(
    wr: &mut W,
    buf: &mut [u8],
    out: &mut Vec<u8>,
    limit: std::time::Duration,
    mut poll: impl FnMut(&mut [u8]) -> Option<usize>,
) -> bool {
    out.clear();
    while out.len() < WRITE_BATCH {
        match poll(buf) {
            Some(n) => out.extend_from_slice(buf.get(..n).unwrap_or_default()),
            None => break,
        }
    }
    out.is_empty()
        || matches!(
            tokio::time::timeout(limit, wr.write_all(out)).await,
            Ok(Ok(()))
        )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::peer::wire::{GroupKey, Msg, Signer};

    #[test]
    fn cuts_frames_and_poisons_on_bad_header() {
        let key = GroupKey::from_array([3; 32]);
        let mut s = Signer::new(key, 1, 1);
        let a = s.seal_vec(&Msg::Heartbeat).unwrap();
        let b = s.seal_vec(&Msg::Unregister { client: 9 }).unwrap();
        let mut r = FrameReader::new(8192);
        r.buf.extend_from_slice(&a);
        r.buf.extend_from_slice(b.get(..10).unwrap());
        assert_eq!(r.next_frame(), Some(a.as_slice()));
        assert_eq!(r.next_frame(), None);
        r.buf.extend_from_slice(b.get(10..).unwrap());
        assert_eq!(r.next_frame(), Some(b.as_slice()));
        r.buf.extend_from_slice(&[0u8; 30]);
        assert_eq!(r.next_frame().map(<[u8]>::len), Some(HEADER_LEN));
        assert_eq!(r.next_frame(), None);
        assert!(r.is_poisoned());
    }

    #[tokio::test]
    async fn a_poisoned_reader_reads_no_more() {
        let mut r = FrameReader::new(8192);
        let mut input: &[u8] = &[0x55; 64];
        assert_eq!(r.read_from(&mut input).await.unwrap(), 64);
        assert_eq!(r.next_frame().map(<[u8]>::len), Some(HEADER_LEN));
        assert!(r.is_poisoned());
        // More bytes are waiting, but nothing is read: the session is over.
        let mut more: &[u8] = &[0x55; 1000];
        assert_eq!(r.read_from(&mut more).await.unwrap(), 0);
        assert_eq!(more.len(), 1000);
        assert!(r.buf.len() <= 64);
    }
}
