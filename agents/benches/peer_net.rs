//! Loopback benchmarks of the Peer Agent net shell.
fn main() {}
