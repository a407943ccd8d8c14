use super::*;
use crate::codec::Raw;

fn problems(text: &str) -> Vec<String> {
    match load_str("p.yaml", text) {
        Ok(p) => panic!("loaded {p:?}"),
        Err(problems) => problems.iter().map(|p| p.to_string()).collect(),
    }
}

fn assert_problem(text: &str, line: u64, needle: &str) {
    let all = problems(text);
    assert!(
        all.iter()
            .any(|p| p.starts_with(&format!("p.yaml:{line}:")) && p.contains(needle)),
        "no problem on line {line} containing {needle:?} in {all:#?}"
    );
}

#[test]
fn waveshare_example_profile_loads() {
    let text = "name: WaveshareAnalogInput\nvendor: Waveshare\nprotocol: modbus-rtu\nfields:\n  - { name: AI1, type: INT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: AI2, type: INT, direction: input, register: { address: 1, kind: input_register } }\n";
    let p = load_str("w.yaml", text).expect("loads");
    assert_eq!(p.name, "WaveshareAnalogInput");
    assert_eq!(p.fields.len(), 2);
    assert_eq!(p.fields[1].register.address, 1);
    assert_eq!(p.fields[1].line, 6);
    assert_eq!(
        p.fields[0].encoding.raw,
        Raw::Int {
            bits: 16,
            signed: true
        }
    );
}

#[test]
fn output_on_input_register_is_rejected() {
    assert_problem(
        "name: X\nfields:\n  - name: A\n    type: INT\n    direction: output\n    register: { address: 0, kind: input_register }\n",
        6,
        "read-only input_register",
    );
}

#[test]
fn every_problem_is_reported_at_once() {
    let text = "name: X\ncolour: red\nfields:\n  - { name: A, type: INT, direction: input, register: { address: 0, kind: input_register } }\n  - { name: a, type: INT, direction: input, register: { address: 5, kind: input_register } }\n  - { name: B, type: BOOL, direction: input, register: { address: 1, kind: holding_register, bit: 16 } }\n  - { name: C, type: INT, direction: input, register: { address: 2, kind: input_register, scale: 0 } }\n";
    let all = problems(text);
    assert_eq!(all.len(), 4, "{all:#?}");
    assert_problem(text, 2, "unknown key `colour`");
    assert_problem(text, 5, "duplicate field name");
    assert_problem(text, 6, "bit: 16 is outside");
    assert_problem(text, 7, "scale must not be zero");
}

#[test]
fn overlapping_fields_are_rejected_but_distinct_bits_share() {
    let text = "name: X\nfields:\n  - { name: A, type: REAL, direction: input, register: { address: 0, kind: input_register, word_count: 2 } }\n  - { name: B, type: INT, direction: input, register: { address: 1, kind: input_register } }\n  - { name: F0, type: BOOL, direction: input, register: { address: 9, kind: holding_register, bit: 0 } }\n  - { name: F1, type: BOOL, direction: input, register: { address: 9, kind: holding_register, bit: 1 } }\n";
    let all = problems(text);
    assert_eq!(all.len(), 1, "{all:#?}");
    assert_problem(text, 4, "overlaps field A (line 3) at input_register 1-1");
}

#[test]
fn type_must_fit_kind_and_word_count() {
    let text = "name: X\nfields:\n  - { name: A, type: INT, direction: input, register: { address: 0, kind: coil } }\n  - { name: B, type: DINT, direction: input, register: { address: 0, kind: input_register, word_count: 3 } }\n  - { name: S, type: STRING, direction: input, register: { address: 5, kind: input_register, word_count: 8 } }\n  - { name: W, type: DINT, direction: input, register: { address: 20, kind: input_register, word_count: 1 } }\n";
    assert_problem(text, 3, "type must be BOOL, not INT");
    assert_problem(
        text,
        4,
        "DINT does not fit in 3 register(s) (allowed: 1 = a 16-bit register widened, 2 = the full 32-bit value)",
    );
    assert_eq!(problems(text).len(), 2, "word_count 1 on a DINT is allowed");
}

