//! The video switcher driver's errors, as the person at the robot reads them.

use ima_video_mux::driver::{DriverError, Fault};
use ima_video_mux::machine::Refusal;
use ima_video_mux::wire::extron::ExtronError;

/// The switcher's refusal said `E01 (InvalidInput)`.
#[test]
fn a_refusal_is_named_in_words() {
    let e = DriverError::Device(Fault::Refused(Refusal::Extron(ExtronError::InvalidInput)));
    assert_eq!(
        e.to_string(),
        "the switcher refused: E01 (invalid input number)"
    );
    let other = Fault::Refused(Refusal::Extron(ExtronError::Other(17)));
    assert_eq!(
        other.to_string(),
        "the switcher refused: E17 (an error code this driver does not know)"
    );
}
