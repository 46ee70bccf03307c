//! A typed client of the `vamos.v1` gRPC API (tonic): open a session and stream images
//! and joint states while scores come back, replay a recorded episode as a live robot
//! (at its recorded rate or as fast as the server scores, never overrunning its queue),
//! and batch-score an MCAP episode.
//!
//! Used by `vamos demo`, `vamos stream` and `vamos loadgen`; the integration tests drive
//! the server through it too.

pub mod replay;

use futures_util::StreamExt;
use replay::Recording;
use std::collections::BTreeSet;
use std::path::Path;
use std::time::{Duration, Instant};
use tokio::io::AsyncReadExt;
use tokio_stream::wrappers::ReceiverStream;
use tonic::metadata::{Ascii, MetadataValue};
use tonic::transport::{Certificate, Channel, ClientTlsConfig, Endpoint};
use vamos_proto as proto;
use vamos_proto::monitor_client::MonitorClient;
use vamos_proto::{stream_request::Message as In, stream_response::Message as Out};

/// Why a client call failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The URL or a TLS setting is unusable.
    #[error("client configuration: {0}")]
    Config(String),
    /// No connection to the server.
    #[error("cannot connect to {url}: {reason}")]
    Connect {
        /// The server URL.
        url: String,
        /// The transport's message.
        reason: String,
    },
    /// The server ended the call with a status.
    #[error("server: {} ({:?})", .0.message(), .0.code())]
    Status(#[from] tonic::Status),
    /// A local file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The error.
        source: std::io::Error,
    },
    /// The request stream closed before every message was sent (the server ended the
    /// call; its status follows in the response stream).
    #[error("the server stopped reading the session's messages")]
    Closed,
}

impl ClientError {
    /// The server refused for capacity (`RESOURCE_EXHAUSTED`: its scoring capacity or a
    /// limit is in use); trying again later may succeed.
    pub fn is_over_capacity(&self) -> bool {
        matches!(self, ClientError::Status(s) if s.code() == tonic::Code::ResourceExhausted)
    }
}

/// How to reach the server.
#[derive(Debug, Clone, Default)]
pub struct ClientOptions {
    /// Bearer token (the `robot` or `admin` role), sent as `authorization` metadata.
    pub token: Option<String>,
    /// PEM of the CA that signed the server's certificate (`https://` URLs); absent: the
    /// platform's roots are not consulted, so `https://` needs it.
    pub ca_pem: Option<Vec<u8>>,
    /// Server name to check the certificate against (default: the URL's host).
    pub tls_domain: Option<String>,
    /// Largest message sent or received, bytes (default 64 MiB).
    pub max_message_bytes: Option<usize>,
    /// Connection timeout (default 10 s).
    pub connect_timeout: Option<Duration>,
}

/// A connected client. Cheap to clone: clones share the connection.
#[derive(Clone)]
pub struct Client {
    inner: MonitorClient<Channel>,
    channel: Channel,
    token: Option<MetadataValue<Ascii>>,
}

/// How fast a recording is replayed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pace {
    /// At the recorded timing divided by `speed` (1.0 = real time), as a robot would send.
    Recorded {
        /// Speed-up factor (> 0).
        speed: f64,
    },
    /// As fast as the server scores, with at most this many images sent and not yet
    /// answered (keep it below the server's queue depth and no image is dropped).
    Window(usize),
}

/// What a replay reports while it runs.
#[derive(Debug, Clone)]
pub enum Update {
    /// An image went out (its stamp).
    Sent {
        /// Image stamp, ns.
        stamp_ns: i64,
    },
    /// A frame's score came back.
    Score(proto::FrameScore),
    /// A session event came back.
    Event(proto::SessionEvent),
    /// An alarm started or ended (boxed: rare, and larger than a score).
    Alarm(Box<proto::AlarmEvent>),
}

