use super::*;

#[test]
fn alert_rules_and_the_compose_prometheus_config_pass_promtool() {
    tools();
    let rules = run(
        "promtool",
        &["check", "rules", "deploy/prometheus/alerts.yml"],
    );
    assert!(rules.contains("SUCCESS: 14 rules found"), "{rules}");
    run(
        "promtool",
        &["check", "config", "deploy/compose/prometheus.yml"],
    );
}

#[test]
fn kubernetes_manifests_validate_against_the_kubernetes_schemas() {
    tools();
    run(
        &iogate_tests::python().to_string_lossy(),
        &[
            "-m",
            "kubernetes_validate",
            "--strict",
            "--quiet",
            "deploy/kubernetes/configmap.yaml",
            "deploy/kubernetes/deployment.yaml",
            "deploy/kubernetes/service.yaml",
        ],
    );
    let kustomization =
        std::fs::read_to_string(deploy("kubernetes/kustomization.yaml")).expect("kustomization");
    for file in ["configmap.yaml", "deployment.yaml", "service.yaml"] {
        assert!(kustomization.contains(file), "{file} not in kustomization");
    }
    let deployment =
        std::fs::read_to_string(deploy("kubernetes/deployment.yaml")).expect("deployment");
    for needed in [
        "replicas: 1",
        "type: Recreate",
        "/livez",
        "/readyz",
        "runAsNonRoot: true",
    ] {
        assert!(deployment.contains(needed), "deployment lacks {needed}");
    }
}

#[test]
fn the_systemd_unit_verifies_where_systemd_analyze_exists() {
    let Ok(probe) = Command::new("systemd-analyze").arg("--version").output() else {
        eprintln!("systemd-analyze is not installed here; unit not verified");
        return;
    };
    assert!(probe.status.success());
    let unit = std::fs::read_to_string(deploy("systemd/iogate.service")).expect("unit");
    for needed in [
        "ExecStartPre=/usr/local/bin/iogate check",
        "Restart=on-failure",
        "NoNewPrivileges=yes",
        "ProtectSystem=strict",
        "PrivateTmp=yes",
        "SupplementaryGroups=dialout",
        "DeviceAllow=char-ttyUSB rw",
    ] {
        assert!(unit.contains(needed), "unit lacks {needed}");
    }
    // Verified with the binary this build made standing in for /usr/local/bin/iogate.
    let binary = repo().join("target/debug/iogate");
    let binary = if binary.exists() {
        binary
    } else {
        PathBuf::from("/bin/true")
    };
    let dir = iogate_tests::devices::temp_dir("systemd");
    let path = dir.join("iogate.service");
    std::fs::write(
        &path,
        unit.replace("/usr/local/bin/iogate", &binary.display().to_string()),
    )
    .expect("write");
    let out = Command::new("systemd-analyze")
        .arg("verify")
        .arg(&path)
        .output()
        .expect("systemd-analyze");
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    // Lines about this unit only; the host's own units may have their own complaints.
    let ours: Vec<&str> = text
        .lines()
        .filter(|l| l.contains("iogate.service"))
        .collect();
    assert!(ours.is_empty(), "{text}");
}

#[test]
fn compose_parses_and_every_file_it_mounts_exists() {
    let compose_dir = deploy("compose");
    let text = std::fs::read_to_string(compose_dir.join("docker-compose.yml")).expect("compose");
    let doc: serde_json::Value = serde_saphyr::from_str(&text).expect("compose parses");
    let services = doc["services"].as_object().expect("services");
    for name in ["iogate", "prometheus", "grafana", "mosquitto"] {
        assert!(services.contains_key(name), "no service {name}");
    }
    // Named volumes (the MQTT buffer) are the compose file's own; every other source is a
    // file beside it.
    let named = doc["volumes"].as_object().cloned().unwrap_or_default();
    assert!(named.contains_key("mqtt-buffer"));
    let mut mounts = 0;
    for (name, service) in services {
        for volume in service["volumes"].as_array().into_iter().flatten() {
            let source = volume
                .as_str()
                .and_then(|v| v.split(':').next())
                .expect("short volume syntax");
            if named.contains_key(source) {
                continue;
            }
            let path = compose_dir.join(source);
            assert!(
                path.exists(),
                "{name} mounts {source}, which does not exist"
            );
            mounts += 1;
        }
    }
    assert!(mounts >= 5);
    let build = &services["iogate"]["build"];
    let dockerfile = compose_dir
        .join(build["context"].as_str().expect("context"))
        .join(build["dockerfile"].as_str().expect("dockerfile"));
    assert!(dockerfile.exists());
    // The Dockerfile's promises.
    let docker = std::fs::read_to_string(dockerfile).expect("Dockerfile");
    for needed in [
        "cargo build --release --locked",
        "USER iogate",
        "--gid dialout",
        "HEALTHCHECK",
        "/readyz",
        "EXPOSE 8080 50051 5020",
        "ENTRYPOINT",
    ] {
        assert!(docker.contains(needed), "Dockerfile lacks {needed}");
    }
    for line in docker
        .lines()
        .filter(|l| l.starts_with("COPY ") && !l.contains("--from"))
    {
        let source = line.split_whitespace().nth(1).expect("source");
        if source != "." {
            assert!(repo().join(source).exists(), "COPY {source}: missing");
        }
    }
}

