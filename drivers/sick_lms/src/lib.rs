//! `ima-sick-lms`: SICK LMS 200/291 laser scanner protocol: sans-IO wire, framer and session.
//!
//! **Status:** not implemented yet; this crate is a placeholder in the workspace layout and
//! exports nothing.
#![cfg_attr(not(feature = "std"), no_std)]
#![warn(missing_docs)]
