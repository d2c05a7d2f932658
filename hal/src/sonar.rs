//! Ultrasonic range-finder arrays.

use core::future::Future;

use crate::{ErrorType, Instant, Isometry2, Stamped};

/// Most transducers any supported array has (P2OS addresses 0–31).
pub const MAX_SONARS: usize = 32;

/// Where a transducer sits on the robot and what it can measure.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarTransducer {
    /// Pose of the transducer in the robot frame; its x axis is the beam axis.
    pub pose: Isometry2,
    /// Shortest range it reports, metres.
    pub min_range_m: f64,
    /// Longest range it reports; a reading at this value means "no echo".
    pub max_range_m: f64,
    /// Full beam width, radians.
    pub beam_width_rad: f64,
}

/// One range from one transducer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SonarReading {
    /// Index into [`SonarArray::transducers`].
    pub index: u8,
    /// Range along the beam, metres.
    pub range_m: f64,
    /// When this transducer last fired.
    pub at: Instant,
}

/// The latest reading of every transducer that has reported, in index order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SonarScan {
    /// Readings, at most one per transducer, sorted by index.
    pub readings: heapless::Vec<SonarReading, MAX_SONARS>,
}

impl SonarScan {
    /// The reading of transducer `index`, if it has reported.
    #[must_use]
    pub fn get(&self, index: u8) -> Option<&SonarReading> {
        self.readings.iter().find(|r| r.index == index)
    }

    /// Insert or replace the reading of `r.index`, keeping index order.
    /// Returns `false` (and drops the reading) only if the scan is full.
    pub fn upsert(&mut self, r: SonarReading) -> bool {
        match self.readings.binary_search_by_key(&r.index, |x| x.index) {
            Ok(pos) => {
                if let Some(slot) = self.readings.get_mut(pos) {
                    *slot = r;
                }
                true
            }
            Err(pos) => self.readings.insert(pos, r).is_ok(),
        }
    }
}

/// An array of sonar transducers.
pub trait SonarArray: ErrorType {
    /// The transducers' geometry, indexed as in [`SonarReading::index`].
    fn transducers(&self) -> &[SonarTransducer];

    /// Turn firing on or off.
    fn set_sonar_enabled(&mut self, on: bool) -> impl Future<Output = Result<(), Self::Error>> + Send;

    /// The latest reading of each transducer (waits for the first reading).
    fn sonar(&mut self) -> impl Future<Output = Result<Stamped<SonarScan>, Self::Error>> + Send;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn r(index: u8, range_m: f64) -> SonarReading {
        SonarReading {
            index,
            range_m,
            at: Instant::ZERO,
        }
    }

    #[test]
    fn upsert_keeps_order_and_replaces() {
        let mut s = SonarScan::default();
        assert!(s.upsert(r(7, 1.0)));
        assert!(s.upsert(r(0, 2.0)));
        assert!(s.upsert(r(7, 3.0)));
        let idx: Vec<u8> = s.readings.iter().map(|x| x.index).collect();
        assert_eq!(idx, vec![0, 7]);
        assert_eq!(s.get(7).map(|x| x.range_m), Some(3.0));
        assert!(s.get(3).is_none());
    }

    #[test]
    fn upsert_refuses_when_full() {
        let mut s = SonarScan::default();
        for i in 0..MAX_SONARS as u8 {
            assert!(s.upsert(r(i, 1.0)));
        }
        assert!(!s.upsert(r(200, 1.0)));
        assert!(s.upsert(r(3, 9.0)), "replacing still works when full");
    }
}
