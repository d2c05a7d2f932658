//! One module per sub-command.

//!
//! By area: [`decode`] (one module per protocol), [`mock`] (one per mock device, and the
//! whole world), [`drive`] (both bases, and `ima demo square`).

pub mod camera;
pub mod commander;
pub mod compass;
pub mod decode;
pub mod demo;
pub mod drive;
pub mod experiment;
#[cfg(test)]
mod layout_tests;
pub mod mock;
pub mod num;
pub mod output;
pub mod peer;
pub mod replay;
pub mod run;
pub mod san;
pub mod scan;

// The paths these modules had before the split by area, still used by `demo`, `run` and
// `crate::stack` (which other work is moving into `ima_agents::runtime`); switch those to the
// new paths and drop the aliases once that lands.
pub use self::drive::square as demo_square;
pub use self::mock::world as mock_world;

/// Checks that every target colour is one of `known`; the error lists the known colours
/// (`what` says where they come from, e.g. "the world's objects").
///
/// # Errors
/// The first unknown colour, with the known ones.
pub fn check_colours(targets: &[String], known: &[String], what: &str) -> anyhow::Result<()> {
    for t in targets {
        anyhow::ensure!(
            known.contains(t),
            "unknown target colour {t:?}; {what} are: {}",
            known.join(", ")
        );
    }
    Ok(())
}
