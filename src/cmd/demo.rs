//! `ima demo`: the demonstration on built-in mock devices.

use anyhow::{Result, bail};
use clap::Args;

/// Arguments of `ima demo`.
#[derive(Debug, Args)]
pub struct DemoArgs {}

/// Run `ima demo`.
pub fn run(_args: &DemoArgs) -> Result<()> {
    bail!("demo not available yet")
}
