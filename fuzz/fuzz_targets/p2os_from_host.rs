#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| ima_p2os::fuzz_harness::p2os_from_host(data));
