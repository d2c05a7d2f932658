#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| ima_agents::fuzz_harness::ses_shared_form(data));
