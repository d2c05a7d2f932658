//! `ima mock <device>`: serve a mock device on a pseudo-terminal.

use anyhow::{Result, bail};
use clap::Args;

/// Arguments of `ima mock`.
#[derive(Debug, Args)]
pub struct MockArgs {
    /// Device to serve.
    device: String,
}

/// Run `ima mock`.
pub fn run(args: &MockArgs) -> Result<()> {
    bail!("mock device {:?} is not available yet", args.device)
}
