//! The MQTT codec against the standard's bytes, and what a broker may send it.

use super::*;

#[test]
fn an_mqtt_5_connect_announces_the_maximum_packet_size() {
    let bytes = connect(
        MqttVersion::V5,
        &Connect {
            client_id: "gw".into(),
            keep_alive: 30,
            clean_start: true,
            username: None,
            password: None,
            will: None,
        },
    );
    // Header, "MQTT", level 5, flags, keep-alive, then 5 bytes of properties.
    assert_eq!(
        &bytes[2..12],
        [0, 4, b'M', b'Q', b'T', b'T', 5, 0x02, 0, 30]
    );
    assert_eq!(&bytes[12..18], [5, 0x27, 0, 0x10, 0, 0]);
}

#[test]
fn a_3_1_1_connect_is_the_standards_bytes() {
    let bytes = connect(
        MqttVersion::V311,
        &Connect {
            client_id: "gw".into(),
            keep_alive: 30,
            clean_start: true,
            username: Some("u".into()),
            password: Some(b"p".to_vec()),
            will: Some(Will {
                topic: "t".into(),
                payload: b"x".to_vec(),
                qos: 1,
                retain: true,
            }),
        },
    );
    assert_eq!(
        bytes,
        [
            0x10, 26, 0, 4, b'M', b'Q', b'T', b'T', 4, 0xEE, 0, 30, 0, 2, b'g', b'w', 0, 1, b't',
            0, 1, b'x', 0, 1, b'u', 0, 1, b'p'
        ]
    );
}

#[test]
fn publishes_round_trip_in_both_versions() {
    for version in [MqttVersion::V311, MqttVersion::V5] {
        let p = Publish {
            topic: "a/b".into(),
            payload: vec![7; 300],
            qos: 1,
            retain: true,
            pkid: 513,
        };
        let mut bytes = publish(version, &p);
        // A partial packet is not taken.
        let mut half = bytes[..10].to_vec();
        assert_eq!(decode(version, &mut half), Ok(None));
        bytes.extend_from_slice(&pingreq()[..1]);
        assert_eq!(
            decode(version, &mut bytes),
            Ok(Some(Incoming::Publish(p.clone())))
        );
        assert_eq!(bytes, [0xC0], "the next packet's first byte stays");
    }
}

#[test]
fn acks_and_their_codes_decode() {
    let mut b = vec![0x20, 2, 0, 0, 0x40, 2, 1, 2, 0x90, 3, 0, 9, 1, 0xD0, 0];
    let v = MqttVersion::V311;
    assert_eq!(
        decode(v, &mut b),
        Ok(Some(Incoming::ConnAck {
            session_present: false,
            code: 0,
            receive_maximum: None,
            maximum_packet: None,
        }))
    );
    assert_eq!(
        decode(v, &mut b),
        Ok(Some(Incoming::PubAck { pkid: 258, code: 0 }))
    );
    assert_eq!(
        decode(v, &mut b),
        Ok(Some(Incoming::SubAck {
            pkid: 9,
            codes: vec![1]
        }))
    );
    assert_eq!(decode(v, &mut b), Ok(Some(Incoming::PingResp)));
    // MQTT 5: a SUBACK has properties before its codes.
    let mut b = vec![0x90, 7, 0, 9, 3, 0x1F, 0, 0, 0x80];
    assert_eq!(
        decode(MqttVersion::V5, &mut b),
        Ok(Some(Incoming::SubAck {
            pkid: 9,
            codes: vec![0x80]
        }))
    );
}

fn dropped(why: PacketError, topic: Option<&str>, pkid: Option<u16>, rest: usize) -> Incoming {
    Incoming::Dropped {
        why,
        topic: topic.map(str::to_owned),
        pkid,
        rest,
    }
}

