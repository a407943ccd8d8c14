//! The web page at `/ui` in a real headless Chromium (WebDriver): the demo's simulated
//! devices and a Modbus RTU device on a pseudo-terminal bus, each through the gateway's real
//! HTTP listener. Screenshots of the overview and a device page, at desktop and phone
//! widths, are written to `target/ui-screenshots/`.

mod overview_and_values;
mod pages;

use std::time::Duration;

use iogate_tests::browser::{Browser, screenshots_dir};
use iogate_tests::devices::{Behaviour, RtuBus};
use iogate_tests::{TestGateway, bus_gateway, eventually};
use reqwest::Method;
use serde_json::json;

const DEVICES: &str = "  - { name: sim, profile: SimIo, refresh_rate: 100ms }\n  - { name: plant, profile: SimPlant, refresh_rate: 250ms }\n  - { name: rack, profile: MyIoModule, link: bus, slave_id: 1, refresh_rate: 50ms, timeout: 100ms, retries: 0 }\n";

const DESKTOP: (u32, u32) = (1280, 900);
const PHONE: (u32, u32) = (390, 844);

/// Console messages at error level (a failed request, an exception, a CSP violation).
async fn console_errors(browser: &Browser) -> anyhow::Result<Vec<String>> {
    Ok(browser
        .console()
        .await?
        .into_iter()
        .filter(|(level, _)| level == "SEVERE")
        .map(|(_, message)| message)
        .collect())
}

/// Types `text` into the field's input in the device page and submits it.
async fn enter(browser: &Browser, field: &str, text: &str) -> anyhow::Result<()> {
    let input = browser
        .wait_for(&format!("tr[data-field='{field}'] input"))
        .await?;
    browser.clear(&input).await?;
    browser.type_text(&input, text).await?;
    let submit = browser
        .wait_for(&format!("tr[data-field='{field}'] button[type='submit']"))
        .await?;
    browser.click(&submit).await
}

/// Waits until the field's outcome (in its row of the device page) satisfies `pred`.
async fn outcome(
    browser: &Browser,
    field: &str,
    pred: impl Fn(&str) -> bool,
) -> anyhow::Result<String> {
    browser
        .until_text(
            &format!("tr[data-field='{field}'] output.outcome"),
            Duration::from_secs(10),
            pred,
        )
        .await
}

/// Waits until the field's value cell shows `shown`, for at most `within`.
async fn value_shows(
    browser: &Browser,
    field: &str,
    shown: &str,
    within: Duration,
) -> anyhow::Result<()> {
    browser
        .until_text(&format!("tr[data-field='{field}'] td.value"), within, |t| {
            t.contains(shown)
        })
        .await
        .map(drop)
}

async fn rest_value(
    gw: &TestGateway,
    device: &str,
    field: &str,
) -> anyhow::Result<serde_json::Value> {
    let (_, body) = gw
        .get(&format!("/api/v1/devices/{device}/fields/{field}"))
        .await?;
    Ok(body["value"].clone())
}
