use super::*;

#[tokio::test]
async fn the_overview_lists_every_device_live_and_a_silent_device_turns_disconnected()
-> anyhow::Result<()> {
    let bus = RtuBus::default();
    bus.slave(1, |_| {});
    // A standing read transaction on the same bus (seed 004's parameters).
    let config = format!(
        "{DEVICES}transactions:\n  - {{ name: temp, link: bus, function: 3, slave: 1, address: 0, value_type: SIGNED_NUMBER16, divisor: 10, precision: 1, byte_order: BigEndian, timeout_ms: 100, refresh_interval: 200ms }}\n"
    );
    let (gw, _pty, task, _) = bus_gateway("ui-overview", &bus, &[], &config).await;
    gw.until("/api/v1/devices/rack", "connected", |b| {
        b["connected"] == true
    })
    .await?;
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    browser.goto(&gw.url("/")).await?;
    for device in ["sim", "plant", "rack"] {
        browser
            .wait_for(&format!(
                "tr[data-device='{device}'] a[href='#/devices/{device}']"
            ))
            .await?;
    }
    browser
        .until_text("tr[data-device='rack']", Duration::from_secs(10), |t| {
            t.contains("connected") && !t.contains("disconnected")
        })
        .await?;
    // The link with its utilisation (measured once its first window has passed).
    browser.wait_for("tr[data-link='bus']").await?;
    browser
        .until_text("tr[data-link='bus']", Duration::from_secs(10), |t| {
            t.contains("% measured") && t.contains("% planned")
        })
        .await?;
    // I/O cycles count up live, from the event stream.
    let cycles = |t: &str| -> u64 {
        t.split_whitespace()
            .filter_map(|w| w.parse().ok())
            .next()
            .unwrap_or(0)
    };
    let before = cycles(
        &browser
            .text("tr[data-device='sim'] td[data-label='I/O cycles']")
            .await?,
    );
    browser
        .until_text(
            "tr[data-device='sim'] td[data-label='I/O cycles']",
            Duration::from_secs(5),
            |t| cycles(t) > before,
        )
        .await?;
    // The standing transaction with seed 002's state.
    let tx = browser
        .until_text(
            "tr[data-transaction='temp']",
            Duration::from_secs(10),
            |t| t.contains("4 done"),
        )
        .await?;
    assert!(tx.contains("bus"), "{tx}");

    // A device declared at run time appears without a reload, and goes when removed.
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/extra",
            json!({ "profile": "SimIo" }).to_string(),
        )
        .await?;
    assert_eq!(status, 201);
    browser.wait_for("tr[data-device='extra']").await?;
    let removed = gw
        .client
        .delete(gw.url("/api/v1/devices/extra"))
        .send()
        .await?;
    assert_eq!(removed.status(), 204);
    eventually("the removed device's row goes", || async {
        browser
            .find("tr[data-device='extra']")
            .await
            .ok()
            .flatten()
            .is_none()
    })
    .await?;
    browser
        .screenshot(&screenshots_dir().join("overview-desktop.png"))
        .await?;
    browser.resize(PHONE.0, PHONE.1).await?;
    browser
        .screenshot(&screenshots_dir().join("overview-phone.png"))
        .await?;
    browser.resize(DESKTOP.0, DESKTOP.1).await?;

    // The device stops answering: its row turns disconnected with the code's meaning.
    bus.slave(1, |s| s.behaviour = Behaviour::Silent);
    let row = browser
        .until_text("tr[data-device='rack']", Duration::from_secs(10), |t| {
            t.contains("disconnected")
        })
        .await?;
    assert!(row.contains("error 10"), "{row}");
    assert!(row.contains("Communication error"), "{row}");
    let marked = browser
        .run(
            "return document.querySelector(\"tr[data-device='rack']\").classList.contains('problem');",
            json!([]),
        )
        .await?;
    assert_eq!(marked, json!(true), "the row is marked as a problem");
    assert!(browser.text("#summary").await?.contains("1 not answering"));
    browser
        .until_text(
            "tr[data-transaction='temp']",
            Duration::from_secs(10),
            |t| t.contains("-2 response timeout"),
        )
        .await?;

    // The link's page: its devices and its poll plan, as `iogate plan` prints it.
    let link = browser.wait_for("tr[data-link='bus'] a").await?;
    browser.click(&link).await?;
    let plan = browser
        .until_text("#plan", Duration::from_secs(5), |t| {
            t.contains("device rack")
        })
        .await?;
    assert!(plan.contains("profile MyIoModule"), "{plan}");
    assert!(plan.contains("bus utilisation"), "{plan}");

    // The silent device's page: every field bad, with the reason.
    browser.goto(&gw.url("/ui#/devices/rack")).await?;
    let quality = browser
        .until_text(
            "tr[data-field='DI_0'] td[data-label='Quality']",
            Duration::from_secs(10),
            |t| t.contains("bad"),
        )
        .await?;
    assert!(
        quality.lines().count() > 1,
        "a reason under the quality: {quality}"
    );
    assert!(browser.text("h1").await?.contains("disconnected"));
    assert_eq!(console_errors(&browser).await?, Vec::<String>::new());
    task.abort();
    Ok(())
}