#[test]
fn the_shipped_configs_pass_the_gateways_own_check() {
    let check = |yaml: &str| {
        let yaml = yaml.replace("profiles: /etc/iogate/profiles", "");
        iogate::drivers::register();
        let mut config = iogate::config::parse("deploy.yaml", &yaml).map_err(|p| p.to_string())?;
        config.profiles = Some(iogate_tests::profiles_dir());
        iogate::app::Setup::from_config(config, Path::new("."))
            .map(drop)
            .map_err(|p| p.to_string())
    };
    let compose = std::fs::read_to_string(deploy("compose/iogate.yaml")).expect("compose config");
    check(&compose).expect("the compose config");
    // The image's default listens beyond loopback: without tokens it refuses to start, and
    // for that reason only.
    let image = std::fs::read_to_string(deploy("docker/iogate.yaml")).expect("image config");
    let refused = check(&image).expect_err("no tokens");
    assert!(refused.contains("no tokens are configured"), "{refused}");
    assert_eq!(
        refused
            .lines()
            .filter(|l| l.contains("deploy.yaml"))
            .count(),
        3,
        "HTTP, gRPC and OPC UA: {refused}"
    );
    let with_tokens = format!("{image}security:\n  insecure: true\n");
    check(&with_tokens).expect("otherwise valid");
    // The Kubernetes config, with the profile the ConfigMap carries.
    let configmap =
        std::fs::read_to_string(deploy("kubernetes/configmap.yaml")).expect("configmap");
    let doc: serde_json::Value = serde_saphyr::from_str(&configmap).expect("yaml");
    let config = doc["data"]["iogate.yaml"].as_str().expect("config");
    let profile = doc["data"]["my_io_module.yaml"].as_str().expect("profile");
    let dir = iogate_tests::devices::temp_dir("k8s-config");
    std::fs::write(dir.join("my_io_module.yaml"), profile).expect("profile");
    std::fs::write(dir.join("tokens"), "admin k8s-admin-token-0123456789\n").expect("tokens");
    let config = config
        .replace("/etc/iogate/profiles", &dir.display().to_string())
        .replace(
            "/etc/iogate/tokens/tokens",
            &dir.join("tokens").display().to_string(),
        );
    iogate::drivers::register();
    let parsed = iogate::config::parse("configmap", &config).expect("parses");
    iogate::app::Setup::from_config(parsed, Path::new(".")).expect("the ConfigMap's config");
}