#[test]
fn without_word_count_every_type_takes_one_register_and_says_so() {
    let text = "name: X\nfields:\n  - { name: Count, type: DINT, direction: output, register: { address: 0, kind: holding_register } }\n  - { name: Total, type: UDINT, direction: input, register: { address: 1, kind: input_register, word_count: 2 } }\n  - { name: Temp, type: REAL, direction: input, register: { address: 3, kind: input_register, scale: 0.1 } }\n  - { name: Ramp, type: TIME, direction: input, register: { address: 4, kind: input_register } }\n";
    let p = load_str("w.yaml", text).expect("loads");
    let count = &p.fields[0];
    assert_eq!(count.register.word_count, 1);
    assert_eq!(count.encoding.words(), 1);
    assert_eq!(
        count.encoding.decode(&[0xFB2E]),
        Ok(crate::codec::Value::Int(-1234)),
        "sign-extended"
    );
    assert_eq!(
        count.encoding.encode(&crate::codec::Value::Int(-1234)),
        Ok(vec![0xFB2E])
    );
    assert!(
        count
            .encoding
            .encode(&crate::codec::Value::Int(40_000))
            .is_err(),
        "a value past 16 bits is refused, never wrapped"
    );
    assert_eq!(p.fields[1].encoding.words(), 2);
    let warnings: Vec<String> = p.width_warnings().iter().map(ToString::to_string).collect();
    assert_eq!(
        warnings,
        [
            "w.yaml:3: field Count: DINT with no `word_count` reads one register as a 16-bit value, sign-extended (the default is 1); to read the full 32-bit value, add `word_count: 2` to its register",
            "w.yaml:6: field Ramp: TIME with no `word_count` reads one register as 16-bit milliseconds (the default is 1); to read 32- or 64-bit milliseconds, add `word_count: 2` or `4` to its register",
        ],
        "the scaled REAL and the explicit UDINT are fine"
    );
}

#[test]
fn virtual_registers_need_a_simulated_profile() {
    assert_problem(
        "name: X\nprotocol: modbus-rtu\nfields:\n  - { name: A, type: BOOL, direction: input, register: { address: 0, kind: virtual } }\n",
        4,
        "only in simulated profiles",
    );
}

#[test]
fn address_past_the_end_is_rejected() {
    assert_problem(
        "name: X\nfields:\n  - { name: A, type: LREAL, direction: input, register: { address: 65534, kind: input_register, word_count: 4 } }\n",
        3,
        "runs past 65535",
    );
    assert_problem(
        "name: X\nfields:\n  - { name: A, type: INT, direction: input, register: { address: 70000, kind: input_register } }\n",
        3,
        "70000 is outside the allowed range 0-65535",
    );
}

#[test]
fn raw_type_chooses_an_unsigned_register() {
    let p = load_str(
        "p.yaml",
        "name: X\nfields:\n  - { name: T, type: REAL, direction: input, register: { address: 0, kind: input_register, raw_type: UINT, scale: 0.1 } }\n  - { name: E, type: LREAL, direction: input, register: { address: 1, kind: input_register, raw_type: UDINT, scale: 0.01 } }\n",
    )
    .expect("loads");
    assert_eq!(
        p.fields[0].encoding.raw,
        Raw::Int {
            bits: 16,
            signed: false
        }
    );
    assert_eq!(p.fields[1].register.word_count, 2);
    assert_problem(
        "name: X\nfields:\n  - { name: T, type: INT, direction: input, register: { address: 0, kind: input_register, raw_type: UINT } }\n",
        3,
        "raw_type is for REAL/LREAL",
    );
}

#[test]
fn reserved_and_invalid_names_are_rejected() {
    let text = "name: 9lives\nfields:\n  - { name: connected, type: BOOL, direction: input, register: { address: 0, kind: coil } }\n";
    assert_problem(text, 1, "not an IEC identifier");
    assert_problem(text, 3, "name is taken");
    for keyword in ["TYPE", "END_VAR", "Function"] {
        let text = format!(
            "name: Io\nfields:\n  - {{ name: {keyword}, type: BOOL, direction: input, register: {{ address: 0, kind: coil }} }}\n"
        );
        assert_problem(&text, 3, "is an IEC 61131-3 keyword");
    }
    let text = "name: Program\nfields:\n  - { name: A, type: BOOL, direction: input, register: { address: 0, kind: coil } }\n";
    assert_problem(text, 1, "is an IEC 61131-3 keyword");
}

