#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| iogate::fuzz::modbus_tcp_request(data));