/// The outcome of a replayed session.
#[derive(Debug, Clone, Default)]
pub struct SessionSummary {
    /// Images sent.
    pub images_sent: u64,
    /// Scores received, in order.
    pub scores: Vec<proto::FrameScore>,
    /// Images the server reported dropped under backpressure.
    pub dropped: u64,
    /// Single messages the server refused (the session went on), with why.
    pub message_errors: Vec<String>,
    /// The session id the server used.
    pub session_id: String,
    /// Wall time from the open message to the end of the response stream.
    pub elapsed: Duration,
}

impl Client {
    /// Connects to `url` (`http://host:port`, or `https://` with `ca_pem`).
    pub async fn connect(url: &str, options: ClientOptions) -> Result<Self, ClientError> {
        let mut endpoint = Endpoint::from_shared(url.to_string())
            .map_err(|e| ClientError::Config(format!("server URL {url:?}: {e}")))?
            .connect_timeout(options.connect_timeout.unwrap_or(Duration::from_secs(10)))
            .tcp_nodelay(true);
        if url.starts_with("https://") {
            let Some(ca) = &options.ca_pem else {
                return Err(ClientError::Config(
                    "an https:// server needs the CA certificate (PEM) that signed it".into(),
                ));
            };
            let mut tls = ClientTlsConfig::new().ca_certificate(Certificate::from_pem(ca));
            if let Some(d) = &options.tls_domain {
                tls = tls.domain_name(d.clone());
            }
            endpoint = endpoint
                .tls_config(tls)
                .map_err(|e| ClientError::Config(format!("TLS: {e}")))?;
        }
        let channel = endpoint.connect().await.map_err(|e| ClientError::Connect {
            url: url.to_string(),
            reason: error_chain(&e),
        })?;
        let limit = options.max_message_bytes.unwrap_or(64 << 20);
        let token = match &options.token {
            Some(t) => Some(
                MetadataValue::try_from(format!("Bearer {t}"))
                    .map_err(|_| ClientError::Config("the token has invalid characters".into()))?,
            ),
            None => None,
        };
        Ok(Self {
            inner: MonitorClient::new(channel.clone())
                .max_decoding_message_size(limit)
                .max_encoding_message_size(limit),
            channel,
            token,
        })
    }

    /// The serving status the server's standard gRPC health service reports for
    /// `service` (`""`: the whole server, `vamos.v1.Monitor`: the monitor), as its
    /// `grpc.health.v1` name (`SERVING`, `NOT_SERVING`, ...).
    pub async fn health(&self, service: &str) -> Result<String, ClientError> {
        use tonic_health::pb::HealthCheckRequest;
        use tonic_health::pb::health_client::HealthClient;
        let mut health = HealthClient::new(self.channel.clone());
        let answer = health
            .check(self.request(HealthCheckRequest {
                service: service.to_string(),
            }))
            .await?
            .into_inner();
        Ok(
            tonic_health::pb::health_check_response::ServingStatus::try_from(answer.status)
                .map_or_else(
                    |_| format!("UNKNOWN({})", answer.status),
                    |s| s.as_str_name().to_string(),
                ),
        )
    }

    fn request<T>(&self, body: T) -> tonic::Request<T> {
        let mut request = tonic::Request::new(body);
        if let Some(t) = &self.token {
            request.metadata_mut().insert("authorization", t.clone());
        }
        request
    }

    /// Opens a session; the returned handle sends messages and receives scores.
    pub async fn open(&self, open: proto::OpenSession) -> Result<Session, ClientError> {
        let (tx, rx) = tokio::sync::mpsc::channel(64);
        tx.send(proto::StreamRequest {
            message: Some(In::Open(open)),
        })
        .await
        .map_err(|_| ClientError::Closed)?;
        let mut inner = self.inner.clone();
        let inbound = inner
            .stream(self.request(ReceiverStream::new(rx)))
            .await?
            .into_inner();
        Ok(Session {
            tx: Some(tx),
            inbound,
        })
    }

