use std::path::{Path, PathBuf};

use super::*;

fn profiles() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../profiles")
}

/// A setup from config text, with profiles from `dir`.
fn setup_in(dir: &Path, text: &str) -> Setup {
    let text = format!("profiles: {}\n{text}", dir.display());
    let config = crate::config::parse("iogate.yaml", &text).expect("config parses");
    Setup::from_config(config, Path::new(".")).expect("config checks")
}

fn setup(text: &str) -> Setup {
    setup_in(&profiles(), text)
}

fn tokens(text: &str) -> Tokens {
    Tokens::parse(text).expect("tokens")
}

fn compare(a: &Setup, b: &Setup) -> Diff {
    diff(a, &Tokens::default(), b, &Tokens::default())
}

fn item<'d>(d: &'d Diff, kind: Kind, name: &str) -> &'d Item {
    d.items
        .iter()
        .find(|i| i.kind == kind && i.name == name)
        .unwrap_or_else(|| panic!("no {kind:?} {name} in {:?}", d.items))
}

const LINE: &str = "links:\n  - { name: bus, serial: { port: /dev/ttyUSB0, baud: 9600 } }\n  - { name: plant, tcp: { host: 192.0.2.10, port: 502 } }\n";

fn devices(rate: &str) -> String {
    format!(
        "devices:\n  - {{ name: rack, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms }}\n  - {{ name: vfd, profile: GenericVfd, link: plant, slave_id: 2, refresh_rate: {rate} }}\n"
    )
}

#[test]
fn the_same_files_differ_in_nothing_whatever_their_lines() {
    let a = setup(&format!("{LINE}{}", devices("100ms")));
    let b = setup(&format!("# a comment\n\n{LINE}\n{}", devices("100ms")));
    let d = compare(&a, &b);
    assert!(d.is_empty(), "{:?}", d.items);
    assert!(d.devices.is_empty() && d.links.is_empty());
}

#[test]
fn a_device_setting_re_plans_that_device_only() {
    let a = setup(&format!("{LINE}{}", devices("100ms")));
    let b = setup(&format!("{LINE}{}", devices("20ms")));
    let d = compare(&a, &b);
    assert_eq!(d.devices.changed, vec!["vfd".to_owned()]);
    assert!(d.devices.added.is_empty() && d.devices.removed.is_empty());
    assert!(d.links.is_empty(), "no link reopened: {:?}", d.links);
    let vfd = item(&d, Kind::Device, "vfd");
    assert_eq!(vfd.action, Action::Changed);
    assert!(
        vfd.details
            .iter()
            .any(|x| x == "refresh_rate: 100ms -> 20ms"),
        "{:?}",
        vfd.details
    );
}

#[test]
fn devices_added_and_removed_and_a_link_whose_settings_changed() {
    let a = setup(&format!("{LINE}{}", devices("100ms")));
    let b = setup(&format!(
        "{}devices:\n  - {{ name: rack, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms }}\n  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}\n",
        LINE.replace("baud: 9600", "baud: 19200")
    ));
    let d = compare(&a, &b);
    assert_eq!(d.links.changed, vec!["bus".to_owned()]);
    assert_eq!(d.devices.added, vec!["sim".to_owned()]);
    assert_eq!(d.devices.removed, vec!["vfd".to_owned()]);
    // A device on a reopened link is not re-planned for it.
    assert!(d.devices.changed.is_empty(), "{:?}", d.devices);
    let bus = item(&d, Kind::Link, "bus");
    assert!(
        bus.details
            .iter()
            .any(|x| x == "serial.baud: 9600 -> 19200"),
        "{:?}",
        bus.details
    );
    assert_eq!(item(&d, Kind::Device, "sim").action, Action::Added);
    assert_eq!(item(&d, Kind::Device, "vfd").action, Action::Removed);
}

