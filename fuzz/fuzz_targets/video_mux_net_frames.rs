#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| ima_video_mux::fuzz_harness::video_mux_net_frames(data));
