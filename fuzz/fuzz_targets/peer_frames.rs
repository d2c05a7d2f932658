#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| ima_agents::fuzz_harness::peer_frames(data));
