#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| iogate::fuzz::bacnet_answer(data));
