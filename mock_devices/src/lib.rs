//! `ima-mock-devices`: robot-side protocol models on a simulated world.
//!
//! **Status:** the P2OS firmware model ([`p2os`]); the world, pty runner and fault injector are
//! being built.
#![warn(missing_docs)]

pub mod p2os;
