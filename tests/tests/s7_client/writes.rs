//! Every type written and read back, the PLC's bytes checked where the form matters (a
//! bit's neighbours, a STRING's length byte, a DTL), and writes the PLC cannot hold
//! refused without touching it.

use super::*;
use iogate_tests::s7::S7Plc;
use serde_json::Value;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_type_is_written_and_a_bit_leaves_its_neighbours() -> anyhow::Result<()> {
    let mut plc = S7Plc::start(None).await?;
    let gw = gateway("s7-writes", plc.port).await?;
    until_device(&gw, "press240", "read", |d| {
        field(d, "Ct")["quality"] == "good"
    })
    .await?;
    let values = written();
    for (name, value) in &values {
        let outcome = write(&gw, "press240", name, value.clone()).await?;
        assert_eq!(outcome["status"], "written", "{name}: {outcome}");
    }
    // Read back: two cycles after the last write, every value is the PLC's and the one
    // written; the byte of a bit written has its other bits (Flags), and an output byte
    // written before one of its bits has both (Qb).
    let (_, now) = gw.get("/api/v1/devices/press240").await?;
    let cycles = now["io_cycles"].as_u64().unwrap_or_default();
    until_device(&gw, "press240", "the values written, read back", |d| {
        d["io_cycles"].as_u64().unwrap_or_default() >= cycles + 2
            && values
                .iter()
                .all(|(n, v)| *n == "Qb" || &field(d, n)["value"] == v)
            && field(d, "Flags")["value"] == json!(0b10101110)
            && field(d, "Qb")["value"] == json!(0x4F)
    })
    .await?;
    // The PLC's bytes: the STRING's maximum kept and its length byte set; the DTL with its
    // weekday; the output bit 6 beside the byte written before it.
    assert_eq!(plc.dump("DB 1", 64, 8).await?, "14066c696e652032");
    assert_eq!(plc.dump("DB 2", 8, 12).await?, "07ef02030204050600000007");
    assert_eq!(plc.dump("PA 0", 4, 1).await?, "4f");
    assert_eq!(
        plc.dump("DB 1", 88, 2).await?,
        "007d",
        "12.5 / 0.1 as an INT"
    );
    // What the PLC cannot hold is refused at once (400, never sent), what the PLC refuses
    // is the write's failure; nothing is written.
    for (name, value, says, at_once) in [
        ("Str", json!("x".repeat(21)), "21", true),
        ("Tm", json!(1234), "S5TIME cannot hold 1234 ms", true),
        ("Ct", json!(1000), "0-999", true),
        ("Scaled", json!(4000.0), "40000", true),
        ("Stamp", json!("2100-01-01T00:00:00"), "1990-2089", true),
        ("Missing", json!(1), "object does not exist", false),
    ] {
        let answer = put(&gw, "press240", name, value.clone()).await?;
        assert_eq!(answer.is_err(), at_once, "{name}: {answer:?}");
        let why = refused(&gw, "press240", name, value).await?;
        assert!(why.contains(says), "{name}: {why}");
    }
    assert_eq!(plc.dump("DB 1", 64, 8).await?, "14066c696e652032");
    // A STRING holds characters of one byte: 20 accented ones fit STRING[20], a euro sign
    // (no Latin-1 byte) is refused at once.
    let accented = "é".repeat(20);
    let outcome = put(&gw, "press240", "Str", json!(accented)).await?;
    assert!(
        outcome.as_ref().is_ok_and(|o| o["status"] == "written"),
        "{outcome:?}"
    );
    assert_eq!(plc.dump("DB 1", 64, 4).await?, "1414e9e9");
    let euro = put(&gw, "press240", "Str", json!("5 €")).await?;
    assert!(
        euro.as_ref().is_err_and(|e| e.contains("Latin-1")),
        "{euro:?}"
    );
    gw.shutdown().await;
    plc.kill().await
}

/// What is written, field by field, in this order.
fn written() -> Vec<(&'static str, Value)> {
    vec![
        ("B2", json!(true)),
        ("Si", json!(-7)),
        ("In", json!(1234)),
        ("Di", json!(-100001)),
        ("Li", json!(1i64 << 41)),
        ("Re", json!(-2.5)),
        ("LR", json!(0.125)),
        ("Us", json!(7)),
        ("Ch", json!("Q")),
        ("Ui", json!(65000)),
        ("Ud", json!(123456789)),
        ("Ul", json!(u64::MAX)),
        ("Wd", json!(0x1234)),
        ("Dw", json!(7)),
        ("Lw", json!(9)),
        ("Tdint", json!(2500)),
        ("Wc", json!("é")),
        ("Str", json!("line 2")),
        ("Stamp", json!("2030-01-02T03:04:05.678")),
        ("StampL", json!("2031-02-03T04:05:06.000000007")),
        ("Ws", json!("ÄÖÜ")),
        ("DtlMs", json!(1_000_000_000_000i64)),
        ("M3", json!(false)),
        ("Mw", json!(-1)),
        ("Qb", json!(0x0F)),
        ("Q6", json!(true)),
        ("Tm", json!(9990)),
        ("Ct", json!(42)),
        ("Scaled", json!(12.5)),
        ("Long", json!("z".repeat(230))),
    ]
}
