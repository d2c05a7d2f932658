//! The SICK LMS driver's errors, as the person at the robot reads them.

use ima_sick_lms::driver::{DriverError, Fault};
use ima_sick_lms::machine::MachineError;

/// What `ima scan` printed when the unit stopped answering: the Debug form
/// `Timeout { code: 58 }`, which names neither the command nor what happened.
#[test]
fn a_session_error_names_the_command_in_words() {
    let text = |e: MachineError| DriverError::from(e).to_string();
    assert_eq!(
        text(MachineError::Timeout { code: 0x3A }),
        "SICK LMS session: no answer to command 3Ah (request type) after every retry"
    );
    assert_eq!(
        text(MachineError::Refused {
            code: 0x77,
            result: 0
        }),
        "SICK LMS session: command 77h (write configuration) refused (result 00h)"
    );
    assert_eq!(
        text(MachineError::Nak { code: 0x99 }),
        "SICK LMS session: command 99h NAKed on every attempt"
    );
    let decode = DriverError::Device(Fault::Decode(
        ima_sick_lms::decode::DecodeError::UnknownMeasuringMode(0x0F),
    ));
    assert_eq!(
        decode.to_string(),
        "SICK LMS scan decoding: unknown measuring mode 0x0f"
    );
    for e in [
        MachineError::NoDevice,
        MachineError::Rejected { code: 0x20 },
        MachineError::DeviceError {
            status: ima_sick_lms::wire::StatusByte(0x07),
            device_status: 1,
        },
        MachineError::Busy,
        MachineError::StreamStalled,
    ] {
        let t = text(e);
        assert!(!t.contains('{') && !t.contains("Timeout"), "{t}");
    }
}
