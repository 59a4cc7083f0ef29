//! Score and ModelInfer: Eq. 5.6 of the networks, the twin critics' disagreement, and every malformed request refused naming its field.

use crate::support::*;

#[test]
fn score_and_model_infer_give_eq_5_6_of_the_networks() {
    let (s, n) = server(ServeConfig::default());
    rt().block_on(async {
        let ch = channel(&s).await;
        let mut d = DesignServiceClient::new(ch.clone());
        let info = d.info(pb::InfoRequest {}).await.unwrap().into_inner();
        assert_eq!((info.robot.as_str(), info.weights_version, info.start_states, info.max_score_batch), ("toy", 42, 7, 10_000));
        assert_eq!(
            info.dimensions.iter().map(|x| (x.name.as_str(), x.low, x.high)).collect::<Vec<_>>(),
            [("thigh", 0.5, 2.0), ("shin", 0.5, 2.0), ("foot", 0.5, 2.0)]
        );
        let batch = [[1.0, 1.0, 1.0], [0.5, 2.0, 1.3], [2.0, 0.5, 0.7], [1.7, 1.1, 2.0]];
        let got = d.score(designs(&batch)).await.unwrap().into_inner();
        assert_eq!((got.weights_version, got.start_states, got.scores.len()), (42, 7, 4));
        let mut distinct = Vec::new();
        for (x, sc) in batch.iter().zip(&got.scores) {
            let (mu, sd) = reference(&n, x);
            assert!((sc.objective - mu).abs() <= 1e-4 * (1.0 + mu.abs()), "objective {} vs {mu} for {x:?}", sc.objective);
            assert!((sc.spread - sd).abs() <= 1e-4 * (1.0 + sd.abs()), "spread {} vs {sd} for {x:?}", sc.spread);
            assert_eq!(sc.disagreement, None, "one critic: no disagreement to report");
            distinct.push(sc.objective);
        }
        distinct.dedup();
        assert_eq!(distinct.len(), 4, "the designs score alike: {distinct:?}");

        // The same values through the Open Inference Protocol, typed and raw.
        let mut i = GrpcInferenceServiceClient::new(ch);
        let flat: Vec<f32> = batch.iter().flatten().copied().collect();
        let input = |contents| oip::model_infer_request::InferInputTensor {
            name: "design".into(),
            datatype: "FP32".into(),
            shape: vec![4, DIM as i64],
            parameters: Default::default(),
            contents,
        };
        let typed = oip::ModelInferRequest {
            model_name: "design-critic".into(),
            id: "q1".into(),
            inputs: vec![input(Some(oip::InferTensorContents { fp32_contents: flat.clone(), ..Default::default() }))],
            ..Default::default()
        };
        let r = i.model_infer(typed.clone()).await.unwrap().into_inner();
        assert_eq!((r.id.as_str(), r.model_version.as_str(), r.outputs[0].shape.as_slice()), ("q1", "42", &[4, 1][..]));
        let values = &r.outputs[0].contents.as_ref().unwrap().fp32_contents;
        assert_eq!(values, &got.scores.iter().map(|s| s.objective).collect::<Vec<_>>());
        let names: Vec<&str> = r.outputs.iter().map(|o| o.name.as_str()).collect();
        assert_eq!(names, ["value", "spread"], "no output named: all of the model's");
        let spread = &r.outputs[1].contents.as_ref().unwrap().fp32_contents;
        assert_eq!(spread, &got.scores.iter().map(|s| s.spread).collect::<Vec<_>>());
        let raw = oip::ModelInferRequest {
            inputs: vec![input(None)],
            raw_input_contents: vec![flat.iter().flat_map(|v| v.to_le_bytes()).collect()],
            ..typed.clone()
        };
        let r = i.model_infer(raw).await.unwrap().into_inner();
        let back: Vec<f32> = r.raw_output_contents[0].chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        assert_eq!(&back, values);

        let meta = i
            .model_metadata(oip::ModelMetadataRequest { name: "design-critic".into(), version: String::new() })
            .await
            .unwrap()
            .into_inner();
        assert_eq!((meta.inputs[0].name.as_str(), meta.inputs[0].shape.as_slice()), ("design", &[-1, 3][..]));
        assert_eq!((meta.outputs[0].name.as_str(), meta.outputs[0].shape.as_slice()), ("value", &[-1, 1][..]));
        assert_eq!(meta.outputs.iter().map(|o| o.name.as_str()).collect::<Vec<_>>(), ["value", "spread"]);
        assert!(i.server_live(oip::ServerLiveRequest {}).await.unwrap().into_inner().live);
        assert!(i.server_ready(oip::ServerReadyRequest {}).await.unwrap().into_inner().ready);
        assert!(
            i.model_ready(oip::ModelReadyRequest { name: "design-critic".into(), version: "42".into() }).await.unwrap().into_inner().ready
        );
        let e = i.model_ready(oip::ModelReadyRequest { name: "nope".into(), version: String::new() }).await.unwrap_err();
        assert_eq!(e.code(), Code::NotFound);
    });
}

