//! The compass driver's errors, as the person at the robot reads them.

use ima_compass::driver::{DriverError, Fault};
use ima_compass::machine::Job;

/// A calibration that got no answer said `compass job StartUserCalibration failed at step 1`:
/// the job in words now.
#[test]
fn a_job_that_failed_is_named_in_words() {
    let e = DriverError::Device(Fault::JobFailed {
        job: Job::StartUserCalibration,
        step: 1,
    });
    assert_eq!(
        e.to_string(),
        "the compass's start of the user calibration got no answer (step 1)"
    );
    let e = Fault::JobFailed {
        job: Job::AutoCalibration(false),
        step: 0,
    };
    assert!(
        e.to_string()
            .contains("switching automatic calibration off")
    );
}
