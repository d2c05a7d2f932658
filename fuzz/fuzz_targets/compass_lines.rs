#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| ima_compass::fuzz_harness::compass_lines(data));
