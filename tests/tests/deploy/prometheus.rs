use super::*;

#[tokio::test]
async fn a_real_prometheus_scrapes_the_gateway_and_evaluates_every_alert_rule() {
    tools();
    let (gw, _pty, task, _) = busy_gateway().await;
    let dir = iogate_tests::devices::temp_dir("prometheus");
    let target = gw.base.trim_start_matches("http://").to_owned();
    let config = dir.join("prometheus.yml");
    std::fs::write(
        &config,
        format!(
            "global:\n  scrape_interval: 1s\n  evaluation_interval: 1s\nrule_files:\n  - {}\nscrape_configs:\n  - job_name: iogate\n    static_configs:\n      - targets: [\"{target}\"]\n",
            deploy("prometheus/alerts.yml").display()
        ),
    )
    .expect("config");
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("free port")
        .port();
    struct Kill(std::process::Child);
    impl Drop for Kill {
        fn drop(&mut self) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
    let prometheus = Command::new("prometheus")
        .arg(format!("--config.file={}", config.display()))
        .arg(format!(
            "--storage.tsdb.path={}",
            dir.join("data").display()
        ))
        .arg(format!("--web.listen-address=127.0.0.1:{port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start prometheus");
    let guard = Kill(prometheus);
    let api = format!("http://127.0.0.1:{port}/api/v1");
    let client = reqwest::Client::builder()
        .timeout(Duration::from_secs(5))
        .build()
        .expect("client");
    let get = |path: String| {
        let client = client.clone();
        async move {
            let response = client.get(path).send().await.ok()?;
            response.json::<serde_json::Value>().await.ok()
        }
    };
    // The target is scraped, healthy.
    let patience = Duration::from_secs(60);
    let deadline = tokio::time::Instant::now() + patience;
    loop {
        let targets = get(format!("{api}/targets")).await;
        let up = targets.as_ref().is_some_and(|t| {
            t["data"]["activeTargets"]
                .as_array()
                .is_some_and(|a| a.iter().any(|t| t["health"] == "up"))
        });
        if up {
            break;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "Prometheus never scraped the gateway: {targets:?}"
        );
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    // Every rule evaluated, none with an error.
    loop {
        let rules = get(format!("{api}/rules")).await;
        let all: Vec<serde_json::Value> = rules
            .as_ref()
            .and_then(|r| r["data"]["groups"].as_array())
            .into_iter()
            .flatten()
            .flat_map(|g| g["rules"].as_array().cloned().unwrap_or_default())
            .collect();
        let evaluated = all.len() == 14
            && all.iter().all(|r| {
                r["lastEvaluation"]
                    .as_str()
                    .is_some_and(|t| !t.starts_with("0001"))
            });
        if evaluated {
            for rule in &all {
                assert_eq!(rule["health"], "ok", "{rule}");
            }
            break;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "rules not evaluated: {rules:?}"
        );
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
    // The series the rules read are there.
    let up = get(format!("{api}/query?query=iogate_link_up")).await;
    let result = up
        .as_ref()
        .and_then(|u| u["data"]["result"].as_array().cloned())
        .unwrap_or_default();
    assert_eq!(result.len(), 1, "{up:?}");
    drop(guard);
    gw.shutdown().await;
    task.abort();
}
