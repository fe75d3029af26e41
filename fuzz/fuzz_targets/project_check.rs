#![no_main]
libfuzzer_sys::fuzz_target!(|d: &[u8]| cloudcontrol_fuzz::project_check(d));
