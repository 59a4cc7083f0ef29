//! Watch over a live run, and a server that stops within its grace.

use crate::support::*;

#[test]
fn watch_streams_the_history_then_each_change_until_the_run_ends() {
    let n = nets();
    // A resumed run's rows: design 1 is the open one.
    let live = Arc::new(LiveSource::new(vec![row(0, ""), row(1, "rejected")]));
    // Streams outlive the server's deadline for a call.
    let cfg = ServeConfig { rpc_timeout: std::time::Duration::from_millis(300), ..ServeConfig::default() };
    let s = serve("127.0.0.1:0".parse().unwrap(), cfg, live.clone()).unwrap();
    rt().block_on(async {
        let mut d = DesignServiceClient::new(channel(&s).await);
        // No networks yet: UNAVAILABLE, but the history is there.
        assert_eq!(d.info(pb::InfoRequest {}).await.unwrap_err().code(), Code::Unavailable);
        let h = d.history(pb::HistoryRequest { from_index: 0, max_rows: 0 }).await.unwrap().into_inner();
        assert_eq!(h.designs.len(), 2);
        let mut w = d.watch(pb::WatchDesignsRequest { from_index: 1 }).await.unwrap().into_inner();
        let first = next(&mut w).await.unwrap().design.unwrap();
        assert_eq!((first.index, first.prototype.as_str()), (1, "rejected"));
        tokio::time::sleep(std::time::Duration::from_millis(600)).await;
        // Design 1 chosen again and confirmed, then trained; design 2 chosen.
        let mut chosen = row(1, "confirmed");
        chosen.episodes = 0;
        live.upsert(chosen);
        live.upsert(row(1, "confirmed"));
        live.set_model(model(&n));
        live.upsert(row(2, ""));
        let got: Vec<(u32, u32, String)> = {
            let mut v = Vec::new();
            for _ in 0..3 {
                let r = next(&mut w).await.unwrap().design.unwrap();
                v.push((r.index, r.episodes, r.prototype));
            }
            v
        };
        assert_eq!(got, vec![(1, 0, "confirmed".into()), (1, 3, "confirmed".into()), (2, 3, String::new())]);
        // The history keeps the rejected proposal and the confirmed row, and the new design.
        let h = d.history(pb::HistoryRequest { from_index: 1, max_rows: 1 }).await.unwrap().into_inner();
        assert_eq!(
            h.designs.iter().map(|r| (r.index, r.prototype.clone())).collect::<Vec<_>>(),
            vec![(1, "rejected".to_string()), (1, "confirmed".to_string())]
        );
        assert!(h.more);
        assert_eq!(d.info(pb::InfoRequest {}).await.unwrap().into_inner().weights_version, 42);
        live.end();
        assert!(next(&mut w).await.is_none(), "the stream ends with the run");
        // A Watch after the end: the rows, then the end.
        let mut w = d.watch(pb::WatchDesignsRequest { from_index: 0 }).await.unwrap().into_inner();
        let mut rows = 0;
        while next(&mut w).await.is_some() {
            rows += 1;
        }
        assert_eq!(rows, 4);
    });
}

#[test]
fn a_server_stops_within_its_grace_whatever_its_clients_do() {
    let (s, _) = server(ServeConfig::default());
    let rt = rt();
    // A client that made a call and then went quiet without closing its connection (its
    // runtime is not polled again: as a frozen or hostile peer would).
    let mut d = rt.block_on(async { DesignServiceClient::new(channel(&s).await) });
    rt.block_on(d.info(pb::InfoRequest {})).unwrap();
    let t = std::time::Instant::now();
    drop(s);
    let took = t.elapsed();
    assert!(took < std::time::Duration::from_secs(3), "the server took {took:?} to stop");
    drop(d);
}

async fn next(w: &mut tonic::Streaming<pb::DesignEvent>) -> Option<pb::DesignEvent> {
    tokio::time::timeout(std::time::Duration::from_secs(5), w.message()).await.expect("no event in 5 s").unwrap()
}
