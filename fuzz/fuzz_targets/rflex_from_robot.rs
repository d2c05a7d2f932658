#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| ima_rflex::fuzz_harness::rflex_from_robot(data));
