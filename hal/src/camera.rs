//! Cameras: a video multiplexer that picks one of several cameras, and a frame source (frame
//! grabber or simulated camera head) that delivers RGB images.
//!
//! Channels are numbered from **1**, as switchers label their inputs (Extron `3!` selects
//! input 3). A frame grabbed less than the mux's settle time after a switch may still show the
//! previous camera or a torn image; [`CameraMux::select`] therefore reports when the new channel
//! is settled, and [`Frame::channel`] says which channel the source believes it was showing.
//!
//! # Memory
//!
//! [`Frame`] owns its pixels in a `Vec<u8>`, so it (and [`FrameSource`]) exist only with the
//! `std` feature. A frame is tens to hundreds of kilobytes and arrives a few times a second, so
//! one allocation per frame is not worth a borrowed-buffer API; a source may also hand back
//! frames whose buffers it recycles. The no_std protocol cores (`ima-video-mux`) need only
//! [`CameraMux`] and its plain types.

use core::future::Future;
use core::time::Duration;

use crate::{ErrorType, Instant};

/// A camera channel of a multiplexer, numbered from 1.
pub type Channel = u8;

/// The outcome of a channel selection the switcher confirmed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Selection {
    /// The channel now selected.
    pub channel: Channel,
    /// When the switcher confirmed the selection (or, for a switcher that does not answer, when
    /// the command was sent).
    pub confirmed_at: Instant,
    /// From this instant on, frames show the new channel (`confirmed_at` + settle time).
    pub settled_at: Instant,
}

/// A video switcher in front of a frame grabber.
pub trait CameraMux: ErrorType {
    /// Number of channels; valid channels are `1..=channel_count()`.
    fn channel_count(&self) -> Channel;

    /// Time after a confirmed switch before frames reliably show the new channel.
    fn settle_time(&self) -> Duration;

    /// Switch to `channel`. Resolves once the switcher confirms (with retries on silence); an
    /// out-of-range channel is an [`InvalidArgument`](crate::ErrorKind::InvalidArgument) error,
    /// a refusal by the switcher a [`Protocol`](crate::ErrorKind::Protocol) error.
    fn select(
        &mut self,
        channel: Channel,
    ) -> impl Future<Output = Result<Selection, Self::Error>> + Send;

    /// The channel the switcher currently shows, as last confirmed or reported by it (`None`
    /// before anything is known). Drivers may ask the switcher.
    fn current_channel(
        &mut self,
    ) -> impl Future<Output = Result<Option<Channel>, Self::Error>> + Send;
}

/// An RGB image with 8 bits per channel, rows top to bottom, pixels left to right, `R G B`
/// interleaved (feature `std`).
#[cfg(feature = "std")]
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The mux channel the image came from, when the source knows it.
    pub channel: Option<Channel>,
    /// `width * height * 3` bytes.
    pub pixels: Vec<u8>,
}

#[cfg(feature = "std")]
impl Frame {
    /// A black frame of the given size (`None` if the size overflows `usize`).
    #[must_use]
    pub fn black(width: u32, height: u32, channel: Option<Channel>) -> Option<Self> {
        let len = Self::byte_len(width, height)?;
        Some(Self {
            width,
            height,
            channel,
            pixels: vec![0; len],
        })
    }

    /// Bytes needed for a `width` × `height` RGB8 image.
    #[must_use]
    pub fn byte_len(width: u32, height: u32) -> Option<usize> {
        usize::try_from(width)
            .ok()?
            .checked_mul(usize::try_from(height).ok()?)?
            .checked_mul(3)
    }

    /// The pixel buffer has exactly `width * height * 3` bytes.
    #[must_use]
    pub fn is_consistent(&self) -> bool {
        Self::byte_len(self.width, self.height) == Some(self.pixels.len())
    }

    fn offset(&self, x: u32, y: u32) -> Option<usize> {
        if x >= self.width || y >= self.height {
            return None;
        }
        let row = usize::try_from(y)
            .ok()?
            .checked_mul(usize::try_from(self.width).ok()?)?;
        row.checked_add(usize::try_from(x).ok()?)?.checked_mul(3)
    }

    /// The `[r, g, b]` of pixel (`x`, `y`), `None` outside the image.
    #[must_use]
    pub fn pixel(&self, x: u32, y: u32) -> Option<[u8; 3]> {
        let o = self.offset(x, y)?;
        match self.pixels.get(o..o.checked_add(3)?)? {
            [r, g, b] => Some([*r, *g, *b]),
            _ => None,
        }
    }

    /// Set pixel (`x`, `y`); returns `false` outside the image.
    pub fn set_pixel(&mut self, x: u32, y: u32, rgb: [u8; 3]) -> bool {
        let Some(o) = self.offset(x, y) else {
            return false;
        };
        let Some(end) = o.checked_add(3) else {
            return false;
        };
        match self.pixels.get_mut(o..end) {
            Some(px) => {
                px.copy_from_slice(&rgb);
                true
            }
            None => false,
        }
    }
}

/// Something that delivers camera images: a frame grabber, or the simulated camera head of the
/// mock devices (feature `std`).
#[cfg(feature = "std")]
pub trait FrameSource: ErrorType {
    /// Grab the next complete frame. The stamp is when the image was exposed (or, if the
    /// source cannot tell, when it was received); [`Frame::channel`] is the mux channel it
    /// came from where known.
    fn grab(&mut self) -> impl Future<Output = Result<crate::Stamped<Frame>, Self::Error>> + Send;
}

#[cfg(all(test, feature = "std"))]
mod tests {
    use super::*;

    #[test]
    fn frame_pixels_bounds_checked() {
        let mut f = Frame::black(4, 2, Some(3)).unwrap();
        assert!(f.is_consistent());
        assert_eq!(f.pixels.len(), 24);
        assert!(f.set_pixel(3, 1, [1, 2, 3]));
        assert_eq!(f.pixel(3, 1), Some([1, 2, 3]));
        assert_eq!(&f.pixels[21..24], &[1, 2, 3]);
        assert_eq!(f.pixel(4, 0), None);
        assert!(!f.set_pixel(0, 2, [9, 9, 9]));
        assert_eq!(
            Frame::byte_len(u32::MAX, u32::MAX).is_some(),
            usize::BITS > 64
        );
    }
}
