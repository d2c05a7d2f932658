//! One module per sub-command.

pub mod decode;
pub mod demo;
pub mod drive;
pub mod mock;
pub mod san;
