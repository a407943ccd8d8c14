//! S7 peers of other makes: a communication processor that splits each answer over two ISO
//! transport (COTP) data frames, the first not marked last (Snap7's answers rewritten so).

use super::*;
use iogate_tests::cable::Cable;
use iogate_tests::s7::S7Plc;

/// Each TPKT frame of `answer` that is a COTP data frame (`F0`) of more than 8 bytes of
/// data, sent as two: the first half not marked last, then the rest marked last.
fn split(answer: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut at = 0;
    while let Some(head) = answer.get(at..at + 4) {
        let len = usize::from(u16::from_be_bytes([head[2], head[3]]));
        let Some(frame) = answer.get(at..at + len) else {
            out.extend_from_slice(&answer[at..]);
            return out;
        };
        at += len;
        let data = frame.get(7..).unwrap_or_default();
        if frame.get(4..7) != Some(&[2, 0xF0, 0x80][..]) || data.len() <= 8 {
            out.extend_from_slice(frame);
            continue;
        }
        let (first, rest) = data.split_at(data.len() / 2);
        for (part, eot) in [(first, 0x00), (rest, 0x80)] {
            let n = (part.len() + 7) as u16;
            out.extend_from_slice(&[3, 0, (n >> 8) as u8, n as u8, 2, 0xF0, eot]);
            out.extend_from_slice(part);
        }
    }
    out.extend_from_slice(answer.get(at..).unwrap_or_default());
    out
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn answers_split_over_two_cotp_frames_are_put_together() -> anyhow::Result<()> {
    let plc = S7Plc::start(None).await?;
    let cable = Cable::rewriting(plc.port, split).await?;
    let gw = gateway("s7-split", cable.port).await?;
    let d = until_device(&gw, "press960", "read", |d| {
        field(d, "In")["quality"] == "good" && field(d, "Long")["quality"] == "good"
    })
    .await?;
    assert_eq!(field(&d, "In")["value"], json!(-300), "{d}");
    let outcome = write(&gw, "press960", "Mw", json!(4321)).await?;
    assert_eq!(outcome["status"], "written", "{outcome}");
    assert_eq!(
        cable.accepted(),
        2,
        "one connection a link, never given up on"
    );
    gw.shutdown().await;
    plc.kill().await
}
