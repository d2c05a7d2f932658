//! One module per sub-command.

pub mod camera;
pub mod commander;
pub mod compass;
pub mod decode;
pub mod decode_compass;
pub mod decode_rflex;
pub mod decode_sick;
pub mod decode_video_mux;
pub mod demo;
pub mod demo_square;
pub mod drive;
pub mod drive_rflex;
pub mod experiment;
pub mod mock;
pub mod mock_rflex;
pub mod mock_sick;
pub mod mock_world;
pub mod num;
pub mod output;
pub mod peer;
pub mod replay;
pub mod run;
pub mod san;
pub mod scan;

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
