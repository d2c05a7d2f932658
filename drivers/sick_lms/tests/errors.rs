//! The SICK LMS driver's errors, as the person at the robot reads them.

use ima_hal::ErrorKind;
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
    for (e, words) in [
        (
            MachineError::NoDevice,
            "no SICK LMS answered at 9600, 38400 or 19200 baud (nor 500000 with RS-422; \
             powered? still booting?)",
        ),
        (
            MachineError::Rejected { code: 0x20 },
            "SICK LMS session: command 20h (change operating mode) rejected (92h)",
        ),
        (
            MachineError::DeviceError {
                status: ima_sick_lms::wire::StatusByte(0x07),
                device_status: 1,
            },
            "SICK LMS session: the unit reports an error (status byte 07h, device status 01h)",
        ),
        (
            MachineError::NotAsAsked { code: 0x3B },
            "SICK LMS session: the unit confirmed command 3Bh (switch variant) with other \
             settings than asked",
        ),
        (
            MachineError::NeedsRs422,
            "SICK LMS session: 500000 baud needs an RS-422 line (set rs422 if this is one)",
        ),
        (
            MachineError::BaudMismatch,
            "SICK LMS session: the unit reports another line speed than the one just set",
        ),
        (
            MachineError::Unsendable { code: 0x77 },
            "SICK LMS session: command 77h (write configuration) did not fit the transmit \
             buffer (a bug of this driver)",
        ),
        (
            MachineError::Busy,
            "SICK LMS session: another request is in progress",
        ),
        (
            MachineError::StreamStalled,
            "SICK LMS session: the scan stream stopped arriving",
        ),
    ] {
        assert_eq!(text(e), words);
    }
    // The session's own words for "nobody answered" are the driver's.
    assert_eq!(
        MachineError::NoDevice.to_string(),
        text(MachineError::NoDevice)
    );
}

/// A unit that never answered: the rates tried, and the one left out without RS-422.
#[test]
fn not_found_names_the_rates_and_the_one_not_tried() {
    let mut report = ima_hal::link::ProbeReport::new();
    for b in [9600, 38400, 19200] {
        report.attempt(b);
    }
    let e = DriverError::Device(Fault::NotFound {
        report: Box::new(report.clone()),
        rs422: false,
    });
    let text = e.to_string();
    assert!(
        text.ends_with(
            "silence at every rate tried (9600, 38400, 19200); 500000 baud not tried (RS-422 lines only)"
        ),
        "{text}"
    );
    assert!(!text.contains("any rate"));
    assert_eq!(ima_hal::Error::kind(&e), ErrorKind::Timeout);
    report.attempt(500_000);
    let e = DriverError::Device(Fault::NotFound {
        report: Box::new(report),
        rs422: true,
    });
    assert!(e.to_string().ends_with("(9600, 38400, 19200, 500000)"));
}

/// How a program can tell the failures apart.
#[test]
fn error_kinds() {
    use ima_hal::Error as _;
    assert_eq!(
        DriverError::from(MachineError::NoDevice).kind(),
        ErrorKind::Timeout
    );
    assert_eq!(
        DriverError::from(MachineError::Rejected { code: 0x3B }).kind(),
        ErrorKind::Protocol
    );
    assert_eq!(DriverError::Disconnected.kind(), ErrorKind::Disconnected);
    assert!(!DriverError::Timeout.to_string().is_empty());
}
