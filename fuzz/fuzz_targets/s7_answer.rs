#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| iogate::fuzz::s7_answer(data));