#[tokio::test]
async fn every_metric_of_the_dashboard_and_the_alerts_is_exported() {
    let dashboard = std::fs::read_to_string(deploy("grafana/iogate.json")).expect("dashboard");
    let doc: serde_json::Value = serde_json::from_str(&dashboard).expect("valid JSON");
    let panels = doc["panels"].as_array().expect("panels");
    let ids: Vec<u64> = panels.iter().filter_map(|p| p["id"].as_u64()).collect();
    let unique: BTreeSet<u64> = ids.iter().copied().collect();
    assert_eq!(ids.len(), panels.len(), "every panel has an id");
    assert_eq!(unique.len(), ids.len(), "panel ids are unique: {ids:?}");
    let variables: Vec<&str> = doc["templating"]["list"]
        .as_array()
        .expect("variables")
        .iter()
        .filter_map(|v| v["name"].as_str())
        .collect();
    assert!(variables.contains(&"link") && variables.contains(&"device"));

    let (gw, _pty, task, _) = busy_gateway().await;
    let names = exported(&gw).await;
    let alerts = std::fs::read_to_string(deploy("prometheus/alerts.yml")).expect("alerts");
    let rules: serde_json::Value = serde_saphyr::from_str(&alerts).expect("rules yaml");
    let expressions: String = rules["groups"][0]["rules"]
        .as_array()
        .expect("rules")
        .iter()
        .filter_map(|r| r["expr"].as_str())
        .collect::<Vec<_>>()
        .join("\n");
    let expressions_in_panels: String = panels
        .iter()
        .flat_map(|p| p["targets"].as_array().into_iter().flatten())
        .filter_map(|t| t["expr"].as_str())
        .collect::<Vec<_>>()
        .join("\n");
    for (what, text) in [
        (
            "dashboard",
            format!("{expressions_in_panels}\n{}", doc["templating"]),
        ),
        ("alert rules", expressions),
    ] {
        let used = used_names(&text);
        assert!(used.len() >= 8, "{what}: {used:?}");
        let missing: Vec<_> = used.difference(&names).collect();
        assert!(
            missing.is_empty(),
            "{what} uses metrics /metrics does not export: {missing:?}\nexported: {names:?}"
        );
    }
    gw.shutdown().await;
    task.abort();
}

#[tokio::test]
async fn metrics_pass_promtool_and_openmetrics_is_served_to_who_asks_for_it() {
    tools();
    let (gw, _pty, task, _) = busy_gateway().await;
    let client = reqwest::Client::new();
    let scrape = |accept: Option<&'static str>| {
        let request = client.get(gw.url("/metrics"));
        let request = match accept {
            Some(a) => request.header("accept", a),
            None => request,
        };
        async move {
            let response = request.send().await.expect("scrape");
            let content_type = response
                .headers()
                .get("content-type")
                .and_then(|v| v.to_str().ok())
                .unwrap_or("")
                .to_owned();
            (content_type, response.text().await.expect("body"))
        }
    };
    // As curl asks: the Prometheus text format 0.0.4, which promtool checks and lints.
    for accept in [None, Some("*/*"), Some("text/plain;version=0.0.4")] {
        let (content_type, text) = scrape(accept).await;
        assert_eq!(
            content_type, "text/plain; version=0.0.4; charset=utf-8",
            "{accept:?}"
        );
        assert!(
            !text.contains("# EOF") && !text.contains("# UNIT"),
            "{text}"
        );
        assert!(
            text.contains("# TYPE iogate_device_requests_total counter"),
            "{text}"
        );
        let (ok, report) = piped("promtool", &["check", "metrics"], &text);
        assert!(ok, "promtool check metrics:\n{report}\n{text}");
    }
    // As Prometheus asks: OpenMetrics 1.0, read by the official Python client's parser.
    let (content_type, text) = scrape(Some(
        "application/openmetrics-text;version=1.0.0,application/openmetrics-text;version=0.0.1;q=0.75,text/plain;version=0.0.4;q=0.5,*/*;q=0.1",
    ))
    .await;
    assert_eq!(
        content_type,
        "application/openmetrics-text; version=1.0.0; charset=utf-8"
    );
    assert!(text.ends_with("# EOF\n"), "{text}");
    let (ok, report) = piped(
        &iogate_tests::python().to_string_lossy(),
        &[
            "-c",
            "import sys\nfrom prometheus_client.openmetrics.parser import text_string_to_metric_families as parse\n\
             families = list(parse(sys.stdin.read()))\nprint(len(families), sum(len(f.samples) for f in families))",
        ],
        &text,
    );
    assert!(ok, "the OpenMetrics parser refused it:\n{report}\n{text}");
    let counts: Vec<usize> = report
        .split_whitespace()
        .filter_map(|n| n.parse().ok())
        .collect();
    assert!(
        counts.len() == 2 && counts[0] >= 10 && counts[1] >= 30,
        "families and samples: {report}"
    );
    gw.shutdown().await;
    task.abort();
}

