#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| iogate::fuzz::iec104_master(data));
