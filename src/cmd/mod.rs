//! One module per sub-command.

pub mod decode;
pub mod decode_rflex;
pub mod demo;
pub mod drive;
pub mod drive_rflex;
pub mod mock;
pub mod mock_rflex;
pub mod san;
