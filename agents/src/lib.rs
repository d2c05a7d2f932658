//! `ima-agents`: the robots' agents. They depend on `ima-hal` only, never on a driver.
//!
//! **Status:** not implemented yet; this crate is a placeholder in the workspace layout.
#![warn(missing_docs)]
