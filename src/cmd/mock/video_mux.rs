//! `ima mock video-mux`: serve a mock Extron SIS (or Kramer Protocol 2000) video switcher.

use std::time::Duration;

use anyhow::{Context, Result};
use ima_mock_devices::pty::{PtyDevice, PtyOptions};
use ima_mock_devices::video_mux::{MuxDevice, MuxDialect, MuxModelConfig, VideoBus};

use super::shared::announce_and_wait;

/// Options of the mock switcher (the switcher-specific flags of `ima mock`).
#[derive(Debug, Clone, Copy)]
pub struct MockMuxOptions {
    /// Number of inputs.
    pub inputs: u8,
    /// Switch delay.
    pub switch_delay: Duration,
    /// Refuse selections with E06 (front-panel auto-switch mode).
    pub auto_switch: bool,
    /// Speak Kramer Protocol 2000 instead of Extron SIS.
    pub kramer: bool,
}

/// `ima mock video-mux`; `seed` seeds the faults (unless the spec names its own `seed=`).
pub fn run_mock(faults: &str, seed: u64, opts: MockMuxOptions) -> Result<()> {
    let plan = super::shared::fault_plan(faults, Some(seed))?;
    let cfg = MuxModelConfig {
        dialect: if opts.kramer {
            MuxDialect::Kramer
        } else {
            MuxDialect::Extron
        },
        inputs: opts.inputs,
        switch_delay: opts.switch_delay,
        auto_switch: opts.auto_switch,
        ..MuxModelConfig::default()
    };
    let dev = PtyDevice::spawn(
        MuxDevice::new(cfg, VideoBus::default()),
        PtyOptions {
            faults: plan,
            ..PtyOptions::default()
        },
    )
    .context("starting the pty")?;
    let what = if opts.kramer {
        "Kramer switcher"
    } else {
        "Extron switcher"
    };
    announce_and_wait(dev.path(), what)?;
    let model = dev
        .stop()
        .map_err(|e| anyhow::anyhow!("stopping the pty: {e}"))?;
    let st = model.stats();
    eprintln!(
        "stopped: {} commands, {} switches, {} error replies",
        st.commands, st.switches, st.errors
    );
    Ok(())
}
