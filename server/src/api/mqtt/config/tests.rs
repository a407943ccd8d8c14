use super::*;

fn read_text(text: &str) -> (Option<MqttConfig>, Vec<String>) {
    crate::config::read_section(text, "mqtt", read)
}

#[test]
fn the_documented_section_reads() {
    let (config, problems) = read_text(
        "mqtt:
  url: mqtts://broker.example:8883
  client_id: iogate-line1
  username: gw1
  password_file: /etc/iogate/mqtt-password
  tls: { ca: ca.pem, cert: client.pem, key: client.key }
  sparkplug: { group_id: plant1, edge_node_id: line1, primary_host: scada }
  json: { prefix: iogate/line1, qos: 1, retain: true }
  report: { deadband: 0, min_interval: 100ms, max_interval: 60s }
  buffer: { dir: /var/lib/iogate/mqtt, max_bytes: 256MiB, max_age: 7d, replay_rate: 500/s }
  writes: true
",
    );
    assert_eq!(problems, Vec::<String>::new());
    let c = config.expect("config");
    assert_eq!(c.url.to_string(), "mqtts://broker.example:8883");
    assert_eq!(c.client_id, "iogate-line1");
    assert_eq!(
        c.password,
        Some(Password::File("/etc/iogate/mqtt-password".into()))
    );
    assert_eq!(c.tls.ca, Some("ca.pem".into()));
    let sp = c.sparkplug.expect("sparkplug");
    assert_eq!(
        (sp.group_id.as_str(), sp.edge_node_id.as_str()),
        ("plant1", "line1")
    );
    assert_eq!(sp.primary_host.as_deref(), Some("scada"));
    let json = c.json.expect("json");
    assert_eq!(
        (json.prefix.as_str(), json.qos, json.retain),
        ("iogate/line1", 1, true)
    );
    assert_eq!(c.report.deadband, Deadband::None);
    assert_eq!(c.report.min_interval, Duration::from_millis(100));
    assert_eq!(c.report.max_interval, Duration::from_secs(60));
    assert_eq!(c.buffer.max_bytes, 256 << 20);
    assert_eq!(c.buffer.max_age, Duration::from_secs(7 * 86_400));
    assert_eq!(c.buffer.replay_rate, 500);
    assert!(c.writes);
}

#[test]
fn every_problem_is_named_at_its_line() {
    let (_, problems) = read_text(
        "mqtt:
  url: http://broker
  sparkplug: { group_id: plant/1, edge_node_id: 'line+1' }
  json: { prefix: /iogate, qos: 2 }
  report: { deadband: lots, min_interval: 2s, max_interval: 1s }
  buffer: { max_bytes: 12 parsecs, replay_rate: fast, fsync: sometimes }
  colour: blue
",
    );
    let expect = [
        "2: mqtt.url: `http://broker` is not an MQTT URL",
        "3: mqtt.sparkplug.group_id: `plant/1` must not contain",
        "3: mqtt.sparkplug.edge_node_id: `line+1` must not contain",
        "4: mqtt.json.prefix: `/iogate` must not contain",
        "4: mqtt.json.qos: 2 is outside the allowed range 0-1",
        "5: mqtt.report.deadband: `lots` is not a deadband",
        "5: mqtt.report.max_interval: must not be shorter than min_interval",
        "6: mqtt.buffer.max_bytes: `12 parsecs` is not a size",
        "6: mqtt.buffer.replay_rate: is not a rate",
        "6: mqtt.buffer.fsync: unknown choice `sometimes`",
        "7: mqtt: unknown key `colour`",
    ];
    for e in expect {
        assert!(
            problems.iter().any(|p| p.starts_with(e)),
            "missing {e:?} in {problems:#?}"
        );
    }
}

#[test]
fn a_sparkplug_node_keeps_no_session_and_the_reconnect_cap_is_bounded() {
    let (_, problems) = read_text(
        "mqtt:
  url: mqtt://broker
  client_id: gw
  clean_start: false
  reconnect_max: 2h
  sparkplug: { group_id: plant1, edge_node_id: line1 }
",
    );
    for e in [
        "4: mqtt.clean_start: a Sparkplug B edge node connects with a clean session",
        "5: mqtt.reconnect_max: must be from 500ms to 1h",
    ] {
        assert!(
            problems.iter().any(|p| p.starts_with(e)),
            "missing {e:?} in {problems:#?}"
        );
    }
    let (config, problems) = read_text("mqtt:\n  url: mqtt://broker\n  json: { prefix: a }\n");
    assert_eq!(problems, Vec::<String>::new());
    assert_eq!(config.expect("config").reconnect_max, DEFAULT_RECONNECT_MAX);
}

#[test]
fn urls_parse_with_their_default_ports() {
    let url = |t| BrokerUrl::parse(t).map(|u| (u.tls, u.host, u.port));
    assert_eq!(
        url("mqtt://127.0.0.1"),
        Ok((false, "127.0.0.1".into(), 1883))
    );
    assert_eq!(
        url("mqtts://b.example"),
        Ok((true, "b.example".into(), 8883))
    );
    assert_eq!(url("mqtt://[::1]:1884"), Ok((false, "::1".into(), 1884)));
    assert!(matches!(url("mqtt://h:0"), Err(UrlError::Port(_))));
    assert!(matches!(url("mqtt://u@h"), Err(UrlError::Extra(_))));
    assert!(matches!(url("mqtt://"), Err(UrlError::NoHost(_))));
    assert!(matches!(url("tcp://h"), Err(UrlError::Scheme(_))));
}

#[test]
fn sizes_and_deadbands_read() {
    assert_eq!(parse_size("256MiB"), Some(256 << 20));
    assert_eq!(parse_size("10MB"), Some(10_000_000));
    assert_eq!(parse_size("4096"), Some(4096));
    assert_eq!(parse_size("1 GiB"), Some(1 << 30));
    assert_eq!(parse_size("MiB"), None);
    assert_eq!(parse_size("99999999999999GiB"), None);
    let (c, p) = read_text(
        "mqtt:\n  url: mqtt://h\n  json: { prefix: a/b }\n  report: { deadband: 2.5% }\n",
    );
    assert_eq!(p, Vec::<String>::new());
    assert_eq!(c.expect("config").report.deadband, Deadband::Percent(2.5));
}
