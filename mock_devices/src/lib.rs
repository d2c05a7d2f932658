//! `ima-mock-devices`: robot-side protocol models on a simulated world.
//!
//! **Status:** being built; nothing is exported yet.
#![warn(missing_docs)]
