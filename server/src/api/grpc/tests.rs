use super::*;
use crate::app::Setup;
use crate::cache::Cache;
use crate::metrics::Metrics;
use crate::runtime::Tasks;

#[tokio::test]
async fn a_slow_subscriber_gets_the_newest_value_not_a_backlog() {
    // No device tasks run: only this test changes the value.
    let setup = Setup::demo_simulated().expect("demo");
    let cache = Arc::new(Cache::new(&setup.config, setup.catalog));
    let tasks = Tasks::new(
        tokio_util::task::TaskTracker::new(),
        tokio_util::sync::CancellationToken::new(),
        Arc::new(Metrics::new()),
    );
    let service = Arc::new(Service::new(cache, tasks));
    let api = GrpcApi::new(service.clone());
    let request = pb::SubscribeRequest {
        devices: Vec::new(),
        fields: vec![pb::FieldRef {
            device: "plant".into(),
            field: "Recipe".into(),
        }],
        diagnostics: false,
        transactions: false,
    };
    let stream = api.subscribe_encoded(request, None).expect("subscribe");
    let mut stream =
        stream.map(|bytes| bytes.map(|b| pb::Update::decode(b).expect("an encoded Update")));
    let first = stream.next().await.expect("current value").expect("ok");
    assert!(matches!(first.kind, Some(pb::update::Kind::Value(_))));

    // 50 changes while the subscriber reads nothing.
    let plant = service.device("plant").expect("plant");
    let recipe = plant.field_index("Recipe").expect("field");
    for n in 1..=50u64 {
        plant.publish(recipe, Ok(Value::UInt(n)));
    }
    let next = stream.next().await.expect("an update").expect("ok");
    let Some(pb::update::Kind::Value(v)) = next.kind else {
        panic!("not a value")
    };
    assert_eq!(
        v.value.and_then(|v| v.kind),
        Some(pb::value::Kind::UintValue(50)),
        "the newest value, not the first change"
    );
    let pending = tokio::time::timeout(Duration::from_millis(50), stream.next()).await;
    assert!(pending.is_err(), "nothing else is queued: {pending:?}");
}