#[test]
fn the_pairs_compose_mounts_two_configs_that_differ_only_in_their_node_and_pass_check() {
    let dir = deploy("compose-ha");
    let text = std::fs::read_to_string(dir.join("docker-compose.yml")).expect("compose");
    let doc: serde_json::Value = serde_saphyr::from_str(&text).expect("compose parses");
    let services = doc["services"].as_object().expect("services");
    for name in ["iogate-a", "iogate-b", "mosquitto"] {
        assert!(services.contains_key(name), "no service {name}");
        for volume in services[name]["volumes"].as_array().into_iter().flatten() {
            let source = volume
                .as_str()
                .and_then(|v| v.split(':').next())
                .expect("volume");
            assert!(dir.join(source).exists(), "{name} mounts {source}: missing");
        }
    }
    let [a, b] = ["a", "b"]
        .map(|n| std::fs::read_to_string(dir.join(format!("iogate-{n}.yaml"))).expect("config"));
    // The same config but for the node: a pair runs one configuration.
    let unnamed = |t: &str, n: &str| {
        t.replace(&format!("Node {n} "), "Node ")
            .replace(&format!("node: {n}"), "node:")
            .replace(&format!("iogate-{n}"), "iogate-")
            .replace(&format!("pair-{n}"), "pair-")
    };
    assert_eq!(unnamed(&a, "a"), unnamed(&b, "b"));
    for (n, text) in [("a", &a), ("b", &b)] {
        iogate::drivers::register();
        let yaml = text.replace("profiles: /etc/iogate/profiles", "");
        let mut config = iogate::config::parse("pair.yaml", &yaml).expect("parses");
        config.profiles = Some(iogate_tests::profiles_dir());
        iogate::app::Setup::from_config(config, Path::new("."))
            .unwrap_or_else(|p| panic!("node {n}: {p}"));
    }
}

#[test]
fn the_pairs_kubernetes_manifests_validate_and_their_config_passes_check() {
    tools();
    let files = [
        "rbac.yaml",
        "configmap.yaml",
        "mosquitto.yaml",
        "statefulset.yaml",
        "service.yaml",
    ];
    let paths: Vec<String> = files
        .iter()
        .map(|f| format!("deploy/kubernetes-ha/{f}"))
        .collect();
    let mut args = vec!["-m", "kubernetes_validate", "--strict", "--quiet"];
    args.extend(paths.iter().map(String::as_str));
    run(&iogate_tests::python().to_string_lossy(), &args);
    let kustomization =
        std::fs::read_to_string(deploy("kubernetes-ha/kustomization.yaml")).expect("kustomization");
    for file in files {
        assert!(kustomization.contains(file), "{file} not in kustomization");
    }
    let set = std::fs::read_to_string(deploy("kubernetes-ha/statefulset.yaml")).expect("set");
    for needed in [
        "replicas: 2",
        "podManagementPolicy: Parallel",
        "IOGATE_HA_NODE",
        "fieldPath: metadata.name",
        "serviceAccountName: iogate",
        "/readyz",
    ] {
        assert!(set.contains(needed), "the StatefulSet lacks {needed}");
    }
    let rbac = std::fs::read_to_string(deploy("kubernetes-ha/rbac.yaml")).expect("rbac");
    assert!(rbac.contains("coordination.k8s.io") && rbac.contains("leases"));
    // The replicas' config passes the gateway's own check, its API server given (outside a
    // pod there is none to find).
    let configmap =
        std::fs::read_to_string(deploy("kubernetes-ha/configmap.yaml")).expect("configmap");
    let doc: serde_json::Value = serde_saphyr::from_str(&configmap).expect("yaml");
    let config = doc["data"]["iogate.yaml"].as_str().expect("config");
    assert!(config.contains("arbiter: kubernetes"), "{config}");
    let dir = iogate_tests::devices::temp_dir("k8s-pair-config");
    std::fs::write(dir.join("tokens"), "admin k8s-admin-token-0123456789\n").expect("tokens");
    let config = config
        .replace("profiles: /etc/iogate/profiles", "")
        .replace(
            "/etc/iogate/tokens/tokens",
            &dir.join("tokens").display().to_string(),
        )
        .replace(
            "/var/lib/iogate/buffer",
            &dir.join("buffer").display().to_string(),
        )
        .replace(
            "lease: 3s\n",
            "lease: 3s\n  kubernetes: { api: \"http://127.0.0.1:9\" }\n",
        );
    iogate::drivers::register();
    let mut parsed = iogate::config::parse("configmap", &config).expect("parses");
    parsed.profiles = Some(iogate_tests::profiles_dir());
    iogate::app::Setup::from_config(parsed, Path::new(".")).expect("the pair's config");
}
