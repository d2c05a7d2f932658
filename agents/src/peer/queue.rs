//! A bounded queue with latest-value semantics (PEER.md, Manager rule 6).

use std::collections::VecDeque;

/// A bounded FIFO that, when full, drops its **oldest** element to make room: a slow consumer
/// of sensor data loses old samples, never blocks the producer, and memory stays bounded.
#[derive(Debug, Clone)]
pub struct LatestQueue<T> {
    items: VecDeque<T>,
    cap: usize,
    dropped: u64,
}

impl<T> LatestQueue<T> {
    /// A queue holding at most `cap` items (at least 1).
    #[must_use]
    pub fn new(cap: usize) -> Self {
        let cap = cap.max(1);
        Self {
            items: VecDeque::with_capacity(cap),
            cap,
            dropped: 0,
        }
    }

    /// Appends `item`; if the queue was full, the oldest item is dropped and returned.
    pub fn push(&mut self, item: T) -> Option<T> {
        let old = if self.items.len() >= self.cap {
            self.dropped = self.dropped.saturating_add(1);
            self.items.pop_front()
        } else {
            None
        };
        self.items.push_back(item);
        old
    }

    /// Takes the oldest item still held.
    pub fn pop(&mut self) -> Option<T> {
        self.items.pop_front()
    }

    /// The newest item, if any.
    #[must_use]
    pub fn latest(&self) -> Option<&T> {
        self.items.back()
    }

    /// Items held.
    #[must_use]
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// Whether the queue is empty.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Capacity.
    #[must_use]
    pub fn capacity(&self) -> usize {
        self.cap
    }

    /// Items dropped so far because the queue was full.
    #[must_use]
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Removes everything.
    pub fn clear(&mut self) {
        self.items.clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_latest_values_and_counts_drops() {
        let mut q = LatestQueue::new(3);
        for i in 0..10 {
            q.push(i);
        }
        assert_eq!(q.len(), 3);
        assert_eq!(q.dropped(), 7);
        assert_eq!(q.latest(), Some(&9));
        assert_eq!(q.pop(), Some(7));
        assert_eq!(q.pop(), Some(8));
        assert_eq!(q.pop(), Some(9));
        assert_eq!(q.pop(), None);
    }

    #[test]
    fn zero_capacity_means_one() {
        let mut q = LatestQueue::new(0);
        assert_eq!(q.push(1), None);
        assert_eq!(q.push(2), Some(1));
        assert_eq!(q.latest(), Some(&2));
    }
}
