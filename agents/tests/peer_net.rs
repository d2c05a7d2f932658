//! Loopback tests of the Peer Agent net shell (feature `net`).
