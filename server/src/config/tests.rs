use super::*;
use crate::profile::Catalog;

const GOOD: &str = "listen:\n  http: 127.0.0.1:0\nlinks:\n  - name: rs485\n    serial: { port: /dev/ttyUSB0, baud: 9600, parity: N, data_bits: 8, stop_bits: 1 }\n  - name: plant\n    tcp: { host: 192.0.2.10, port: 502 }\ndevices:\n  - { name: io_rack, profile: MyIoModule, link: rs485, slave_id: 1, refresh_rate: 50ms }\n  - { name: pump_vfd, profile: MyVfd, link: rs485, slave_id: 2, refresh_rate: 100ms, timeout: 200ms }\n  - { name: sim, profile: SimIo, refresh_rate: T#100ms }\n";

#[test]
fn the_spec_example_parses() {
    let c = parse("iogate.yaml", GOOD).expect("parses");
    assert_eq!(c.http.port(), 0);
    assert_eq!(c.grpc.to_string(), DEFAULT_GRPC);
    assert_eq!(c.links.len(), 2);
    assert_eq!(c.devices[0].refresh_rate, Duration::from_millis(50));
    assert_eq!(c.devices[1].timeout, Duration::from_millis(200));
    assert_eq!(c.devices[2].refresh_rate, Duration::from_millis(100));
    assert_eq!(c.devices[2].link, None);
    assert_eq!(c.devices[2].line, 11);
}

#[test]
fn max_streams_is_read_and_bounded() {
    assert_eq!(
        parse(
            "c.yaml",
            "devices: []
"
        )
        .expect("parses")
        .max_streams,
        DEFAULT_MAX_STREAMS
    );
    let c = parse(
        "c.yaml",
        "listen: { max_streams: 12000 }
",
    )
    .expect("parses");
    assert_eq!(c.max_streams, 12_000);
    for (text, needle) in [
        (
            "listen: { max_streams: 0 }\n",
            "c.yaml:1: listen.max_streams: 0 is outside the allowed range 1-100000",
        ),
        (
            "listen: { max_streams: many }\n",
            "c.yaml:1: listen.max_streams:",
        ),
    ] {
        let all = problems(text);
        assert!(all.contains(needle), "missing {needle:?} in\n{all}");
    }
}

#[test]
fn max_connections_is_read_and_bounded() {
    let c = parse("c.yaml", "devices: []\n").expect("parses");
    assert_eq!(c.max_connections, DEFAULT_MAX_CONNECTIONS);
    let c = parse("c.yaml", "listen: { max_connections: 64 }\n").expect("parses");
    assert_eq!(c.max_connections, 64);
    assert_eq!(
        c.max_connections_per_client,
        DEFAULT_MAX_CONNECTIONS_PER_CLIENT
    );
    let text = "listen: { max_connections_per_client: 8, max_streams_per_client: 3 }\n";
    let c = parse("c.yaml", text).expect("parses");
    assert_eq!(
        (c.max_connections_per_client, c.max_streams_per_client),
        (8, 3)
    );
    let all = problems("listen: { max_connections: 0 }\n");
    let needle = "c.yaml:1: listen.max_connections: 0 is outside the allowed range 1-100000";
    assert!(all.contains(needle), "missing {needle:?} in\n{all}");
}

fn problems(text: &str) -> String {
    parse("c.yaml", text).expect_err("should fail").to_string()
}

#[test]
fn serial_settings_mismatch_on_one_port_is_an_error() {
    let text = "links:\n  - { name: a, serial: { port: /dev/ttyS0, baud: 9600 } }\n  - { name: b, serial: { port: /dev/ttyS0, baud: 19200, parity: E } }\n";
    let all = problems(text);
    assert!(all.contains("c.yaml:3: link b: Baudrate configuration mismatch.\n    /dev/ttyS0: 19200 here, 9600 in link a (line 2)"), "{all}");
    assert!(all.contains("Parity configuration mismatch"), "{all}");
}

