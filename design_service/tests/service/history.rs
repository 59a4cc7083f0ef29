//! History paged on whole designs; health and reflection.

use crate::support::*;

#[test]
fn history_pages_end_on_whole_designs() {
    let (s, _) = server(ServeConfig::default());
    rt().block_on(async {
        let mut d = DesignServiceClient::new(channel(&s).await);
        let p = d.history(pb::HistoryRequest { from_index: 0, max_rows: 2 }).await.unwrap().into_inner();
        // Rows 0 and 1 (rejected) fit the page; design 1's final row comes with them.
        assert_eq!(
            p.designs.iter().map(|r| (r.index, r.prototype.as_str())).collect::<Vec<_>>(),
            [(0, ""), (1, "rejected"), (1, "confirmed")]
        );
        assert_eq!((p.next_index, p.more), (2, true));
        assert_eq!(p.designs[0].design.as_ref().unwrap().values, [1.0, 1.0, 1.0]);
        assert_eq!(
            (p.designs[2].best_eval_return, p.designs[2].predicted_objective, p.designs[0].predicted_objective),
            (Some(11.0), Some(5.5), None)
        );
        let p = d.history(pb::HistoryRequest { from_index: p.next_index, max_rows: 0 }).await.unwrap().into_inner();
        assert_eq!((p.designs.len(), p.designs[0].index, p.more), (1, 2, false));
    });
}

#[test]
fn health_and_reflection_name_both_services() {
    use tonic_health::pb::health_check_response::ServingStatus;
    use tonic_health::pb::{HealthCheckRequest, health_client::HealthClient};
    use tonic_reflection::pb::v1::ServerReflectionRequest;
    use tonic_reflection::pb::v1::server_reflection_client::ServerReflectionClient;
    use tonic_reflection::pb::v1::server_reflection_request::MessageRequest;
    use tonic_reflection::pb::v1::server_reflection_response::MessageResponse;
    let (s, _) = server(ServeConfig::default());
    rt().block_on(async {
        let ch = channel(&s).await;
        let mut health = HealthClient::new(ch.clone());
        for service in ["", "coadapt.v1.DesignService", "inference.GRPCInferenceService"] {
            let st = health.check(HealthCheckRequest { service: service.into() }).await.unwrap().into_inner().status;
            assert_eq!(st, ServingStatus::Serving as i32, "{service:?}");
        }
        let mut reflection = ServerReflectionClient::new(ch);
        let req = ServerReflectionRequest { host: String::new(), message_request: Some(MessageRequest::ListServices(String::new())) };
        let mut answers = reflection.server_reflection_info(tokio_stream::iter(vec![req])).await.unwrap().into_inner();
        let Some(MessageResponse::ListServicesResponse(list)) = answers.message().await.unwrap().unwrap().message_response else {
            panic!("not a service list")
        };
        let names: Vec<_> = list.service.into_iter().map(|s| s.name).collect();
        for want in ["coadapt.v1.DesignService", "inference.GRPCInferenceService", "grpc.health.v1.Health"] {
            assert!(names.iter().any(|n| n == want), "{want} missing from {names:?}");
        }
    });
}
