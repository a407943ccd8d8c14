use super::*;

/// Every refinement finds its place in utoipa's document: a renamed schema or path
/// would leave it out silently.
#[test]
fn every_refinement_lands() {
    let doc = document(true, &Described::default());
    let has = |pointer: &str| doc.pointer(pointer).is_some();
    for pointer in [
        "/components/schemas/FieldValue/properties/value/type/4",
        "/components/schemas/WriteInfo/properties/value/type/3",
        "/components/schemas/StandingValues/properties/values/items/type",
        "/components/schemas/DeviceDetail/allOf/1/properties/fields/additionalProperties",
        "/paths/~1api~1v1~1devices~1{device}~1fields/patch/requestBody/content/application~1json/schema/minProperties",
        "/paths/~1api~1v1~1devices~1{device}~1fields~1{field}/put/requestBody/content/application~1json/schema/oneOf",
        "/paths/~1api~1v1~1map~1{at}/put/requestBody/content/application~1json/schema/oneOf",
        "/paths/~1api~1v1~1map~1{at}/get/parameters/0/schema/pattern",
        "/components/schemas/DeviceDeclarationBody/properties/timeout_ms/maximum",
        "/components/schemas/TcpDeclaration/properties/port/maximum",
        "/components/schemas/SerialDeclaration/properties/baud/minimum",
        "/components/schemas/LinkDeclarationBody/oneOf",
        "/components/schemas/TransactionSpec/anyOf",
        "/components/schemas/StandingDeclaration/properties/link/pattern",
        "/components/schemas/StandingDeclaration/anyOf",
        "/paths/~1api~1v1~1config~1reload/post/responses/400/content/application~1json/schema/anyOf",
        "/components/securitySchemes/bearer",
        "/paths/~1api~1v1~1devices/get/security",
        "/paths/~1api~1v1~1devices/get/responses/401",
    ] {
        assert!(has(pointer), "{pointer} is not in the document");
    }
    assert_eq!(
        doc.pointer("/components/schemas/DeviceDeclarationBody/properties/timeout_ms/minimum"),
        Some(&json!(10))
    );
    // Without tokens, no operation asks for one; health endpoints never do.
    let open = document(false, &Described::default());
    assert!(
        open.pointer("/paths/~1api~1v1~1devices/get/security")
            .is_none()
    );
    assert!(doc.pointer("/paths/~1livez/get/security").is_none());
}
