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
pub mod peer;
pub mod run;
pub mod san;
pub mod scan;
