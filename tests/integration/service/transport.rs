//! The transport edge: tokens, limits, bad messages, disconnects, health, reflection, readiness, one port, TLS.

use super::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_limits_bad_messages_and_disconnects() {
    let f = fixture_setup(1, true);
    let server = start(&f).await;
    let addr = server.grpc_addr;
    let name = "test_0000";
    let (messages, camera) = episode_messages(&episode(name));

    // No token, a wrong token: UNAUTHENTICATED. REST admin routes: 401 / 403.
    let err = stream_all(addr, None, open_msg("sim-arm", "x", None), vec![])
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unauthenticated);
    let err = stream_all(addr, Some("nope"), open_msg("sim-arm", "x", None), vec![])
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unauthenticated);
    let http = reqwest::Client::new();
    let url = format!("http://{}/v1/sessions", server.rest_addr);
    assert_eq!(http.get(&url).send().await.unwrap().status(), 401);
    assert_eq!(
        http.get(&url)
            .bearer_auth(ROBOT)
            .send()
            .await
            .unwrap()
            .status(),
        403
    );
    // Unknown profile: NOT_FOUND.
    let err = stream_all(addr, Some(ROBOT), open_msg("nope", "x", None), vec![])
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::NotFound);

    // A session that holds the only slot (it sends a few frames, then waits). It goes
    // through a TCP proxy, so the test can cut its connection as a network failure would.
    let (proxy_addr, proxy) = tcp_proxy(addr).await;
    let mut client = MonitorClient::connect(format!("http://{proxy_addr}"))
        .await
        .unwrap();
    let (tx, rx) = mpsc::channel(16);
    tx.send(proto::StreamRequest {
        message: Some(open_msg("sim-arm", "held", camera)),
    })
    .await
    .unwrap();
    let mut held = client
        .stream(authed(ReceiverStream::new(rx), Some(ROBOT)))
        .await
        .unwrap()
        .into_inner();
    let first = held.next().await.unwrap().unwrap();
    assert!(matches!(
        first.message,
        Some(proto::stream_response::Message::Event(ref e)) if e.kind == proto::session_event::Kind::Opened as i32
    ));
    // max_sessions = 1: a second session is refused.
    let err = stream_all(
        addr,
        Some(ROBOT),
        open_msg("sim-arm", "other", None),
        vec![],
    )
    .await
    .unwrap_err();
    assert_eq!(err.code(), tonic::Code::ResourceExhausted, "{err:?}");
    // A re-open of a session id that is streaming: ALREADY_EXISTS.
    let err = stream_all(addr, Some(ROBOT), open_msg("sim-arm", "held", None), vec![])
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::AlreadyExists, "{err:?}");

    // Bad messages: an undecodable image, NaN joints, a stamp going backwards. Each is
    // reported as an event and the session goes on.
    let mut good = messages.clone().into_iter();
    let mut sent = Vec::new();
    for m in good.by_ref() {
        let img = matches!(m, In::Image(_));
        sent.push(m);
        if img && sent.iter().filter(|m| matches!(m, In::Image(_))).count() == 4 {
            break;
        }
    }
    let last_stamp = sent
        .iter()
        .filter_map(|m| match m {
            In::Image(i) => Some(i.stamp_ns),
            _ => None,
        })
        .next_back()
        .unwrap();
    for m in sent {
        tx.send(proto::StreamRequest { message: Some(m) })
            .await
            .unwrap();
    }
    let bad = [
        In::Image(proto::Image {
            stamp_ns: last_stamp + 1,
            encoding: "rgb8".into(),
            width: 160,
            height: 120,
            step: 0,
            big_endian: false,
            data: vec![0; 10],
            depth: None,
        }),
        In::Joints(proto::JointState {
            stamp_ns: last_stamp + 2,
            names: vec!["pan".into()],
            positions: vec![f64::NAN],
            ..Default::default()
        }),
        In::Image(proto::Image {
            stamp_ns: 5,
            encoding: "jpeg".into(),
            data: vec![1, 2, 3],
            ..Default::default()
        }),
    ];
    for m in bad {
        tx.send(proto::StreamRequest { message: Some(m) })
            .await
            .unwrap();
    }
    let mut errors = Vec::new();
    let mut scores = 0;
    while errors.len() < 3 {
        let item = tokio::time::timeout(Duration::from_secs(30), held.next())
            .await
            .expect("events in time")
            .unwrap()
            .unwrap();
        match item.message {
            Some(proto::stream_response::Message::Event(e))
                if e.kind == proto::session_event::Kind::MessageError as i32 =>
            {
                errors.push(e.detail)
            }
            Some(proto::stream_response::Message::Score(_)) => scores += 1,
            _ => {}
        }
    }
    let all = errors.join("\n");
    assert!(all.contains("image refused"), "{all}");
    assert!(all.contains("non-finite"), "{all}");
    assert!(all.contains("is not after the previous image"), "{all}");
    let sessions: serde_json::Value = http
        .get(&url)
        .bearer_auth(ADMIN)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let list = sessions["sessions"].as_array().unwrap();
    assert_eq!(list.len(), 1);
    assert_eq!(list[0]["id"], "held");
    assert_eq!(list[0]["robot_id"], "robot-held");
    assert!(list[0]["dropped"].as_u64().unwrap() >= 2);
    let _ = scores;

    // The robot's connection breaks mid-stream: the resumable session waits for its
    // client, and a resume carries on where it stopped.
    proxy.abort();
    let _ = proxy.await;
    let mut detached = false;
    for _ in 0..100 {
        let s: serde_json::Value = http
            .get(&url)
            .bearer_auth(ADMIN)
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if s["sessions"][0]["state"] == "detached" {
            detached = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(detached, "the session was not kept for resumption");
    let rest: Vec<In> = good.collect();
    let (scores, events) = stream_all(addr, Some(ROBOT), open_msg("sim-arm", "held", None), rest)
        .await
        .unwrap();
    assert_eq!(events[0].kind, proto::session_event::Kind::Resumed as i32);
    assert!(!scores.is_empty());
    // Frame indices carry on from before the disconnect.
    assert!(scores[0].frame >= 2, "{}", scores[0].frame);
    assert_eq!(server.shared.hub.session_count(), 0);

    // A session that never sends its open message, and a stream whose first message is
    // not `open`.
    let err = stream_all(
        addr,
        Some(ROBOT),
        In::Phase(proto::PhaseMarker {
            stamp_ns: 0,
            phase: "release".into(),
        }),
        vec![],
    )
    .await
    .unwrap_err();
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    let mut counts = HashMap::new();
    for line in metrics_text(server.rest_addr)
        .await
        .lines()
        .filter(|l| l.starts_with("vamos_message_errors_total"))
    {
        let (k, v) = line.rsplit_once(' ').unwrap();
        counts.insert(k.to_string(), v.parse::<f64>().unwrap());
    }
    assert_eq!(
        counts["vamos_message_errors_total{kind=\"joints\",profile=\"sim-arm\"}"],
        1.0
    );
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_reflection_readiness_and_one_port() {
    let f = fixture_setup(4, false);
    let server = start(&f).await;
    assert_ne!(server.grpc_addr, server.rest_addr);
    let mut health = tonic_health::pb::health_client::HealthClient::new(
        tonic::transport::Endpoint::from_shared(format!("http://{}", server.grpc_addr))
            .unwrap()
            .connect()
            .await
            .unwrap(),
    );
    let r = health
        .check(tonic_health::pb::HealthCheckRequest {
            service: "vamos.v1.Monitor".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        r.status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
    // `vamos health` (the containers' health check) says the same, and exit code 1 for a
    // service the server does not have.
    let probe = |service: &'static str| {
        let url = format!("http://{}", server.grpc_addr);
        tokio::task::spawn_blocking(move || {
            std::process::Command::new(env!("CARGO_BIN_EXE_vamos"))
                .args(["health", "--server", &url, "--service", service])
                .output()
                .unwrap()
        })
    };
    let out = probe("vamos.v1.Monitor").await.unwrap();
    assert!(out.status.success(), "{out:?}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["status"], "SERVING");
    let out = probe("no.such.Service").await.unwrap();
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    // Server reflection, as grpcurl uses it: list the services, then fetch the file that
    // declares Monitor (v1 and v1alpha).
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{}", server.grpc_addr))
        .unwrap()
        .connect()
        .await
        .unwrap();
    {
        use tonic_reflection::pb::v1::{
            ServerReflectionRequest, server_reflection_client::ServerReflectionClient,
            server_reflection_request::MessageRequest, server_reflection_response::MessageResponse,
        };
        let mut client = ServerReflectionClient::new(channel.clone());
        let requests = [
            MessageRequest::ListServices(String::new()),
            MessageRequest::FileContainingSymbol("vamos.v1.Monitor".into()),
        ]
        .map(|m| ServerReflectionRequest {
            host: String::new(),
            message_request: Some(m),
        });
        let mut answers = client
            .server_reflection_info(tokio_stream::iter(requests))
            .await
            .unwrap()
            .into_inner();
        let Some(MessageResponse::ListServicesResponse(list)) =
            answers.next().await.unwrap().unwrap().message_response
        else {
            panic!("no service list");
        };
        let names: Vec<&str> = list.service.iter().map(|s| s.name.as_str()).collect();
        assert!(names.contains(&"vamos.v1.Monitor"), "{names:?}");
        assert!(names.contains(&"grpc.health.v1.Health"), "{names:?}");
        let Some(MessageResponse::FileDescriptorResponse(files)) =
            answers.next().await.unwrap().unwrap().message_response
        else {
            panic!("no file descriptor");
        };
        let fd = <prost_types::FileDescriptorProto as prost::Message>::decode(
            files.file_descriptor_proto[0].as_slice(),
        )
        .unwrap();
        assert_eq!(fd.package(), "vamos.v1");
        let methods: Vec<&str> = fd.service[0].method.iter().map(|m| m.name()).collect();
        assert_eq!(methods, ["Stream", "ScoreEpisode"]);
    }
    {
        use tonic_reflection::pb::v1alpha::{
            ServerReflectionRequest, server_reflection_client::ServerReflectionClient,
            server_reflection_request::MessageRequest, server_reflection_response::MessageResponse,
        };
        let mut client = ServerReflectionClient::new(channel);
        let mut answers = client
            .server_reflection_info(tokio_stream::iter([ServerReflectionRequest {
                host: String::new(),
                message_request: Some(MessageRequest::ListServices(String::new())),
            }]))
            .await
            .unwrap()
            .into_inner();
        let Some(MessageResponse::ListServicesResponse(list)) =
            answers.next().await.unwrap().unwrap().message_response
        else {
            panic!("no service list (v1alpha)");
        };
        assert!(list.service.iter().any(|s| s.name == "vamos.v1.Monitor"));
    }
    let ready = reqwest::get(format!("http://{}/readyz", server.rest_addr))
        .await
        .unwrap();
    assert_eq!(ready.status(), 200);
    let missing = reqwest::get(format!("http://{}/v2/models/nope/ready", server.rest_addr))
        .await
        .unwrap();
    assert_eq!(missing.status(), 404);
    server.shutdown().await.unwrap();

    // gRPC and REST on one port.
    let mut f = fixture_setup(4, false);
    f.settings.service.grpc_addr = "127.0.0.1:0".into();
    f.settings.service.rest_addr = f.settings.service.grpc_addr.clone();
    let catalog = ProfileCatalog::from_setups(vec![f.setup.clone()]);
    let server = Server::start(f.settings.clone(), catalog).await.unwrap();
    assert_eq!(server.grpc_addr, server.rest_addr);
    let body = reqwest::get(format!("http://{}/healthz", server.rest_addr))
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(body.contains("live"));
    let mut health = tonic_health::pb::health_client::HealthClient::new(
        tonic::transport::Endpoint::from_shared(format!("http://{}", server.grpc_addr))
            .unwrap()
            .connect()
            .await
            .unwrap(),
    );
    assert!(
        health
            .check(tonic_health::pb::HealthCheckRequest {
                service: String::new(),
            })
            .await
            .is_ok()
    );
    let unknown = reqwest::get(format!("http://{}/nope", server.rest_addr))
        .await
        .unwrap();
    assert_eq!(unknown.status(), 404);
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_on_both_transports_with_a_generated_certificate() {
    let mut f = fixture_setup(4, false);
    let cert = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (cert_path, key_path) = (dir.path().join("tls.crt"), dir.path().join("tls.key"));
    std::fs::write(&cert_path, cert.cert.pem()).unwrap();
    std::fs::write(&key_path, cert.signing_key.serialize_pem()).unwrap();
    f.settings.service.tls = Some(vamos::service::TlsConfig {
        cert: cert_path,
        key: key_path,
    });
    let server = start(&f).await;

    // gRPC over TLS: a session end to end.
    let tls = tonic::transport::ClientTlsConfig::new()
        .ca_certificate(tonic::transport::Certificate::from_pem(cert.cert.pem()))
        .domain_name("localhost");
    let channel = tonic::transport::Endpoint::from_shared(format!("https://{}", server.grpc_addr))
        .unwrap()
        .tls_config(tls)
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut client = MonitorClient::new(channel);
    let name = "test_0000";
    let (messages, camera) = episode_messages(&episode(name));
    let mut requests = vec![proto::StreamRequest {
        message: Some(open_msg("sim-arm", name, camera)),
    }];
    requests.extend(
        messages
            .into_iter()
            .map(|m| proto::StreamRequest { message: Some(m) }),
    );
    let mut inbound = client
        .stream(tokio_stream::iter(requests))
        .await
        .unwrap()
        .into_inner();
    let mut scores = Vec::new();
    while let Some(item) = inbound.next().await {
        if let Some(proto::stream_response::Message::Score(s)) = item.unwrap().message {
            scores.push(s);
        }
    }
    assert_same_scores(&scores, &offline(&f.setup, &episode(name)));

    // REST over TLS, trusting the generated certificate; plain HTTP is refused.
    let http = reqwest::Client::builder()
        .add_root_certificate(reqwest::Certificate::from_pem(cert.cert.pem().as_bytes()).unwrap())
        .resolve("localhost", server.rest_addr)
        .build()
        .unwrap();
    let r = http
        .get(format!(
            "https://localhost:{}/healthz",
            server.rest_addr.port()
        ))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert!(
        reqwest::get(format!("http://{}/healthz", server.rest_addr))
            .await
            .is_err()
    );
    // A client that does not trust the certificate fails the handshake.
    assert!(
        reqwest::get(format!(
            "https://localhost:{}/healthz",
            server.rest_addr.port()
        ))
        .await
        .is_err()
    );
    server.shutdown().await.unwrap();
}
