use super::*;

fn parse_ok(text: &str) -> Node {
    let mut report = Report::new("t.yaml");
    let node = parse(text, &mut report);
    assert!(!report.has_problems(), "{}", report.into_problems());
    node.expect("parsed")
}

#[test]
fn values_keep_their_lines() {
    let node = parse_ok("a: 1\nb:\n  - x\n  - { c: 2.5 }\n");
    let Kind::Map(entries) = &node.kind else {
        panic!("not a map")
    };
    assert_eq!(entries[0].0.name, "a");
    assert_eq!(entries[0].1.kind, Kind::Int(1));
    assert_eq!(entries[1].0.line, 2);
    let Kind::Seq(items) = &entries[1].1.kind else {
        panic!("not a seq")
    };
    assert_eq!(items[1].line, 4);
}

#[test]
fn syntax_error_names_its_line() {
    let mut report = Report::new("bad.yaml");
    assert!(parse("a: 1\nb: [1, 2\nc: d\n", &mut report).is_none());
    let problems = report.into_problems();
    assert_eq!(problems.len(), 1);
    assert!(problems.0[0].line >= 2, "{problems}");
    assert!(problems.0[0].message.starts_with("invalid YAML"));
}

#[test]
fn duplicate_keys_are_an_error() {
    let mut report = Report::new("dup.yaml");
    assert!(parse("a: 1\na: 2\n", &mut report).is_none());
    let problems = report.into_problems();
    assert_eq!(problems.0[0].line, 2);
    assert_eq!(
        problems.0[0].message,
        "duplicate key `a`: a key may appear once in a mapping (keep one)"
    );
}

#[test]
fn unknown_keys_are_reported_with_their_lines() {
    let node = parse_ok("name: x\ncolour: red\nsize: 3\n");
    let mut report = Report::new("t.yaml");
    let mut map = node.map(&mut report, "").expect("map");
    assert!(map.get("name").is_some());
    map.finish(&mut report, "profile", &["name"]);
    let problems = report.into_problems();
    assert_eq!(problems.len(), 2);
    assert_eq!(problems.0[0].line, 2);
    assert!(problems.0[0].message.contains("`colour`"));
    assert_eq!(problems.0[1].line, 3);
}

#[test]
fn empty_document_is_null() {
    assert_eq!(parse_ok("").kind, Kind::Null);
    assert_eq!(parse_ok("# only a comment\n").kind, Kind::Null);
}

#[test]
fn a_profile_of_fifty_thousand_fields_is_read_and_a_larger_file_named_so() {
    crate::drivers::register();
    let mut text = String::from("name: Big\nprotocol: opcua\nfields:\n");
    for k in 0..50_000 {
        text.push_str(&format!(
            "  - {{ name: V{k}, type: DINT, direction: input, node: \"ns=2;s=V{k}\", unit: rpm }}\n"
        ));
    }
    let node = parse_ok(&text);
    let Kind::Map(entries) = &node.kind else {
        panic!("a map");
    };
    assert_eq!(entries.len(), 3);
    // Past the bound: one problem that says what to do.
    let many = format!("[{}]", vec!["0"; MAX_VALUES + 1].join(","));
    let mut report = Report::new("huge.yaml");
    assert!(parse(&many, &mut report).is_none());
    let problems = report.into_problems();
    assert_eq!(problems.len(), 1, "{problems}");
    assert!(
        problems.0[0]
            .message
            .contains("split it into several profiles"),
        "{problems}"
    );
}