#[tokio::test]
async fn simulated_inputs_toggled_in_the_page_reach_rest_and_rest_writes_show_in_the_page()
-> anyhow::Result<()> {
    let gw = TestGateway::demo().await?;
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    browser.goto(&gw.url("/ui#/devices/sim")).await?;
    let toggle = browser
        .wait_for("tr[data-field='DI_0'] button.toggle")
        .await?;
    value_shows(&browser, "DI_0", "FALSE", Duration::from_secs(5)).await?;
    assert_eq!(rest_value(&gw, "sim", "DI_0").await?, json!(false));

    // Toggling the simulated input in the page changes what REST reads.
    browser.click(&toggle).await?;
    eventually("DI_0 true over REST", || async {
        rest_value(&gw, "sim", "DI_0").await.ok() == Some(json!(true))
    })
    .await?;
    value_shows(&browser, "DI_0", "TRUE", Duration::from_secs(5)).await?;

    // A write made over REST shows in the page within a second, without a reload.
    let marker = browser
        .run("window.__notReloaded = 1; return 1;", json!([]))
        .await?;
    assert_eq!(marker, json!(1));
    let current = rest_value(&gw, "sim", "DO_0").await?;
    let wanted = !current.as_bool().unwrap_or(false);
    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/sim/fields/DO_0",
            json!({ "value": wanted }).to_string(),
        )
        .await?;
    assert_eq!(status, 202);
    let shown = if wanted { "TRUE" } else { "FALSE" };
    value_shows(&browser, "DO_0", shown, Duration::from_secs(1)).await?;
    assert_eq!(
        browser
            .run("return window.__notReloaded === 1;", json!([]))
            .await?,
        json!(true)
    );

    // A write made in the page ends `written`, and REST reads it; with the keyboard alone
    // (the button focused, Enter pressed).
    let write = browser
        .wait_for("tr[data-field='DO_0'] button.toggle")
        .await?;
    browser.type_text(&write, "\u{E007}").await?;
    outcome(&browser, "DO_0", |t| t.starts_with("written")).await?;
    assert_eq!(rest_value(&gw, "sim", "DO_0").await?, json!(!wanted));
    assert_eq!(console_errors(&browser).await?, Vec::<String>::new());
    Ok(())
}

#[tokio::test]
async fn invalid_values_show_the_apis_error_and_numbers_are_written() -> anyhow::Result<()> {
    let gw = TestGateway::demo().await?;
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    browser.goto(&gw.url("/ui#/devices/plant")).await?;

    // Out of range for USINT: the page shows the API's own message.
    let (status, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/plant/fields/Recipe",
            json!({ "value": 300 }).to_string(),
        )
        .await?;
    assert_eq!(status, 400);
    let message = body["error"]["message"].as_str().unwrap_or("").to_owned();
    assert!(!message.is_empty());
    enter(&browser, "Recipe", "300").await?;
    let shown = outcome(&browser, "Recipe", |t| {
        !t.is_empty() && !t.contains("sending")
    })
    .await?;
    assert_eq!(shown, message);

    // Not a number at all: again the API's words.
    let (_, body) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/plant/fields/Recipe",
            json!({ "value": "lots" }).to_string(),
        )
        .await?;
    let message = body["error"]["message"].as_str().unwrap_or("").to_owned();
    enter(&browser, "Recipe", "lots").await?;
    outcome(&browser, "Recipe", |t| t == message).await?;

    // A good value is written, and a TIME as IEC literal too.
    enter(&browser, "Recipe", "7").await?;
    outcome(&browser, "Recipe", |t| t.starts_with("written")).await?;
    assert_eq!(rest_value(&gw, "plant", "Recipe").await?, json!(7));
    enter(&browser, "MixTime", "T#1s500ms").await?;
    outcome(&browser, "MixTime", |t| t.starts_with("written")).await?;
    assert_eq!(rest_value(&gw, "plant", "MixTime").await?, json!(1500));
    value_shows(&browser, "MixTime", "1500 ms", Duration::from_secs(5)).await?;

    // A numeric field's recent values draw a trend: one point per value the stream brought.
    for level in [10.5, 42.0, 17.25] {
        enter(&browser, "Level", &level.to_string()).await?;
        value_shows(
            &browser,
            "Level",
            &level.to_string(),
            Duration::from_secs(5),
        )
        .await?;
    }
    let points = browser
        .run(
            "const p = document.querySelector(\"tr[data-field='Level'] svg.spark polyline\"); return p ? p.getAttribute('points').trim().split(' ').length : 0;",
            json!([]),
        )
        .await?;
    assert!(
        points.as_u64().is_some_and(|n| n >= 4),
        "the first value and three set: {points}"
    );

    browser
        .run(
            "window.scrollTo(0, 0); document.activeElement.blur();",
            json!([]),
        )
        .await?;
    browser
        .screenshot(&screenshots_dir().join("device-desktop.png"))
        .await?;
    browser.resize(PHONE.0, PHONE.1).await?;
    browser
        .screenshot(&screenshots_dir().join("device-phone.png"))
        .await?;
    // On a phone each field is a card with labelled cells, nothing wider than the screen.
    let overflow = browser
        .run(
            "return document.documentElement.scrollWidth > window.innerWidth + 1;",
            json!([]),
        )
        .await?;
    assert_eq!(
        overflow,
        json!(false),
        "the page scrolls sideways on a phone"
    );
    // The refused values' answers (400) are logged by the browser as failed loads; nothing
    // else may be.
    let errors: Vec<String> = console_errors(&browser)
        .await?
        .into_iter()
        .filter(|m| !m.contains("status of 400"))
        .collect();
    assert_eq!(errors, Vec::<String>::new());
    Ok(())
}