#[test]
fn a_profile_edit_names_its_fields_and_re_plans_the_devices_using_it() {
    let dir = tempfile::tempdir().expect("temp dir");
    let profile = |ty: &str, extra: &str| {
        format!(
            "name: Meter\nfields:\n  - {{ name: V, type: {ty}, direction: input, register: {{ address: 0, kind: input_register }} }}\n  - {{ name: A, type: UINT, direction: input, register: {{ address: 1, kind: input_register }} }}\n{extra}"
        )
    };
    let config = "links:\n  - { name: bus, serial: { port: /dev/ttyUSB0, baud: 9600 } }\ndevices:\n  - { name: m, profile: Meter, link: bus, slave_id: 1, refresh_rate: 1s }\n";
    std::fs::write(dir.path().join("meter.yaml"), profile("UINT", "")).expect("write");
    let a = setup_in(dir.path(), config);
    std::fs::write(
        dir.path().join("meter.yaml"),
        profile(
            "INT",
            "  - { name: W, type: UINT, direction: input, register: { address: 2, kind: input_register } }\n",
        ),
    )
    .expect("write");
    let b = setup_in(dir.path(), config);
    let d = compare(&a, &b);
    assert!(d.profiles);
    assert_eq!(d.devices.changed, vec!["m".to_owned()]);
    assert_eq!(item(&d, Kind::Profile, "Meter").action, Action::Changed);
    let v = item(&d, Kind::Field, "m.V");
    assert_eq!(v.action, Action::Changed);
    assert!(
        v.details.iter().any(|x| x == "type: UINT -> INT"),
        "{:?}",
        v.details
    );
    assert!(
        v.details.iter().any(|x| x.contains("a new field")),
        "a changed type ends the old field: {:?}",
        v.details
    );
    assert_eq!(item(&d, Kind::Field, "m.W").action, Action::Added);
    assert!(
        !d.items.iter().any(|i| i.name == "m.A"),
        "an unchanged field is not reported: {:?}",
        d.items
    );
}

#[test]
fn tokens_are_counted_by_role_and_never_named() {
    let a = setup("devices: []\n");
    let d = diff(
        &a,
        &tokens("read aaaaaaaaaaaaaaaaaaaaaaaa\n"),
        &a,
        &tokens("read aaaaaaaaaaaaaaaaaaaaaaaa\nadmin bbbbbbbbbbbbbbbbbbbbbbbb\n"),
    );
    assert!(d.access);
    let text = format!("{:?}", d.items);
    assert!(text.contains("admin"), "{text}");
    assert!(
        !text.contains("bbbbbbbbbbbbbbbbbbbbbbbb"),
        "a token is never reported: {text}"
    );
}

#[test]
fn listeners_and_the_mqtt_section_are_flagged_for_what_applies_them() {
    let mqtt = |id: &str| {
        format!(
            "devices: []\nmqtt:\n  url: mqtt://127.0.0.1:1883\n  client_id: {id}\n  json: {{ prefix: plant }}\n"
        )
    };
    let a = setup(&format!(
        "listen: {{ http: 127.0.0.1:8080 }}\n{}",
        mqtt("one")
    ));
    let b = setup(&format!(
        "listen: {{ http: 127.0.0.1:8081 }}\n{}",
        mqtt("two")
    ));
    let d = compare(&a, &b);
    assert!(d.http_listen && !d.grpc_listen && !d.modbus_listen);
    assert!(d.front_ends.contains(&"mqtt"));
    let m = item(&d, Kind::Section("mqtt"), "mqtt");
    assert_eq!(m.action, Action::Changed);
    assert!(
        m.details.iter().any(|x| x == "client_id: one -> two"),
        "{:?}",
        m.details
    );
    let gone = setup("listen: { http: 127.0.0.1:8081 }\ndevices: []\n");
    let d = compare(&b, &gone);
    assert!(d.front_ends.contains(&"mqtt"));
    assert_eq!(
        item(&d, Kind::Section("mqtt"), "mqtt").action,
        Action::Removed
    );
    assert!(!d.http_listen);
}
