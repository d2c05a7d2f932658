#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| ima_sick_lms::fuzz_harness::sick_lms_roundtrip(data));
