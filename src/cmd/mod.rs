//! One module per sub-command.

pub mod decode;
pub mod decode_sick;
pub mod demo;
pub mod drive;
pub mod mock;
pub mod mock_sick;
pub mod san;
pub mod scan;
