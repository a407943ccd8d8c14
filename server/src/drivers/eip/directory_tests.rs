use super::*;

#[test]
fn list_requests_name_the_scope_and_the_first_instance() {
    assert_eq!(
        list_request(None, 0),
        b"\x55\x02\x20\x6b\x24\x00\x03\x00\x01\x00\x02\x00\x08\x00"
    );
    let program = list_request(Some("Program:Main"), 300);
    assert_eq!(&program[..4], b"\x55\x0a\x91\x0c");
    assert_eq!(&program[4..16], b"Program:Main");
    assert_eq!(&program[16..22], b"\x20\x6b\x25\x00\x2c\x01");
    assert_eq!(&list_request(Some("P"), 70_000)[2..6], b"\x91\x01P\x00");
    assert_eq!(
        &list_request(None, 70_000)[2..10],
        b"\x20\x6b\x26\x00\x70\x11\x01\x00"
    );
}

fn entry(instance: u32, name: &str, ty: u16, dims: [u32; 3]) -> Vec<u8> {
    let mut b = instance.to_le_bytes().to_vec();
    b.extend_from_slice(&(name.len() as u16).to_le_bytes());
    b.extend_from_slice(name.as_bytes());
    b.extend_from_slice(&ty.to_le_bytes());
    for d in dims {
        b.extend_from_slice(&d.to_le_bytes());
    }
    b
}

#[test]
fn symbols_are_taken_apart_and_short_ones_refused() {
    let mut page = entry(1, "Speed", 0x00CA, [0; 3]);
    page.extend(entry(7, "Grid", 0x40C3, [2, 3, 0]));
    page.extend(entry(9, "M1", 0x8102, [0; 3]));
    let s = symbols(&page).expect("page");
    assert_eq!(s.len(), 3);
    assert_eq!(s[1].name, "Grid");
    assert_eq!(s[1].dims, [2, 3, 0]);
    assert_eq!(dimensions(s[1].ty), 2);
    assert_eq!(atomic_code(s[1].ty), 0xC3);
    assert!(is_structure(s[2].ty) && template_id(s[2].ty) == 0x102);
    assert!(is_system(0x1068) && !is_system(0x00C4));
    for cut in 1..page.len() {
        if cut != 25 && cut != 49 {
            assert!(symbols(&page[..cut]).is_err(), "cut at {cut}");
        }
    }
    assert!(symbols(&[]).expect("empty").is_empty());
}

#[test]
fn template_attributes_and_definitions_are_read_as_controllers_give_them() {
    assert_eq!(
        template_attributes_request(0x102),
        b"\x03\x03\x20\x6c\x25\x00\x02\x01\x04\x00\x04\x00\x05\x00\x02\x00\x01\x00"
    );
    // Asked 4, 5, 2, 1: attribute 1 refused (no value), the rest given.
    let mut a = 4u16.to_le_bytes().to_vec();
    for (id, status, value) in [
        (4u16, 0u16, &30u32.to_le_bytes()[..]),
        (5, 0, &12u32.to_le_bytes()[..]),
        (2, 0, &3u16.to_le_bytes()[..]),
        (1, 0x14, &[][..]),
    ] {
        a.extend_from_slice(&id.to_le_bytes());
        a.extend_from_slice(&status.to_le_bytes());
        a.extend_from_slice(value);
    }
    let info = template_attributes(&a).expect("attributes");
    assert_eq!(info.members, 3);
    assert_eq!(info.structure_size, 12);
    assert_eq!(info.bytes(), 100);
    assert!(template_attributes(&a[..12]).is_err());
    assert_eq!(
        read_template_request(5, 200, 480),
        b"\x4c\x02\x20\x6c\x24\x05\xc8\x00\x00\x00\xe0\x01"
    );
    // Three members: a hidden host, a BOOL in it, an INT[3]; the name with `;n...`.
    let mut d = Vec::new();
    for (info, ty, offset) in [(0u16, 0xC2u16, 0u32), (0, 0xC1, 0), (3, 0x20C3, 2)] {
        d.extend_from_slice(&info.to_le_bytes());
        d.extend_from_slice(&ty.to_le_bytes());
        d.extend_from_slice(&offset.to_le_bytes());
    }
    d.extend_from_slice(b"VALVE;n\x01\x02\0ZZZZZZZZZZVALVE0\0Open\0Hist\0\0\0");
    let t = template(&d, 3).expect("template");
    assert_eq!(t.name, "VALVE");
    let seen: Vec<&str> = t.visible().map(|m| m.name.as_str()).collect();
    assert_eq!(seen, ["Open", "Hist"]);
    assert_eq!(t.members[2].info, 3);
    assert!(!t.is_string());
    assert!(template(&d[..20], 3).is_err());
    assert!(template(&d[..30], 3).is_err(), "names missing");
    let mut s = Vec::new();
    for (info, ty) in [(0u16, 0xC4u16), (82, 0x20C2)] {
        s.extend_from_slice(&info.to_le_bytes());
        s.extend_from_slice(&ty.to_le_bytes());
        s.extend_from_slice(&0u32.to_le_bytes());
    }
    s.extend_from_slice(b"STRING20\0LEN\0DATA\0");
    assert!(template(&s, 2).expect("string").is_string());
}
