//! Skeeter's stack (waiting for `mission::skeeter` and `mission::scan`).

use anyhow::Result;
use ima_agents::peer::wire::GroupKey;
use tokio::sync::watch;

use super::Events;
use super::devices::SkeeterDevices;
use crate::config::RobotConfig;

/// Run Skeeter until `stop` turns true.
pub async fn run(
    _cfg: RobotConfig,
    _key: GroupKey,
    _dev: SkeeterDevices,
    _events: Events,
    _stop: watch::Receiver<bool>,
) -> Result<()> {
    anyhow::bail!("Skeeter's stack is not built yet")
}
