//! `ima-video-mux`: Serial video switchers (Extron SIS, Kramer Protocol 2000) and frame sources.
//!
//! **Status:** not implemented yet; this crate is a placeholder in the workspace layout and
//! exports nothing.
#![cfg_attr(not(feature = "std"), no_std)]
#![warn(missing_docs)]