    /// Streams `recording` as one session opened with `open` and collects every answer;
    /// `on_update` sees each image sent, score and event as it happens.
    pub async fn replay(
        &self,
        open: proto::OpenSession,
        recording: &Recording,
        pace: Pace,
        mut on_update: impl FnMut(&Update),
    ) -> Result<SessionSummary, ClientError> {
        if let Pace::Recorded { speed } = pace
            && !(speed.is_finite() && speed > 0.0)
        {
            return Err(ClientError::Config(format!(
                "replay speed must be positive, got {speed}"
            )));
        }
        let window = match pace {
            Pace::Window(n) => n.max(1),
            Pace::Recorded { .. } => usize::MAX,
        };
        // Paced by the recording: the server is told the rate, to admit the session by it.
        let mut open = open;
        if let (Pace::Recorded { speed }, Some(rate)) = (pace, recording.image_rate_hz())
            && open.image_rate_hz <= 0.0
        {
            open.image_rate_hz = rate * speed;
        }
        let started = Instant::now();
        let mut session = self.open(open).await?;
        let mut summary = SessionSummary::default();
        // Images sent and not yet answered (scored, refused or dropped), oldest first.
        let mut pending: BTreeSet<(u64, i64)> = BTreeSet::new();
        let mut next = 0usize;
        if recording.messages.is_empty() {
            // Nothing to send: end the request side now, or the server waits for more.
            session.finish();
        }
        let start = tokio::time::Instant::now();
        loop {
            let sendable = recording
                .messages
                .get(next)
                .filter(|(_, m)| !matches!(m, In::Image(_)) || pending.len() < window);
            let due = match (sendable, pace) {
                (Some((at, _)), Pace::Recorded { speed }) => start + at.div_f64(speed),
                _ => start,
            };
            tokio::select! {
                biased;
                answer = session.next() => match answer {
                    Some(Ok(Update::Score(s))) => {
                        if let Some(k) = pending.iter().find(|(_, st)| *st == s.stamp_ns).copied() {
                            pending.remove(&k);
                        }
                        let u = Update::Score(s);
                        on_update(&u);
                        if let Update::Score(s) = u {
                            summary.scores.push(s);
                        }
                    }
                    Some(Ok(Update::Event(e))) => {
                        use proto::session_event::Kind;
                        match Kind::try_from(e.kind) {
                            Ok(Kind::FramesDropped) => {
                                for _ in summary.dropped..e.count {
                                    pending.pop_first();
                                }
                                summary.dropped = summary.dropped.max(e.count);
                            }
                            Ok(Kind::MessageError) => {
                                if let Some(k) = pending.iter().find(|(_, st)| *st == e.stamp_ns).copied() {
                                    pending.remove(&k);
                                }
                                summary.message_errors.push(e.detail.clone());
                            }
                            Ok(Kind::Opened | Kind::Resumed) => summary.session_id = e.session_id.clone(),
                            _ => {}
                        }
                        on_update(&Update::Event(e));
                    }
                    Some(Ok(u @ Update::Alarm(_))) => on_update(&u),
                    Some(Ok(Update::Sent { .. })) => {}
                    Some(Err(e)) => return Err(e),
                    None => break,
                },
                _ = tokio::time::sleep_until(due), if sendable.is_some() => {
                    let Some((_, m)) = sendable else { continue };
                    if let In::Image(img) = m {
                        pending.insert((summary.images_sent, img.stamp_ns));
                        summary.images_sent += 1;
                        on_update(&Update::Sent { stamp_ns: img.stamp_ns });
                    }
                    session.send(m.clone()).await?;
                    next += 1;
                    if next == recording.messages.len() {
                        session.finish();
                    }
                }
            }
        }
        summary.elapsed = started.elapsed();
        Ok(summary)
    }