#[test]
fn bad_packets_are_read_past_and_only_lost_framing_is_an_error() {
    let v = MqttVersion::V5;
    assert_eq!(
        decode(v, &mut vec![0x30, 0xFF, 0xFF, 0xFF, 0xFF, 1]),
        Err(PacketError::Length)
    );
    let mut b = vec![0x30, 3, 0, 9, b'a', 0xD0, 0];
    assert_eq!(
        decode(v, &mut b),
        Ok(Some(dropped(
            PacketError::Malformed("PUBLISH"),
            None,
            None,
            0
        )))
    );
    assert_eq!(
        decode(v, &mut b),
        Ok(Some(Incoming::PingResp)),
        "the next packet is read"
    );
    assert_eq!(
        decode(v, &mut vec![0x10, 0]),
        Ok(Some(dropped(PacketError::Unexpected(1), None, None, 0)))
    );
    // A QoS 1 publish with a topic that is not UTF-8: dropped, its id kept to acknowledge.
    assert_eq!(
        decode(
            MqttVersion::V311,
            &mut vec![0x32, 6, 0, 2, 0xFF, b'a', 1, 2]
        ),
        Ok(Some(dropped(
            PacketError::Topic,
            Some("\u{fffd}a"),
            Some(258),
            0
        )))
    );
}

#[test]
fn a_publish_too_big_to_keep_is_dropped_with_its_topic_and_id_and_the_rest_read_past() {
    let v = MqttVersion::V311;
    let big = Publish {
        topic: "spBv1.0/g/NCMD/n".into(),
        payload: vec![0; MAX_INCOMING + 10],
        qos: 1,
        retain: true,
        pkid: 7,
    };
    let bytes = publish(v, &big);
    let total = bytes.len();
    // The head alone is not enough to say more than "wait".
    let mut head = bytes[..5].to_vec();
    assert_eq!(decode(v, &mut head), Ok(None));
    let mut some = bytes[..4096].to_vec();
    assert_eq!(
        decode(v, &mut some),
        Ok(Some(dropped(
            PacketError::TooBig(total - 4),
            Some("spBv1.0/g/NCMD/n"),
            Some(7),
            total - 4096
        )))
    );
    assert!(some.is_empty(), "nothing of it is kept");
}

proptest::proptest! {
    #[test]
    fn no_bytes_make_the_decoder_panic(bytes in proptest::collection::vec(0u8..=255, 0..64)) {
        for version in [MqttVersion::V311, MqttVersion::V5] {
            let mut b = bytes.clone();
            while let Ok(Some(_)) = decode(version, &mut b) {}
        }
    }
}

#[test]
fn an_mqtt_5_connack_gives_the_brokers_receive_maximum_and_maximum_packet_size() {
    let v = MqttVersion::V5;
    // Properties: Assigned Client Identifier "ab", Topic Alias Maximum 10, Receive Maximum 20.
    let props = [0x12, 0, 2, b'a', b'b', 0x22, 0, 10, 0x21, 0, 20];
    let mut b = vec![0x20, 3 + props.len() as u8, 0, 0, props.len() as u8];
    b.extend_from_slice(&props);
    assert_eq!(
        decode(v, &mut b),
        Ok(Some(Incoming::ConnAck {
            session_present: false,
            code: 0,
            receive_maximum: Some(20),
            maximum_packet: None,
        }))
    );
    // Receive Maximum 5, Maximum Packet Size 2,048.
    let props = [0x21, 0, 5, 0x27, 0, 0, 8, 0];
    let mut b = vec![0x20, 3 + props.len() as u8, 0, 0, props.len() as u8];
    b.extend_from_slice(&props);
    assert_eq!(
        decode(v, &mut b),
        Ok(Some(Incoming::ConnAck {
            session_present: false,
            code: 0,
            receive_maximum: Some(5),
            maximum_packet: Some(2048),
        }))
    );
    // Zero is a protocol error: no maximum taken from it.
    let mut b = vec![0x20, 6, 1, 0, 3, 0x21, 0, 0];
    assert_eq!(
        decode(v, &mut b),
        Ok(Some(Incoming::ConnAck {
            session_present: true,
            code: 0,
            receive_maximum: None,
            maximum_packet: None,
        }))
    );
    // A string property running past the block, and an unknown property: malformed.
    for props in [vec![0x1F, 0, 9, b'x'], vec![0x7F, 1]] {
        let mut b = vec![0x20, 3 + props.len() as u8, 0, 0, props.len() as u8];
        b.extend_from_slice(&props);
        assert!(matches!(
            decode(v, &mut b),
            Ok(Some(Incoming::Dropped { .. }))
        ));
    }
}