#[tokio::test]
async fn the_page_says_when_the_gateway_is_gone_and_reconnects_by_itself() -> anyhow::Result<()> {
    let config = "devices:\n  - { name: sim, profile: SimIo, refresh_rate: 100ms }\n";
    let gw = TestGateway::start(config).await?;
    let addr: std::net::SocketAddr = gw.base.trim_start_matches("http://").parse()?;
    let browser = Browser::start(DESKTOP.0, DESKTOP.1).await?;
    browser.goto(&gw.url("/ui#/devices/sim")).await?;
    browser.wait_for("tr[data-field='DI_0']").await?;
    browser
        .until_text("#connection", Duration::from_secs(5), |t| t == "live")
        .await?;
    gw.shutdown().await;
    browser
        .until_text("#banner", Duration::from_secs(10), |t| {
            t.contains("Connection to the gateway lost")
        })
        .await?;
    assert_eq!(browser.text("#connection").await?, "connection lost");

    // The gateway comes back on the same port with DI_0 set: the page follows by itself.
    let gw = TestGateway::start_on(config, addr).await?;
    gw.send(
        Method::PUT,
        "/api/v1/devices/sim/fields/DI_0/simulate",
        json!({ "value": true }).to_string(),
    )
    .await?;
    browser
        .until_text("#connection", Duration::from_secs(15), |t| t == "live")
        .await?;
    let hidden = browser
        .run(
            "return document.getElementById('banner').hidden;",
            json!([]),
        )
        .await?;
    assert_eq!(hidden, json!(true));
    browser
        .until_text(
            "tr[data-field='DI_0'] td.value",
            Duration::from_secs(5),
            |t| t.contains("TRUE"),
        )
        .await?;
    // Failed fetches while the gateway was away are the network's errors, not the page's.
    let errors: Vec<String> = console_errors(&browser)
        .await?
        .into_iter()
        .filter(|m| !m.contains("net::ERR_CONNECTION_REFUSED") && !m.contains("Failed to fetch"))
        .collect();
    assert_eq!(errors, Vec::<String>::new());
    Ok(())
}

#[tokio::test]
async fn the_page_is_served_with_a_strict_policy_and_without_a_token() -> anyhow::Result<()> {
    let gw = TestGateway::demo().await?;
    let client = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()?;
    let root = client.get(gw.url("/")).send().await?;
    assert!(root.status().is_redirection());
    assert_eq!(root.headers()["location"], "/ui");
    for path in [
        "/ui",
        "/ui/",
        "/ui/app.js",
        "/ui/api.js",
        "/ui/dom.js",
        "/ui/style.css",
        "/ui/icon.svg",
    ] {
        let r = client.get(gw.url(path)).send().await?;
        assert_eq!(r.status(), 200, "{path}");
        let csp = r.headers()["content-security-policy"].to_str()?.to_owned();
        for directive in [
            "default-src 'none'",
            "script-src 'self'",
            "require-trusted-types-for 'script'",
            "frame-ancestors 'none'",
        ] {
            assert!(csp.contains(directive), "{path}: {csp}");
        }
        assert!(!csp.contains("unsafe"), "{path}: {csp}");
        assert_eq!(r.headers()["x-content-type-options"], "nosniff");
    }
    let missing = client.get(gw.url("/ui/missing.js")).send().await?;
    assert_eq!(missing.status(), 404);
    Ok(())
}