#[test]
fn with_the_twin_critics_a_score_says_how_far_they_disagree() {
    let n = nets();
    let model = model_with(&n, &[&n.theta, &n.theta2]);
    let s =
        serve("127.0.0.1:0".parse().unwrap(), ServeConfig::default(), Arc::new(StaticSource { model: Arc::new(model), history: vec![] }))
            .unwrap();
    rt().block_on(async {
        let ch = channel(&s).await;
        let batch = [[1.0, 1.0, 1.0], [0.5, 2.0, 1.3], [2.0, 0.5, 0.7]];
        let got = DesignServiceClient::new(ch.clone()).score(designs(&batch)).await.unwrap().into_inner();
        for (x, sc) in batch.iter().zip(&got.scores) {
            let (mu, _) = reference(&n, x);
            assert!((sc.objective - mu).abs() <= 1e-4 * (1.0 + mu.abs()), "Q1 still scores: {} vs {mu}", sc.objective);
            let want = reference_disagreement(&n, x);
            let d = sc.disagreement.expect("two critics: a disagreement");
            assert!(want > 1e-3, "the critics differ here: {want}");
            assert!((d - want).abs() <= 1e-4 * (1.0 + want), "disagreement {d} vs {want} for {x:?}");
        }

        let mut i = GrpcInferenceServiceClient::new(ch);
        let flat: Vec<f32> = batch.iter().flatten().copied().collect();
        let out = |name: &str| oip::model_infer_request::InferRequestedOutputTensor { name: name.into(), parameters: Default::default() };
        let req = oip::ModelInferRequest {
            model_name: "design-critic".into(),
            inputs: vec![oip::model_infer_request::InferInputTensor {
                name: "design".into(),
                datatype: "FP32".into(),
                shape: vec![3, DIM as i64],
                parameters: Default::default(),
                contents: None,
            }],
            raw_input_contents: vec![flat.iter().flat_map(|v| v.to_le_bytes()).collect()],
            outputs: vec![out("disagreement"), out("value")],
            ..Default::default()
        };
        let r = i.model_infer(req.clone()).await.unwrap().into_inner();
        assert_eq!(r.outputs.iter().map(|o| o.name.as_str()).collect::<Vec<_>>(), ["disagreement", "value"], "in the order asked");
        let raw: Vec<Vec<f32>> =
            r.raw_output_contents.iter().map(|b| b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()).collect();
        assert_eq!(raw[0], got.scores.iter().map(|s| s.disagreement.unwrap()).collect::<Vec<_>>());
        assert_eq!(raw[1], got.scores.iter().map(|s| s.objective).collect::<Vec<_>>());
        let meta = i
            .model_metadata(oip::ModelMetadataRequest { name: "design-critic".into(), version: String::new() })
            .await
            .unwrap()
            .into_inner();
        assert_eq!(meta.outputs.iter().map(|o| o.name.as_str()).collect::<Vec<_>>(), ["value", "spread", "disagreement"]);
        let twice = oip::ModelInferRequest { outputs: vec![out("value"), out("value")], ..req };
        invalid(i.model_infer(twice).await, "outputs[1].name");
    });
}

#[test]
fn malformed_requests_are_refused_naming_the_field() {
    let (s, _) = server(ServeConfig { max_score_batch: 5, ..ServeConfig::default() });
    rt().block_on(async {
        let ch = channel(&s).await;
        let mut d = DesignServiceClient::new(ch.clone());
        invalid(d.score(designs(&[])).await, "designs: empty");
        invalid(d.score(designs(&[[1.0; DIM]; 6])).await, "designs: 6 designs, at most 5");
        let short = pb::ScoreRequest { designs: vec![pb::Design { values: vec![1.0; DIM] }, pb::Design { values: vec![1.0; 2] }] };
        invalid(d.score(short).await, "designs[1].values: 2 values");
        invalid(d.score(designs(&[[1.0, 1.0, 2.5]])).await, "designs[0].values[2] (foot): 2.5 is outside the design box");
        invalid(d.score(designs(&[[f32::NAN, 1.0, 1.0]])).await, "designs[0].values[0] (thigh)");

        let mut i = GrpcInferenceServiceClient::new(ch);
        let req = |shape: Vec<i64>, n: usize| oip::ModelInferRequest {
            model_name: "design-critic".into(),
            inputs: vec![oip::model_infer_request::InferInputTensor {
                name: "design".into(),
                datatype: "FP32".into(),
                shape,
                parameters: Default::default(),
                contents: Some(oip::InferTensorContents { fp32_contents: vec![1.0; n], ..Default::default() }),
            }],
            ..Default::default()
        };
        invalid(i.model_infer(req(vec![2, 4], 8)).await, "inputs[0].shape");
        invalid(i.model_infer(req(vec![6, 3], 18)).await, "inputs[0].shape: [6, 3]: N must be 1 to 5");
        invalid(i.model_infer(req(vec![2, 3], 5)).await, "inputs[0].contents.fp32_contents: 5 values");
        let mut r = req(vec![1, 3], 0);
        r.inputs[0].contents = None;
        r.raw_input_contents = vec![vec![0; 11]];
        invalid(i.model_infer(r).await, "raw_input_contents[0]: 11 bytes");
        let mut r = req(vec![1, 3], 3);
        r.inputs[0].datatype = "FP64".into();
        invalid(i.model_infer(r).await, "inputs[0].datatype");
        let mut r = req(vec![1, 3], 3);
        r.outputs = vec![oip::model_infer_request::InferRequestedOutputTensor { name: "q".into(), parameters: Default::default() }];
        invalid(i.model_infer(r).await, "outputs[0].name");
        let mut r = req(vec![1, 3], 3);
        r.model_name = "other".into();
        assert_eq!(i.model_infer(r).await.unwrap_err().code(), Code::NotFound);
        let mut r = req(vec![1, 3], 3);
        r.model_version = "41".into();
        assert_eq!(i.model_infer(r).await.unwrap_err().code(), Code::NotFound);
    });
}
