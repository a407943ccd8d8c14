use super::*;

#[test]
fn signed_values_travel_sign_extended_and_come_back() {
    let m = Metric {
        datatype: Some(DataType::Int16 as u32),
        value: Some(metric_value(&Value::Int(-5))),
        ..Metric::default()
    };
    assert_eq!(m.value, Some(MetricValue::IntValue(0xFFFF_FFFB)));
    let bytes = encode(1, Some(3), vec![m]);
    let c = commands(&bytes).expect("test");
    assert_eq!(c[0].value, Some(serde_json::json!(-5)));
    assert_eq!(
        typed_value(IecType::Lint, &Value::Int(-1)),
        MetricValue::LongValue(u64::MAX)
    );
}

#[test]
fn command_topics_name_the_node_or_a_device() {
    let t = Topics::new(&SparkplugConfig {
        group_id: "plant1".into(),
        edge_node_id: "line1".into(),
        primary_host: None,
    });
    assert_eq!(t.command("spBv1.0/plant1/NCMD/line1"), Some(None));
    assert_eq!(
        t.command("spBv1.0/plant1/DCMD/line1/pump"),
        Some(Some("pump"))
    );
    assert_eq!(t.command("spBv1.0/plant1/DCMD/line1/"), None);
    assert_eq!(t.command("spBv1.0/plant1/DCMD/line2/pump"), None);
}

#[test]
fn aliases_are_unique_and_stable() {
    let mut a = Aliases::default();
    let p = a.base("pump", 10);
    let v = a.base("valve", 3);
    assert!(v >= p + 14);
    assert_eq!(a.base("pump", 10), p);
    assert!(p > 3);
}

#[test]
fn a_kept_metric_is_sent_as_if_it_were_encoded_whole() {
    let metric = Metric {
        timestamp: Some(1_700_000_000_000),
        datatype: Some(DataType::Float as u32),
        value: Some(MetricValue::FloatValue(21.5)),
        ..Metric::default()
    };
    let kept = kept_metric(&metric);
    for historical in [false, true] {
        let sent = sendable(&kept).expect("a metric");
        let spliced = data_payload(42, 7, &sent, 12, historical);
        let whole = Metric {
            alias: Some(12),
            is_historical: historical.then_some(true),
            ..metric.clone()
        };
        let expected = Payload {
            timestamp: Some(42),
            metrics: vec![whole],
            seq: Some(7),
            ..Payload::default()
        };
        assert_eq!(
            Payload::decode(spliced.as_slice()).expect("decodes"),
            expected
        );
    }
    // Kept by an earlier version with its name: sent by alias alone.
    let named = Metric {
        name: Some("Level".into()),
        ..metric.clone()
    };
    let old = named.encode_to_vec();
    let sent = sendable(&old).expect("a metric");
    let payload = Payload::decode(data_payload(1, 0, &sent, 3, false).as_slice()).expect("decodes");
    assert_eq!(payload.metrics[0].name, None);
    assert_eq!(payload.metrics[0].alias, Some(3));
    assert!(sendable(&[0x0A, 0xFF]).is_none(), "not a metric");
}

#[test]
fn several_kept_metrics_are_one_payload_each_by_its_alias_in_order() {
    let metrics: Vec<Metric> = (0..3u32)
        .map(|i| Metric {
            timestamp: Some(1_700_000_000_000 + u64::from(i)),
            datatype: Some(DataType::UInt16 as u32),
            value: Some(MetricValue::IntValue(100 + i)),
            ..Metric::default()
        })
        .collect();
    let kept: Vec<Vec<u8>> = metrics.iter().map(kept_metric).collect();
    let refs: Vec<(&[u8], u64)> = kept
        .iter()
        .zip([20u64, 21, 25])
        .map(|(k, a)| (k.as_slice(), a))
        .collect();
    let payload =
        Payload::decode(data_payload_of(42, 9, &refs, false).as_slice()).expect("decodes");
    let expected = Payload {
        timestamp: Some(42),
        metrics: metrics
            .into_iter()
            .zip([20u64, 21, 25])
            .map(|(m, a)| Metric {
                alias: Some(a),
                ..m
            })
            .collect(),
        seq: Some(9),
        ..Payload::default()
    };
    assert_eq!(payload, expected);
}

#[test]
fn a_null_metric_is_a_relinquish_and_a_metric_without_a_value_is_nothing() {
    let null = Metric {
        name: Some("Valve".into()),
        datatype: Some(DataType::Float as u32),
        is_null: Some(true),
        ..Metric::default()
    };
    let empty = Metric {
        name: Some("Fan".into()),
        datatype: Some(DataType::Boolean as u32),
        ..Metric::default()
    };
    let c = commands(&encode(1, Some(3), vec![null, empty])).expect("test");
    assert_eq!(c[0].value, Some(serde_json::Value::Null));
    assert_eq!(c[1].value, None);
}
