use super::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rtu_masters_read_and_write_the_map_through_the_serial_slave() {
    run_installer("serial/install.sh").expect("serial peers");
    let (line, _holder, gw, port) = slave_gateway("serial-rtu", ", baud: 19200, parity: E").await;

    let got = python(
        "serial/master.py",
        &[&line.masters_path, "rtu", "7", "19200", "N", "8"],
    )
    .await;
    assert_master_results(&got);
    // The write of coil 0 reached the simulated device's output.
    let (_, field) = gw
        .get("/api/v1/devices/sim/fields/DO_0")
        .await
        .expect("DO_0");
    assert_eq!(field["value"], json!(true), "{field}");

    // libmodbus's mbpoll: reads what pymodbus wrote, writes a register.
    let mbpoll = |args: &[&str]| {
        let mut command = std::process::Command::new("mbpoll");
        command.args([
            "-m", "rtu", "-a", "7", "-b", "19200", "-P", "none", "-0", "-1",
        ]);
        command.args(args).arg(&line.masters_path);
        command
    };
    let out = mbpoll(&["-t", "4", "-r", "1024", "-c", "3"])
        .output()
        .expect("mbpoll");
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}");
    for (address, value) in [(1024, 11), (1025, 22), (1026, 33)] {
        assert!(
            text.lines()
                .any(|l| l.trim_start().starts_with(&format!("[{address}]:"))
                    && l.split_whitespace().last() == Some(&value.to_string())),
            "[{address}] {value} in\n{text}"
        );
    }
    let out = mbpoll(&["-t", "4", "-r", "1031"])
        .arg("4242")
        .output()
        .expect("mbpoll");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    let (_, memory) = gw.get("/api/v1/memory").await.expect("memory");
    assert_eq!(memory["registers"]["%MW7"], json!(4242), "{memory}");
    assert_eq!(memory["registers"]["%MW6"], json!(555), "{memory}");

    // A frame with a bad CRC is ignored; the next good one answered (the test as a third
    // master, on a port opened as a serial port: raw, whatever the last master left).
    let mut raw = tokio_serial::SerialStream::open(&tokio_serial::new(&line.masters_path, 19200))
        .expect("the masters' end");
    let answers_before = way_bytes(&line.seen, Way::Answer).len();
    let good = rtu(&[7, 0x03, 0x04, 0x00, 0x00, 0x01]);
    let mut bad = good.clone();
    bad[6] ^= 0x55;
    bad[7] ^= 0x55;
    raw.write_all(&bad).await.expect("write");
    let mut answer = [0u8; 7];
    assert!(
        tokio::time::timeout(Duration::from_millis(300), raw.read_exact(&mut answer))
            .await
            .is_err(),
        "a frame with a bad CRC was answered"
    );
    raw.write_all(&good).await.expect("write");
    tokio::time::timeout(iogate_tests::PATIENCE, raw.read_exact(&mut answer))
        .await
        .expect("answered in time")
        .expect("read");
    assert_eq!(&answer[..5], &[7, 0x03, 2, 0, 11], "{answer:02x?}");

    // On the line: every answer a whole frame of unit 7 with its CRC, one for each request
    // to unit 7 with a good CRC (none for the broadcast, the other unit, the bad CRC).
    let answers = rtu_answers(&way_bytes(&line.seen, Way::Answer), 7);
    assert_eq!(way_bytes(&line.seen, Way::Answer).len(), answers_before + 7);
    // pymodbus: 12 answered (2 of them exceptions); mbpoll: 2; the raw good frame: 1.
    assert_eq!(answers.len(), 12 + 2 + 1, "{answers:02x?}");
    // Each answer came at least 3.5 characters (2.005 ms at 19200 8E1) after its request.
    let gaps = answer_gaps(&line.seen, |_| true);
    assert_eq!(gaps.len(), answers.len(), "{gaps:?}");
    for gap in gaps {
        assert!(gap >= Duration::from_micros(2000), "answered after {gap:?}");
    }

    let state = serial_state(&gw).await;
    assert_eq!(state["framing"], "rtu", "{state}");
    assert_eq!(state["line"], "19200 8E1", "{state}");
    assert_eq!(state["frames"]["answered"], json!(13), "{state}");
    assert_eq!(state["frames"]["exception"], json!(2), "{state}");
    assert_eq!(state["frames"]["broadcast"], json!(1), "{state}");
    assert_eq!(state["frames"]["other_unit"], json!(1), "{state}");
    assert_eq!(state["frames"]["crc_error"], json!(1), "{state}");
    let metrics = gw.metrics().await.expect("metrics");
    for (outcome, n) in [("answered", 13), ("crc_error", 1), ("broadcast", 1)] {
        let line = format!(
            "iogate_modbus_serial_frames_total{{port=\"{}\",outcome=\"{outcome}\"}} {n}",
            port.display()
        );
        assert!(metrics.contains(&line), "{line} in\n{metrics}");
    }
    assert!(metrics.contains(&format!(
        "iogate_modbus_serial_port_up{{port=\"{}\"}} 1",
        port.display()
    )));
    gw.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_ascii_master_reads_and_writes_the_map_through_the_serial_slave() {
    run_installer("serial/install.sh").expect("serial peers");
    let (line, _holder, gw, _) = slave_gateway(
        "serial-ascii-server",
        ", baud: 9600, parity: E, data_bits: 7, framing: ascii, turnaround_delay: 30ms",
    )
    .await;
    let got = python(
        "serial/master.py",
        &[&line.masters_path, "ascii", "7", "9600", "N", "8"],
    )
    .await;
    assert_master_results(&got);
    // On the line: answers are ASCII frames from unit 7 with their LRC, one for each
    // request to unit 7.
    let answers = ascii_frames(&way_bytes(&line.seen, Way::Answer));
    assert_eq!(answers.len(), 12, "{answers:02x?}");
    assert!(answers.iter().all(|a| a[0] == 7), "{answers:02x?}");
    let requests = ascii_frames(&way_bytes(&line.seen, Way::Request));
    assert_eq!(requests.len(), 14, "{requests:02x?}");
    // Each answer waited the turnaround delay after its request's LF.
    let gaps = answer_gaps(&line.seen, |bytes| bytes.ends_with(b"\n"));
    assert_eq!(gaps.len(), answers.len(), "{gaps:?}");
    for gap in gaps {
        assert!(gap >= Duration::from_millis(30), "answered after {gap:?}");
    }
    let state = serial_state(&gw).await;
    assert_eq!(state["framing"], "ascii", "{state}");
    assert_eq!(state["line"], "9600 7E1", "{state}");
    gw.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_ascii_link_polls_an_independent_ascii_slave() {
    run_installer("serial/install.sh").expect("serial peers");
    let dir = temp_dir("serial-ascii-link");
    let (line, _holder) = line(&dir, "ttyLINK");
    // The slave (pymodbus) on the masters' end of the sniffed line; the gateway, the
    // master here, on the other.
    let mut slave = tokio::process::Command::new(iogate_tests::python())
        .arg(repo_file("serial/slave.py"))
        .args([&line.masters_path, "ascii", "5", "9600", "N", "8"])
        .kill_on_drop(true)
        .stdout(std::process::Stdio::null())
        .spawn()
        .expect("slave");
    let profiles = dir.join("profiles");
    std::fs::create_dir_all(&profiles).expect("dir");
    std::fs::write(
        profiles.join("ascii_meter.yaml"),
        "name: AsciiMeter\nprotocol: modbus-rtu\nfields:\n  \
         - { name: R0, type: UINT, direction: input, register: { address: 0, kind: holding_register } }\n  \
         - { name: R1, type: UINT, direction: input, register: { address: 1, kind: holding_register } }\n  \
         - { name: SET5, type: UINT, direction: output, register: { address: 5, kind: holding_register } }\n",
    )
    .expect("profile");
    let gw = TestGateway::start(&format!(
        "profiles: {}\nlinks:\n  - {{ name: ascii, serial: {{ port: {}, baud: 9600, parity: E, data_bits: 7, framing: ascii }} }}\n\
         devices:\n  - {{ name: meter, profile: AsciiMeter, link: ascii, slave_id: 5, refresh_rate: 100ms, timeout: 500ms }}\n",
        profiles.display(),
        dir.join("ttyLINK").display()
    ))
    .await
    .expect("gateway");
    eventually("the meter read", || async {
        let (_, device) = gw.get("/api/v1/devices/meter").await.expect("meter");
        device["connected"] == json!(true)
    })
    .await
    .unwrap_or_else(|e| {
        panic!(
            "{e}: on the line {:?}",
            line.seen
                .lock()
                .expect("sniffer")
                .iter()
                .map(|(w, b, _)| (*w, String::from_utf8_lossy(b).into_owned()))
                .collect::<Vec<_>>()
        )
    });
    let (_, r0) = gw.get("/api/v1/devices/meter/fields/R0").await.expect("R0");
    let (_, r1) = gw.get("/api/v1/devices/meter/fields/R1").await.expect("R1");
    assert_eq!(
        (r0["value"].clone(), r1["value"].clone()),
        (json!(1000), json!(1001))
    );
    let (status, accepted) = gw
        .send(
            reqwest::Method::PUT,
            "/api/v1/devices/meter/fields/SET5",
            json!({"value": 77}).to_string(),
        )
        .await
        .expect("write");
    assert_eq!(status, 202, "{accepted}");
    let generation = accepted["generation"].clone();
    gw.until(
        &format!("/api/v1/writes/{generation}"),
        "the write confirmed by the slave",
        |w| w["status"] == "written",
    )
    .await
    .expect("written");
    // On the line: the gateway's requests are ASCII frames to unit 5 with their LRC; the
    // slave's answers too.
    let requests = ascii_frames(&way_bytes(&line.seen, Way::Answer));
    assert!(requests.len() >= 3, "{requests:02x?}");
    assert!(requests.iter().all(|r| r[0] == 5), "{requests:02x?}");
    // The write: register 5 = 77, by FC06 or FC16, echoed by the slave.
    let write = |f: &Vec<u8>| {
        f.get(1..4) == Some(&[0x06, 0, 5][..]) && f.get(4..6) == Some(&[0, 77][..])
            || f.get(1..6) == Some(&[0x10, 0, 5, 0, 1][..]) && f.get(7..9) == Some(&[0, 77][..])
    };
    assert!(requests.iter().any(write), "the write: {requests:02x?}");
    let answers = ascii_frames(&way_bytes(&line.seen, Way::Request));
    assert!(answers.iter().all(|a| a[0] == 5), "{answers:02x?}");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        !metrics.contains("iogate_device_crc_errors_total{device=\"meter\"} 1"),
        "{metrics}"
    );
    let _ = slave.kill().await;
    gw.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_frame_ends_at_a_silence_and_a_lost_port_is_reopened() {
    let dir = temp_dir("serial-reopen");
    let path = dir.join("ttyGW");
    let (mut master, holder) = pty_at(&path).expect("pty");
    let gw = TestGateway::start(&gateway_config(&path, ", baud: 19200"))
        .await
        .expect("gateway");
    eventually("the port open", || async {
        serial_state(&gw).await["state"] == "open"
    })
    .await
    .expect("open");
    drop(holder);
    let read = rtu(&[7, 0x03, 0x04, 0x00, 0x00, 0x01]);
    let mut answer = [0u8; 7];
    // A request cut by 20 ms of silence (3.5 characters at 19200 baud are 1.8 ms) is two
    // frames, neither with a good CRC: no answer.
    master.write_all(&read[..4]).await.expect("write");
    tokio::time::sleep(Duration::from_millis(20)).await;
    master.write_all(&read[4..]).await.expect("write");
    assert!(
        tokio::time::timeout(Duration::from_millis(300), master.read_exact(&mut answer))
            .await
            .is_err(),
        "a frame cut by a silence was answered"
    );
    let state = serial_state(&gw).await;
    assert_eq!(state["frames"]["crc_error"], json!(2), "{state}");
    // Whole, it is answered.
    master.write_all(&read).await.expect("write");
    tokio::time::timeout(iogate_tests::PATIENCE, master.read_exact(&mut answer))
        .await
        .expect("answered")
        .expect("read");
    assert_eq!(&answer[..3], &[7, 0x03, 2]);

    // Unplugged: the port is lost; plugged in again at the same path: reopened.
    drop(master);
    gw.until("/api/v1/map", "the port lost", |m| {
        m["serial"][0]["state"] == "lost"
    })
    .await
    .expect("lost");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains(&format!(
            "iogate_modbus_serial_port_up{{port=\"{}\"}} 0",
            path.display()
        )),
        "{metrics}"
    );
    let (mut master, _holder) = pty_at(&path).expect("pty");
    let state = gw
        .until("/api/v1/map", "the port reopened", |m| {
            m["serial"][0]["state"] == "open"
        })
        .await
        .expect("reopened");
    assert_eq!(state["serial"][0]["reopens"], json!(1), "{state}");
    master.write_all(&read).await.expect("write");
    tokio::time::timeout(iogate_tests::PATIENCE, master.read_exact(&mut answer))
        .await
        .expect("answered after the reopening")
        .expect("read");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains(&format!(
            "iogate_modbus_serial_port_reopens_total{{port=\"{}\"}} 1",
            path.display()
        )),
        "{metrics}"
    );
    gw.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn noise_on_the_line_is_never_answered_and_the_ports_keep_serving() {
    let dir = temp_dir("serial-noise");
    let (mut rtu_end, _rtu_holder) = pty_at(&dir.join("ttyRTU")).expect("pty");
    let (mut ascii, _ascii_holder) = pty_at(&dir.join("ttyASCII")).expect("pty");
    let gw = TestGateway::start(&format!(
        "devices:\n  - {{ name: sim, profile: SimIo, refresh_rate: 100ms }}\n\
         modbus_server:\n  serial:\n    - {{ port: {}, baud: 115200, unit_id: 7 }}\n    \
         - {{ port: {}, baud: 115200, unit_id: 7, framing: ascii }}\n",
        dir.join("ttyRTU").display(),
        dir.join("ttyASCII").display()
    ))
    .await
    .expect("gateway");
    gw.until("/api/v1/map", "both ports open", |m| {
        m["serial"]
            .as_array()
            .is_some_and(|s| s.len() == 2 && s.iter().all(|p| p["state"] == "open"))
    })
    .await
    .expect("open");
    // 40 bursts of noise on each line, each followed by more than a frame's silence
    // (3.5 characters at 115200 baud are 1.75 ms), some with `:` and CR LF in them.
    for k in 0..40u64 {
        let mut burst = noise(k + 1, 1 + (k as usize * 37) % 300);
        rtu_end.write_all(&burst).await.expect("write");
        if k % 3 == 0 {
            burst.insert(0, b':');
            burst.extend_from_slice(b"\r\n");
        }
        ascii.write_all(&burst).await.expect("write");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    // Nothing was answered.
    let mut byte = [0u8; 1];
    for end in [&mut rtu_end, &mut ascii] {
        assert!(
            tokio::time::timeout(Duration::from_millis(200), end.read(&mut byte))
                .await
                .is_err(),
            "noise was answered"
        );
    }
    // Both ports still answer a good request.
    let read = rtu(&[7, 0x03, 0x04, 0x00, 0x00, 0x01]);
    rtu_end.write_all(&read).await.expect("write");
    let mut answer = [0u8; 7];
    tokio::time::timeout(iogate_tests::PATIENCE, rtu_end.read_exact(&mut answer))
        .await
        .expect("RTU answered")
        .expect("read");
    assert_eq!(&answer[..3], &[7, 0x03, 2]);
    // An unfinished ASCII frame (the noise's last `:`) is dropped at the next `:`.
    ascii
        .write_all(b":070304000001F1\r\n")
        .await
        .expect("write");
    let mut line = Vec::new();
    while !line.ends_with(b"\r\n") {
        tokio::time::timeout(iogate_tests::PATIENCE, ascii.read_exact(&mut byte))
            .await
            .expect("ASCII answered")
            .expect("read");
        line.push(byte[0]);
    }
    assert!(
        line.starts_with(b":070302"),
        "{}",
        String::from_utf8_lossy(&line)
    );
    let (_, map) = gw.get("/api/v1/map").await.expect("map");
    for port in map["serial"].as_array().expect("ports") {
        let f = &port["frames"];
        assert_eq!(f["answered"], json!(1), "{port}");
        let ignored = ["crc_error", "malformed", "other_unit"]
            .iter()
            .map(|k| f[*k].as_u64().unwrap_or(0))
            .sum::<u64>();
        assert!(ignored >= 10, "{port}");
    }
    gw.shutdown().await;
}