#[test]
fn every_config_problem_is_reported() {
    let text = "listen: { http: localhost }\nlinks:\n  - { name: a, serial: { port: /dev/x, baud: 9600, parity: X, stop_bits: 3 } }\ndevices:\n  - { name: d, profile: P, slave_id: 300, refresh_rate: 50 }\n  - { name: d, profile: P, refresh_rate: soon, colour: red }\n";
    let all = problems(text);
    for needle in [
        "c.yaml:1: listen.http: `localhost` is not an address",
        "c.yaml:3: link a: serial.parity: Invalid parity configuration.\n    `X` is not N, E or O",
        "c.yaml:3: link a: serial.stop_bits: Invalid stop bits configuration.\n    3 stop bits: 1 or 2",
        "c.yaml:5: device d: slave_id: 300 is outside",
        "c.yaml:5: device d: refresh_rate: `50` has no unit",
        "c.yaml:6: device d: refresh_rate: `soon` is not a duration",
        "c.yaml:6: device d: unknown key `colour`",
        "c.yaml:6: device d: duplicate device name (first defined on line 5)",
    ] {
        assert!(all.contains(needle), "missing {needle:?} in\n{all}");
    }
}

#[test]
fn devices_are_checked_against_profiles_and_links() {
    let config = parse("c.yaml", "links:\n  - { name: bus, tcp: { host: 127.0.0.1 } }\ndevices:\n  - { name: a, profile: Sim, link: bus }\n  - { name: b, profile: Meter }\n  - { name: c, profile: Nope }\n  - { name: e, profile: Meter, link: other, slave_id: 1 }\n").expect("parses");
    let sim = crate::profile::load_str("s.yaml", "name: Sim\nprotocol: simulated\nfields:\n  - { name: X, type: BOOL, direction: input, register: { address: 0, kind: virtual } }\n").expect("sim");
    let real = crate::profile::load_str("r.yaml", "name: Meter\nfields:\n  - { name: X, type: BOOL, direction: input, register: { address: 0, kind: coil } }\n").expect("real");
    let catalog = Catalog::new([sim, real]);
    let all = check_devices(&config, &catalog)
        .expect_err("fails")
        .to_string();
    for needle in [
        "c.yaml:4: device a: a simulated device has no link",
        "c.yaml:5: device b: profile Meter is modbus-rtu: the device needs a `link`",
        "c.yaml:5: device b: no slave configured",
        "c.yaml:6: device c: unknown profile `Nope` (known: Meter, Sim)",
        "c.yaml:7: device e: unknown link `other` (known: bus)",
    ] {
        assert!(all.contains(needle), "missing {needle:?} in\n{all}");
    }
}

proptest::proptest! {
    #[test]
    fn arbitrary_text_never_panics(text in "\\PC{0,300}") {
        let _ = parse("fuzz.yaml", &text);
    }

    #[test]
    fn mutated_configs_never_panic(
        at in proptest::prelude::any::<proptest::sample::Index>(),
        insert in "[ \\-:{}\\[\\],#'\"a-z0-9\n]{0,4}",
        cut in 0usize..6,
    ) {
        let _ = parse("fuzz.yaml", &crate::yaml::mutate(GOOD, at, &insert, cut));
    }
}

#[test]
fn names_are_bounded_identifiers_unique_ignoring_case() {
    let long = "x".repeat(65);
    let text = format!(
        "devices:\n  - {{ name: '', profile: P }}\n  - {{ name: a/b, profile: P }}\n  - {{ name: '..', profile: P }}\n  - {{ name: Sim, profile: P }}\n  - {{ name: sim, profile: P }}\n  - {{ name: {long}, profile: P }}\n  - {{ name: io_rack-2.b, profile: P }}\n"
    );
    let all = problems(&text);
    for needle in [
        "c.yaml:2: devices[0]: name: `` is not a name",
        "c.yaml:3: devices[1]: name: `a/b` is not a name",
        "c.yaml:4: devices[2]: name: `..` is not a name",
        "c.yaml:6: device sim: duplicate device name (first defined on line 5)",
        "c.yaml:7: devices[5]: name: `xxxxxxxx",
    ] {
        assert!(all.contains(needle), "missing {needle:?} in\n{all}");
    }
    assert!(!all.contains("io_rack-2.b"), "{all}");
}

#[test]
fn empty_config_is_valid() {
    let c = parse("c.yaml", "").expect("empty is fine");
    assert!(c.devices.is_empty());
}