    /// Uploads the MCAP episode at `path` in chunks for scoring with `profile` and
    /// returns every frame's score (`on_score` sees each as it arrives).
    pub async fn score_episode(
        &self,
        path: &Path,
        profile: &str,
        mut on_score: impl FnMut(&proto::FrameScore),
    ) -> Result<Vec<proto::FrameScore>, ClientError> {
        const CHUNK: usize = 1 << 20;
        let io = |source| ClientError::Io {
            path: path.display().to_string(),
            source,
        };
        let mut file = tokio::fs::File::open(path).await.map_err(io)?;
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let (tx, rx) = tokio::sync::mpsc::channel(4);
        let profile = profile.to_string();
        let reader = tokio::spawn(async move {
            let mut first = true;
            loop {
                let mut buf = vec![0u8; CHUNK];
                let n = file.read(&mut buf).await?;
                if n == 0 {
                    return Ok::<(), std::io::Error>(());
                }
                buf.truncate(n);
                let chunk = proto::EpisodeChunk {
                    profile: if first {
                        profile.clone()
                    } else {
                        String::new()
                    },
                    name: if first { name.clone() } else { String::new() },
                    data: buf,
                };
                first = false;
                if tx.send(chunk).await.is_err() {
                    return Ok(());
                }
            }
        });
        let mut inner = self.inner.clone();
        let mut inbound = inner
            .score_episode(self.request(ReceiverStream::new(rx)))
            .await?
            .into_inner();
        let mut scores = Vec::new();
        while let Some(item) = inbound.next().await {
            let s = item?;
            on_score(&s);
            scores.push(s);
        }
        match reader.await {
            Ok(Ok(())) => Ok(scores),
            Ok(Err(e)) => Err(io(e)),
            Err(e) => Err(ClientError::Config(format!("reader task: {e}"))),
        }
    }
}

/// One open session: send messages, receive answers.
pub struct Session {
    tx: Option<tokio::sync::mpsc::Sender<proto::StreamRequest>>,
    inbound: tonic::Streaming<proto::StreamResponse>,
}

/// The sending side of a session ([`Session::take_sender`]); clones send on the same
/// stream.
#[derive(Clone)]
pub struct SessionSender(tokio::sync::mpsc::Sender<proto::StreamRequest>);

impl SessionSender {
    /// Sends one message (image, joint state or phase marker); waits while the stream's
    /// buffer is full.
    pub async fn send(&self, message: In) -> Result<(), ClientError> {
        self.0
            .send(proto::StreamRequest {
                message: Some(message),
            })
            .await
            .map_err(|_| ClientError::Closed)
    }
}

impl Session {
    /// Sends one message (image, joint state or phase marker).
    pub async fn send(&mut self, message: In) -> Result<(), ClientError> {
        let tx = self.tx.clone().ok_or(ClientError::Closed)?;
        SessionSender(tx).send(message).await
    }

    /// The request side as a handle of its own, for a task apart from the one reading
    /// the answers (this session's `send` fails from then on). The request stream ends
    /// when every clone of it is dropped.
    pub fn take_sender(&mut self) -> Option<SessionSender> {
        self.tx.take().map(SessionSender)
    }

    /// Ends the request side: the server scores what it has, then ends the stream.
    pub fn finish(&mut self) {
        self.tx = None;
    }

    /// The next score or event; `None` when the server ended the session cleanly.
    pub async fn next(&mut self) -> Option<Result<Update, ClientError>> {
        loop {
            return match self.inbound.next().await? {
                Ok(r) => match r.message {
                    Some(Out::Score(s)) => Some(Ok(Update::Score(s))),
                    Some(Out::Event(e)) => Some(Ok(Update::Event(e))),
                    Some(Out::Alarm(a)) => Some(Ok(Update::Alarm(Box::new(a)))),
                    None => continue,
                },
                Err(status) => Some(Err(ClientError::Status(status))),
            };
        }
    }
}

fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        text.push_str(": ");
        text.push_str(&s.to_string());
        source = s.source();
    }
    text
}