proptest::proptest! {
    #[test]
    fn arbitrary_text_never_panics(text in "\\PC{0,300}") {
        let _ = load_str("fuzz.yaml", &text);
    }

    #[test]
    fn mutated_shipped_profiles_never_panic(
        which in 0..crate::demo::PROFILES.len(),
        at in proptest::prelude::any::<proptest::sample::Index>(),
        insert in "[ \\-:{}\\[\\],#'\"a-z0-9\n]{0,4}",
        cut in 0usize..6,
    ) {
        let (name, text) = crate::demo::PROFILES[which];
        let _ = load_str(name, &crate::yaml::mutate(text, at, &insert, cut));
    }
}

#[test]
fn duplicate_profile_names_across_files_are_rejected() {
    let a = "name: Same\nfields:\n  - { name: A, type: BOOL, direction: input, register: { address: 0, kind: coil } }\n";
    let err = load_files([("a.yaml", a), ("b.yaml", a)]).expect_err("duplicate");
    assert!(err.to_string().contains("b.yaml:1"), "{err}");
    assert!(err.to_string().contains("already used in a.yaml"), "{err}");
}

#[test]
fn an_s7_fields_address_type_and_scaling_are_checked_with_their_lines() {
    crate::drivers::register();
    let head = "name: P\nprotocol: s7\nfields:\n";
    for (field, needle) in [
        (
            "{ name: a, type: REAL, direction: input, address: MW2 }",
            "the address is 2 byte(s); a REAL is 4",
        ),
        (
            "{ name: a, type: STRING, direction: input, address: DB1.DBB0 }",
            "needs its `length:`",
        ),
        (
            "{ name: a, type: INT, direction: input, address: DB0.DBW0 }",
            "numbered from 1",
        ),
        (
            "{ name: a, type: STRING, direction: input, address: DB1.DBB0, length: 8, scale: 2 }",
            "cannot be scaled",
        ),
        (
            "{ name: a, type: REAL, direction: input, address: DB1.DBW0, raw_type: INT, scale: 0 }",
            "must not be zero",
        ),
        (
            "{ name: a, type: REAL, direction: input, address: DB1.DBW0, raw_type: BOOL }",
            "raw_type is the number type",
        ),
        (
            "{ name: a, type: REAL, direction: input, address: DB1.DBD0, raw_type: INT }",
            "the address is 4 byte(s); a INT is 2",
        ),
    ] {
        assert_problem(&format!("{head}  - {field}\n"), 4, needle);
    }
    let ok = load_str(
        "p.yaml",
        &format!("{head}  - {{ name: a, type: REAL, direction: input, address: DB1.DBW0, raw_type: INT, scale: 0.1, offset: -5 }}\n"),
    )
    .expect("a scaled field loads");
    let r = &ok.fields[0].register;
    assert_eq!(
        (r.scale, r.offset, r.raw_type),
        (0.1, -5.0, Some(IecType::Int))
    );
}

#[test]
fn one_place_named_two_ways_is_one_point() {
    crate::drivers::register();
    // A counter in English and German, a timer in two cases; two distinct counters pass.
    let text = "name: P\nprotocol: s7\nfields:\n  - { name: C, type: INT, direction: input, address: C3 }\n  - { name: Z, type: WORD, direction: input, address: Z3 }\n  - { name: T, type: TIME, direction: input, address: T5 }\n  - { name: T2, type: WORD, direction: input, address: t5 }\n  - { name: C4, type: INT, direction: input, address: C4 }\n";
    assert_problem(text, 5, "names the same point as field C (line 4)");
    assert_problem(text, 7, "names the same point as field T (line 6)");
    assert_eq!(problems(text).len(), 2, "{:#?}", problems(text));
    // Logix tags are one tag whatever their case.
    let text = "name: P\nprotocol: ab-eip\nfields:\n  - { name: A, type: DINT, direction: input, tag: Count }\n  - { name: B, type: DINT, direction: input, tag: COUNT }\n";
    assert_problem(text, 5, "names the same point as field A (line 4)");
}
