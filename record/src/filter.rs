//! Topics left out of a recording (`--record-exclude`).
//!
//! A pattern is a topic path: `/`-separated segments, where a segment `*` stands for any one
//! segment. A pattern leaves out every topic whose leading segments it matches, so
//! `/*/camera` leaves out `/skeeter/camera` and `/skeeter/camera/3` but not
//! `/skeeter/cameras`, and `/scooter/serial/laser` leaves out that one raw port. (Like the
//! `--exclude` of `ros2 bag record`, but by topic path rather than regular expression.)
//!
//! Leaving topics out of the file is the way to record for less: in the demo, camera frames are
//! four fifths of the bytes logged and about a third of what recording costs (the README's
//! measurements). A left-out raw port cannot be replayed or decoded later.

use std::sync::Arc;

/// A pattern that cannot match any topic.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FilterError {
    /// Topics start with `/`.
    #[error("topic pattern {0:?} does not start with '/' (e.g. /*/camera)")]
    NotAbsolute(String),
    /// An empty segment (`//`, a trailing `/`) or a segment with `*` in it besides `*` alone.
    #[error("topic pattern {pattern:?}: segment {segment} is {what} (a segment is a name or *)")]
    BadSegment {
        /// The pattern.
        pattern: String,
        /// The segment's position, from 1.
        segment: usize,
        /// What is wrong with it.
        what: &'static str,
    },
}

/// One checked pattern.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TopicPattern {
    text: String,
}

impl TopicPattern {
    /// Check a pattern.
    pub fn new(text: &str) -> Result<Self, FilterError> {
        let rest = text
            .strip_prefix('/')
            .ok_or_else(|| FilterError::NotAbsolute(text.to_owned()))?;
        for (i, seg) in rest.split('/').enumerate() {
            let what = if seg.is_empty() {
                "empty"
            } else if seg != "*" && seg.contains('*') {
                "a partial wildcard"
            } else {
                continue;
            };
            return Err(FilterError::BadSegment {
                pattern: text.to_owned(),
                segment: i + 1,
                what,
            });
        }
        Ok(Self {
            text: text.to_owned(),
        })
    }

    /// The pattern as given.
    #[must_use]
    pub fn as_str(&self) -> &str {
        &self.text
    }

    /// Whether `topic`'s leading segments match this pattern.
    #[must_use]
    pub fn matches(&self, topic: &str) -> bool {
        let Some(topic) = topic.strip_prefix('/') else {
            return false;
        };
        let mut segs = topic.split('/');
        let pattern = self.text.strip_prefix('/').unwrap_or(&self.text);
        pattern
            .split('/')
            .all(|p| segs.next().is_some_and(|s| p == "*" || p == s))
    }
}

impl std::str::FromStr for TopicPattern {
    type Err = FilterError;
    fn from_str(s: &str) -> Result<Self, FilterError> {
        Self::new(s)
    }
}

impl std::fmt::Display for TopicPattern {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.text)
    }
}

/// The topics a recording leaves out (none by default). Cheap to clone.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct TopicFilter {
    patterns: Arc<[TopicPattern]>,
}

impl TopicFilter {
    /// Leave out what any of `patterns` matches.
    #[must_use]
    pub fn new(patterns: Vec<TopicPattern>) -> Self {
        Self {
            patterns: patterns.into(),
        }
    }

    /// Whether `topic` is left out.
    #[must_use]
    pub fn excludes(&self, topic: &str) -> bool {
        self.patterns.iter().any(|p| p.matches(topic))
    }

    /// Whether nothing is left out.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.patterns.is_empty()
    }

    /// The patterns that match none of `topics` (a typo, or a device that never logged), as
    /// given.
    #[must_use]
    pub fn unmatched<'a>(&self, topics: impl Iterator<Item = &'a str> + Clone) -> Vec<String> {
        self.patterns
            .iter()
            .filter(|p| !topics.clone().any(|t| p.matches(t)))
            .map(|p| p.as_str().to_owned())
            .collect()
    }

    /// The patterns, as given, comma-separated.
    #[must_use]
    pub fn describe(&self) -> String {
        let v: Vec<&str> = self.patterns.iter().map(TopicPattern::as_str).collect();
        v.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn p(s: &str) -> TopicPattern {
        TopicPattern::new(s).unwrap()
    }

    #[test]
    fn patterns_match_leading_segments() {
        let cam = p("/*/camera");
        assert!(cam.matches("/skeeter/camera"));
        assert!(cam.matches("/skeeter/camera/3"));
        assert!(!cam.matches("/skeeter/cameras"));
        assert!(!cam.matches("/camera"));
        assert!(!cam.matches("skeeter/camera"));
        let laser = p("/scooter/serial/laser");
        assert!(laser.matches("/scooter/serial/laser"));
        assert!(!laser.matches("/scooter/serial/base"));
        assert!(!laser.matches("/skeeter/serial/laser"));
    }

    #[test]
    fn bad_patterns_are_named() {
        assert_eq!(
            TopicPattern::new("camera"),
            Err(FilterError::NotAbsolute("camera".into()))
        );
        let e = TopicPattern::new("/skeeter//camera").unwrap_err();
        assert!(e.to_string().contains("segment 2 is empty"), "{e}");
        let e = TopicPattern::new("/skeeter/cam*").unwrap_err();
        assert!(
            e.to_string().contains("segment 2 is a partial wildcard"),
            "{e}"
        );
        assert!(TopicPattern::new("/skeeter/").is_err());
        assert!(TopicPattern::new("/").is_err());
        assert!(TopicPattern::new("").is_err());
    }

    #[test]
    fn a_filter_leaves_out_what_any_pattern_matches() {
        let f = TopicFilter::new(vec![p("/*/camera"), p("/broadcasts")]);
        assert!(f.excludes("/skeeter/camera/2"));
        assert!(f.excludes("/broadcasts"));
        assert!(!f.excludes("/scooter/scan"));
        assert_eq!(f.describe(), "/*/camera, /broadcasts");
        let topics = ["/skeeter/camera/2", "/scooter/scan"];
        assert_eq!(f.unmatched(topics.iter().copied()), ["/broadcasts"]);
        assert!(!TopicFilter::default().excludes("/skeeter/camera"));
    }

    proptest! {
        /// A topic's own path, and any of its prefixes with segments starred, match it; a
        /// pattern one segment longer than the topic does not.
        #[test]
        fn prefixes_match(
            segs in proptest::collection::vec("[a-z_0-9]{1,6}", 1..6),
            cut in 1usize..6,
            stars in proptest::collection::vec(any::<bool>(), 6),
        ) {
            let topic = format!("/{}", segs.join("/"));
            let n = cut.min(segs.len());
            let pat: Vec<&str> = segs[..n]
                .iter()
                .zip(&stars)
                .map(|(s, &star)| if star { "*" } else { s.as_str() })
                .collect();
            let pat = p(&format!("/{}", pat.join("/")));
            prop_assert!(pat.matches(&topic));
            let longer = p(&format!("{topic}/x"));
            prop_assert!(!longer.matches(&topic));
        }

        /// Any text is either a pattern or a named error, never a panic; a pattern matches
        /// without panicking on any topic.
        #[test]
        fn never_panics(pattern in ".{0,20}", topic in ".{0,20}") {
            if let Ok(p) = TopicPattern::new(&pattern) {
                let _ = p.matches(&topic);
                prop_assert_eq!(p.to_string(), pattern);
            }
        }
    }
}
