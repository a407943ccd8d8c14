#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| iogate::fuzz::json_write(data));
