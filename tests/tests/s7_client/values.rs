//! Every type and area read, at a PDU of 240 and of 960, with
//! the PLC's identity in the link's state and the jobs in its plan.

use super::*;
use iogate_tests::s7::S7Plc;
use serde_json::Value;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_type_and_area_is_read_at_both_pdu_sizes() -> anyhow::Result<()> {
    let plc = S7Plc::start(None).await?;
    let gw = gateway("s7-values", plc.port).await?;
    for device in ["press240", "press960"] {
        // Edge's range, merged with Over's past the end of DB1, is read alone once the PLC
        // said the merged one is out of range.
        let d = until_device(&gw, device, "read", |d| {
            field(d, "Ct")["quality"] == "good"
                && field(d, "Ws")["quality"] == "good"
                && field(d, "Edge")["quality"] == "good"
        })
        .await?;
        let v = |n: &str| field(&d, n)["value"].clone();
        for (name, want) in expected() {
            assert_eq!(v(name), want, "{device} {name}: {}", field(&d, name));
            assert_eq!(field(&d, name)["quality"], "good", "{device} {name}");
        }
        // Item errors are their fields', naming what to change; the others stay good.
        let missing = field(&d, "Missing");
        assert_eq!(missing["quality"], "bad", "{missing}");
        let why = missing["error"].as_str().unwrap_or_default();
        assert!(why.contains("object does not exist"), "{why}");
        let over = field(&d, "Over")["error"].as_str().unwrap_or_default();
        assert!(over.contains("address out of range"), "{over}");
        let past = field(&d, "Past")["error"].as_str().unwrap_or_default();
        assert!(
            past.contains("address out of range") && past.contains("Optimized block access"),
            "{past}"
        );
    }
    // The PLC's identity and the PDU size it granted, in the link's state.
    let (_, link) = gw.get("/api/v1/links/plc240").await?;
    assert_eq!(link["peer"]["pdu_size"], "240", "{link}");
    assert_eq!(
        link["peer"]["order_number"], "6ES7 315-2EH14-0AB0",
        "{link}"
    );
    assert_eq!(link["peer"]["module"], "CPU 315-2 PN/DP", "{link}");
    assert_eq!(link["peer"]["cpu_state"], "run", "{link}");
    let (_, link) = gw.get("/api/v1/links/plc960").await?;
    assert_eq!(link["peer"]["pdu_size"], "960", "{link}");
    // The plan: more jobs at 240 bytes than at 960.
    let jobs = |plan: &str| plan.matches("    job ").count();
    let text = |link: &str| reqwest::get(gw.url(&format!("/api/v1/links/{link}/plan")));
    let small = text("plc240").await?.text().await?;
    let large = text("plc960").await?.text().await?;
    assert!(small.contains("PDU of 240 bytes (granted)"), "{small}");
    assert!(large.contains("PDU of 960 bytes (granted)"), "{large}");
    assert!(
        jobs(&small) > jobs(&large) && jobs(&large) >= 1,
        "{small}\n{large}"
    );
    // STRING[254] (256 bytes) is more than one item of 240 carries: read in two pieces.
    assert!(
        small.contains("DB3 bytes 0-217: Long (part 1 of 2)"),
        "{small}"
    );
    assert!(
        small.contains("DB3 bytes 218-255: Long (part 2 of 2)"),
        "{small}"
    );
    gw.shutdown().await;
    plc.kill().await
}

/// Each field's value as `tests/s7/plc.py` holds it.
fn expected() -> Vec<(&'static str, Value)> {
    vec![
        ("Flags", json!(0b10101010)),
        ("B1", json!(true)),
        ("B2", json!(false)),
        ("Si", json!(-5)),
        ("In", json!(-300)),
        ("Di", json!(100000)),
        ("Li", json!(-(1i64 << 40))),
        ("Re", json!(1.5)),
        ("LR", json!(2.25)),
        ("Us", json!(200)),
        ("Ch", json!("Z")),
        ("Ui", json!(60000)),
        ("Ud", json!(4000000000u64)),
        ("Ul", json!((1u64 << 63) + 5)),
        ("Wd", json!(0xBEEF)),
        ("Dw", json!(0xDEADBEEFu32)),
        ("Lw", json!(0x0123456789ABCDEFu64)),
        ("Tdint", json!(-1500)),
        ("Wc", json!("Ω")),
        ("Str", json!("press")),
        ("Stamp", json!("2026-11-26T16:50:45.123")),
        ("StampL", json!("2026-11-26T16:50:45.123456789")),
        ("Ws", json!("Grüße")),
        ("DtlMs", json!(1_795_711_845_123i64)),
        ("M3", json!(true)),
        ("Mw", json!(1234)),
        ("I7", json!(true)),
        ("Iw", json!(0x1234)),
        ("Qb", json!(0x5A)),
        ("Q6", json!(true)),
        ("Tm", json!(2500)),
        ("Ct", json!(123)),
        ("Tail", json!("tail")),
        ("Scaled", json!(25.0)),
        (
            "Long",
            json!(
                (0..200)
                    .map(|i| char::from(b'a' + i % 26))
                    .collect::<String>()
            ),
        ),
        ("Edge", json!(258)),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_real_that_json_has_no_number_for_is_said_as_a_string() -> anyhow::Result<()> {
    let mut plc = S7Plc::start(None).await?;
    let gw = gateway("s7-not-finite", plc.port).await?;
    for (bits, said) in [
        ("7fc00000", "NaN"),
        ("7f800000", "Infinity"),
        ("ff800000", "-Infinity"),
    ] {
        assert_eq!(plc.cmd(&format!("set DB 1 16 {bits}")).await?, "ok");
        let d = until_device(&gw, "press960", said, |d| field(d, "Re")["value"] == said).await?;
        assert_eq!(field(&d, "Re")["quality"], "good", "{d}");
        let (_, one) = gw.get("/api/v1/devices/press960/fields/Re").await?;
        assert_eq!(one["value"], said, "{one}");
    }
    gw.shutdown().await;
    plc.kill().await
}
