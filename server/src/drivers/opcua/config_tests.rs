use crate::config::Config;

fn problems(yaml: &str) -> String {
    let config: Config = match crate::config::parse("c.yaml", yaml) {
        Ok(c) => c,
        Err(p) => return p.to_string(),
    };
    crate::drivers::check_links(&config).to_string()
}

#[test]
fn an_opcua_link_is_checked_with_each_problem_at_its_line() {
    crate::drivers::register();
    let text = problems(
        "links:\n  - name: plc\n    opcua:\n      url: http://plc:4840\n      security_policy: Basic512\n      speed: fast\n      user: { username: op }\n",
    );
    for expected in [
        "c.yaml:4: link plc: opcua.url: `http://plc:4840` is not an OPC UA endpoint",
        "c.yaml:5: link plc: opcua.security_policy: unknown `Basic512` (expected one of: None, Basic256Sha256, Aes128_Sha256_RsaOaep, Aes256_Sha256_RsaPss)",
        "c.yaml:6: link plc: opcua: unknown key `speed`",
        "c.yaml:7: link plc: opcua.user: a user is `{ username, password_file }` or `{ certificate, private_key }`",
    ] {
        assert!(text.contains(expected), "missing {expected:?} in:\n{text}");
    }
}

#[test]
fn security_needs_a_mode_that_secures_and_files_that_exist() {
    crate::drivers::register();
    let text = problems(
        "links:\n  - name: plc\n    opcua: { url: \"opc.tcp://plc:4840\", security_policy: Basic256Sha256, security_mode: None }\n",
    );
    assert!(
        text.contains("security_policy Basic256Sha256 needs security_mode Sign or SignAndEncrypt"),
        "{text}"
    );
    let text = problems(
        "links:\n  - name: plc\n    opcua: { url: \"opc.tcp://plc:4840\", user: { username: op, password_file: /nonexistent/iogate.pw } }\n",
    );
    assert!(
        text.contains("opcua.user.password_file /nonexistent/iogate.pw"),
        "{text}"
    );
    let text = problems("links:\n  - name: plc\n    opcua: { url: \"opc.tcp://plc:4840/\" }\n");
    assert!(text.is_empty(), "{text}");
}

#[test]
fn a_link_without_its_url_or_with_two_kinds_says_so() {
    crate::drivers::register();
    let text = problems("links:\n  - name: plc\n    opcua: { security_mode: Sign }\n");
    assert!(
        text.contains("link plc: opcua: missing required key `url`"),
        "{text}"
    );
    let text = problems(
        "links:\n  - name: plc\n    tcp: { host: plc }\n    opcua: { url: \"opc.tcp://plc:4840\" }\n",
    );
    assert!(
        text.contains("a link is `serial`, `tcp` or `opcua`, not several"),
        "{text}"
    );
}

#[test]
fn devices_and_links_of_different_protocols_do_not_mix() {
    crate::drivers::register();
    let opcua = crate::profile::load_str(
        "p.yaml",
        "name: Plc\nprotocol: opcua\nfields:\n  - { name: Speed, type: REAL, direction: input, node: \"ns=2;s=Speed\" }\n",
    )
    .expect("profile");
    let modbus = crate::profile::load_str(
        "m.yaml",
        "name: Meter\nfields:\n  - { name: V, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n",
    )
    .expect("profile");
    let config = crate::config::parse(
        "c.yaml",
        "links:\n  - { name: plc, opcua: { url: \"opc.tcp://plc:4840\" } }\n  - { name: bus, tcp: { host: meter } }\ndevices:\n  - { name: a, profile: Plc, link: bus }\n  - { name: b, profile: Meter, link: plc, slave_id: 1 }\n  - { name: c, profile: Plc, link: plc, slave_id: 3 }\n",
    )
    .expect("config");
    let catalog = crate::profile::Catalog::new([opcua, modbus]);
    let text = crate::config::check_devices(&config, &catalog)
        .err()
        .map(|p| p.to_string())
        .unwrap_or_default();
    for expected in [
        "device a: link: profile Plc is opcua, but link bus is a Modbus link",
        "device b: link: profile Meter is modbus-rtu, but link plc is an opcua link",
        "device c: profile Plc is opcua: its devices have no slave_id (remove it)",
    ] {
        assert!(text.contains(expected), "missing {expected:?} in:\n{text}");
    }
}

#[test]
fn a_point_field_names_its_node_and_nothing_modbus() {
    crate::drivers::register();
    let p = |fields: &str| {
        crate::profile::load_str(
            "p.yaml",
            &format!("name: P\nprotocol: opcua\nfields:\n{fields}"),
        )
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default()
    };
    let text = p("  - { name: A, type: INT, direction: input, node: \"ns=2;x=1\" }\n");
    assert!(
        text.contains("p.yaml:4: field A: node: `ns=2;x=1`: unknown identifier kind"),
        "{text}"
    );
    let text =
        p("  - { name: A, type: INT, direction: input, register: { address: 0, kind: coil } }\n");
    assert!(
        text.contains("names its `node`, not a Modbus `register`"),
        "{text}"
    );
    let text = p("  - { name: A, type: INT, direction: input }\n");
    assert!(text.contains("missing `node`"), "{text}");
    let text = p(
        "  - { name: A, type: INT, direction: input, node: \"i=1\" }\n  - { name: B, type: INT, direction: input, node: \"i=1\" }\n",
    );
    assert!(
        text.contains("field B: names the same point as field A (line 4)"),
        "{text}"
    );
    let text = p("  - { name: A, type: INT, direction: input, node: \"i=1\", length: 4 }\n");
    assert!(text.contains("only a STRING field has a length"), "{text}");
}
