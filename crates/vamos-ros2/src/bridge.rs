//! The bridge node: one robot's camera and joint states in from the ROS 2 graph, one vamos
//! session over gRPC, stamped scores and diagnostics back out to the graph.
//!
//! The session opens at the first image (the camera info, when it came first, goes with
//! it; joint states that came before are sent right after) and is opened again under the
//! same session id, which the server resumes, at the next image after the stream broke.
//! Subscriptions use the sensor-data QoS camera drivers publish with (best effort, keep
//! last): they match reliable publishers too, and a bridge that falls behind drops the
//! oldest images, never the newest. Scores, anomaly maps and diagnostics are published
//! reliable, keep last 10 (the ROS 2 default). Alarm events are published reliable and
//! transient-local, keep last 10: an alarm is two messages (start, end), rare next to the
//! scores, so a subscriber that joins late (an operator's console started after an
//! alarm) still gets the last five alarms' edges, and transient-local publishers match
//! volatile subscriptions too.
//!
//! Anomaly maps (`anomaly_maps`, off by default: they cost bandwidth) are asked of the
//! server only when on, and each is published as a `mono8` `sensor_msgs/Image` with the
//! scored image's header.
//!
//! With a depth topic, each colour image goes to the server with the depth image nearest
//! its stamp within `max_depth_gap_ms`, after waiting for it at most twice that gap
//! ([`crate::depth`] has the rules and bounds); without one, images go at once.

use crate::depth::DepthPairer;
use crate::msg::{self, types};
use crate::names::{self, NameError};
use crate::status::BridgeState;
use futures_util::stream::{self, BoxStream, StreamExt};
use ros2_client::{
    Context, ContextOptions, Name, Node, NodeName, NodeOptions, Publisher, QosProfile,
    Subscription,
    qos::{Durability, History},
};
use std::collections::{HashMap, VecDeque};
use std::future::Future;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use vamos_client::{Client, ClientError, ClientOptions, Session, SessionSender, Update};
use vamos_proto as proto;
use vamos_proto::stream_request::Message as In;

/// How the bridge joins the graph and reaches vamos.
#[derive(Debug, Clone)]
pub struct BridgeOptions {
    /// gRPC URL of `vamos serve`.
    pub server: String,
    /// Token and TLS settings of the connection.
    pub client: ClientOptions,
    /// The server's profile to score with.
    pub profile: String,
    /// DDS domain (`ROS_DOMAIN_ID`).
    pub domain_id: u16,
    /// The node's namespace (`/robot1`; empty for the root).
    pub namespace: String,
    /// The node's name.
    pub node_name: String,
    /// The robot's id in the session (default: from the namespace).
    pub robot_id: Option<String>,
    /// The session id (default: `ROBOT_ID-<random>`; a fixed one resumes after a
    /// restart within the server's idle timeout).
    pub session_id: Option<String>,
    /// Task label recorded with the session.
    pub task: String,
    /// Camera images (relative names resolve under the namespace).
    pub image_topic: String,
    /// `image_topic` carries `sensor_msgs/CompressedImage`.
    pub compressed: bool,
    /// `sensor_msgs/Image` depth images registered to the camera images (`16UC1` mm or
    /// `32FC1` m, e.g. a depth camera's `aligned_depth_to_color/image_raw`); `None` or
    /// empty: none (the default; never chosen automatically, as an unregistered depth
    /// image would misplace the scene).
    pub depth_topic: Option<String>,
    /// A camera image takes the depth image nearest its stamp if at most this far,
    /// milliseconds; it waits for one at most twice this long. Default 20 (the recorded
    /// path's `[episode] max_depth_gap_ms`).
    pub max_depth_gap_ms: f64,
    /// `sensor_msgs/CameraInfo` of the camera.
    pub camera_info_topic: String,
    /// `sensor_msgs/JointState` topics.
    pub joint_states_topics: Vec<String>,
    /// `vamos_msgs/FrameScore` output, stamped with the scored image's header.
    pub frame_score_topic: String,
    /// `std_msgs/Float64` score output.
    pub score_topic: String,
    /// `std_msgs/Bool` anomaly output.
    pub anomaly_topic: String,
    /// `vamos_msgs/AlarmEvent` output: each alarm's start and end.
    pub alarm_topic: String,
    /// Ask the server for each frame's anomaly map and publish it on
    /// `anomaly_map_topic` (off by default).
    pub anomaly_maps: bool,
    /// `sensor_msgs/Image` (`mono8`, 0 = nominal) output of the anomaly maps, stamped
    /// with the scored image's header.
    pub anomaly_map_topic: String,
    /// Period of `diagnostic_msgs/DiagnosticArray` on `/diagnostics`.
    pub diagnostics_period: Duration,
}

impl BridgeOptions {
    /// The defaults of the Python bridge's parameters (`clients/ros2/vamos_bridge`), for
    /// `profile` on `server`.
    pub fn new(server: &str, profile: &str) -> Self {
        Self {
            server: server.to_string(),
            client: ClientOptions::default(),
            profile: profile.to_string(),
            domain_id: 0,
            namespace: String::new(),
            node_name: "vamos_bridge".into(),
            robot_id: None,
            session_id: None,
            task: String::new(),
            image_topic: "camera/image_raw".into(),
            compressed: false,
            depth_topic: None,
            max_depth_gap_ms: 20.0,
            camera_info_topic: "camera/camera_info".into(),
            joint_states_topics: vec!["joint_states".into()],
            frame_score_topic: "vamos/frame_score".into(),
            score_topic: "vamos/score".into(),
            anomaly_topic: "vamos/anomaly".into(),
            alarm_topic: "vamos/alarm".into(),
            anomaly_maps: false,
            anomaly_map_topic: "vamos/anomaly_map".into(),
            diagnostics_period: Duration::from_secs(1),
        }
    }
}

/// Why the bridge could not run.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// A topic, namespace or node name rcl would refuse.
    #[error(transparent)]
    Name(#[from] NameError),
    /// An option the bridge cannot run with.
    #[error("{0}")]
    Options(String),
    /// The DDS participant, a topic, a reader or a writer could not be created.
    #[error("DDS: {0}")]
    Dds(String),
}

/// What a bridge did, when it stops.
#[derive(Debug, Clone, Default)]
pub struct BridgeReport {
    /// Images passed to the server.
    pub images_sent: u64,
    /// Scores published.
    pub scores_published: u64,
    /// Sessions opened again after their stream broke.
    pub reconnects: u64,
    /// Messages refused (by the bridge or the server).
    pub refused: u64,
    /// Images the server dropped under backpressure.
    pub dropped: u64,
    /// Alarm events (starts and ends) published.
    pub alarm_events_published: u64,
    /// Anomaly maps published.
    pub anomaly_maps_published: u64,
    /// The last session id.
    pub session_id: String,
}

/// The fully qualified names the bridge uses, by option.
#[derive(Debug, Clone)]
pub struct Resolved {
    /// `(option, fully qualified topic)`, sorted by option.
    pub topics: Vec<(String, String)>,
    /// The node's namespace, normalised (`""` or `/a/b`).
    pub namespace: String,
    /// The robot's id.
    pub robot_id: String,
    /// The session id.
    pub session_id: String,
}

impl BridgeOptions {
    /// Checks the options and resolves every name; `suffix` makes the default session id
    /// unique.
    pub fn resolve(&self, suffix: &str) -> Result<Resolved, BridgeError> {
        if self.profile.is_empty() {
            return Err(BridgeError::Options(
                "a profile is required (the server's profile to score with)".into(),
            ));
        }
        if self.joint_states_topics.is_empty() {
            return Err(BridgeError::Options(
                "at least one joint states topic is needed".into(),
            ));
        }
        if self.diagnostics_period.is_zero() {
            return Err(BridgeError::Options(
                "the diagnostics period must be > 0".into(),
            ));
        }
        if !(self.max_depth_gap_ms > 0.0 && self.max_depth_gap_ms <= Self::MAX_DEPTH_GAP_MS) {
            return Err(BridgeError::Options(format!(
                "the depth gap must be > 0 and at most {} ms, not {} ms",
                Self::MAX_DEPTH_GAP_MS,
                self.max_depth_gap_ms
            )));
        }
        names::check_node_name(&self.node_name)?;
        let namespace = names::normalise_namespace(&self.namespace)?;
        let resolve = |t: &str| names::resolve_topic(t, &namespace, &self.node_name);
        let mut topics = vec![
            ("alarm_topic".to_string(), resolve(&self.alarm_topic)?),
            ("anomaly_topic".to_string(), resolve(&self.anomaly_topic)?),
            (
                "camera_info_topic".to_string(),
                resolve(&self.camera_info_topic)?,
            ),
            (
                "frame_score_topic".to_string(),
                resolve(&self.frame_score_topic)?,
            ),
            ("image_topic".to_string(), resolve(&self.image_topic)?),
            ("score_topic".to_string(), resolve(&self.score_topic)?),
        ];
        if let Some(t) = self.depth_topic() {
            topics.push(("depth_topic".to_string(), resolve(t)?));
        }
        if self.anomaly_maps {
            topics.push((
                "anomaly_map_topic".to_string(),
                resolve(&self.anomaly_map_topic)?,
            ));
        }
        for (i, t) in self.joint_states_topics.iter().enumerate() {
            topics.push((format!("joint_states_topics[{i}]"), resolve(t)?));
        }
        topics.sort();
        let robot_id = match &self.robot_id {
            Some(id) if !id.is_empty() => id.clone(),
            _ => names::default_robot_id(&namespace, &self.node_name),
        };
        let session_id = match &self.session_id {
            Some(id) if !id.is_empty() => id.clone(),
            _ => format!("{robot_id}-{suffix}"),
        };
        Ok(Resolved {
            topics,
            namespace,
            robot_id,
            session_id,
        })
    }
}

impl BridgeOptions {
    /// The largest depth gap, ms: farther apart, a depth image is of another moment.
    pub const MAX_DEPTH_GAP_MS: f64 = 1000.0;

    /// The message that opens the session: anomaly maps are asked for only when they are
    /// published.
    pub fn open_session(
        &self,
        resolved: &Resolved,
        camera: Option<proto::CameraInfo>,
    ) -> proto::OpenSession {
        proto::OpenSession {
            robot_id: resolved.robot_id.clone(),
            profile: self.profile.clone(),
            camera_info: camera,
            task: self.task.clone(),
            session_id: resolved.session_id.clone(),
            anomaly_maps: self.anomaly_maps,
            image_rate_hz: 0.0,
        }
    }

    /// The depth topic, when one is set (an empty name is none).
    pub fn depth_topic(&self) -> Option<&str> {
        self.depth_topic.as_deref().filter(|t| !t.is_empty())
    }

    /// The pairing of camera and depth images, when a depth topic is set: the gap, and a
    /// hold of twice the gap.
    fn depth_pairer(&self) -> Option<DepthPairer> {
        self.depth_topic()?;
        let gap = Duration::from_secs_f64(self.max_depth_gap_ms * 1e-3);
        Some(DepthPairer::new(gap, 2 * gap))
    }
}

fn dds<E: std::fmt::Display>(what: &str) -> impl FnOnce(E) -> BridgeError + '_ {
    move |e| BridgeError::Dds(format!("{what}: {e}"))
}

/// A ROS 2 name of a fully qualified topic.
fn ros_name(fq: &str) -> Result<Name, BridgeError> {
    Name::parse(fq).map_err(dds(fq))
}

/// What arrives from the graph.
enum Incoming {
    Image(Result<proto::Image, msg::ConvertError>, String),
    /// A depth image and its stamp.
    Depth(i64, proto::DepthImage),
    Camera(Box<msg::CameraInfo>),
    Joints(msg::JointState),
    /// A sample the DDS reader could not deserialise (wrong type on the topic).
    Unreadable(String),
}

/// The scored images' `frame_id`s by stamp, so a score gets the frame of the image it
/// scored. Bounded: the oldest are forgotten first; a stamp not remembered gets the
/// latest frame id.
#[derive(Default)]
struct FrameIds {
    by_stamp: HashMap<i64, String>,
    order: VecDeque<i64>,
    latest: String,
    /// The frame id of the last score's image (an alarm event follows the score of the
    /// frame that started or ended it).
    last_scored: String,
}

impl FrameIds {
    const CAPACITY: usize = 256;

    fn remember(&mut self, stamp: i64, frame_id: String) {
        self.latest.clone_from(&frame_id);
        if self.by_stamp.insert(stamp, frame_id).is_none() {
            self.order.push_back(stamp);
        }
        while self.order.len() > Self::CAPACITY {
            if let Some(old) = self.order.pop_front() {
                self.by_stamp.remove(&old);
            }
        }
    }

    fn pop(&mut self, stamp: i64) -> String {
        let frame_id = self
            .by_stamp
            .remove(&stamp)
            .unwrap_or_else(|| self.latest.clone());
        self.last_scored.clone_from(&frame_id);
        frame_id
    }
}

/// The publishers of the bridge's outputs.
struct Outputs {
    frame_score: Publisher<msg::FrameScore>,
    score: Publisher<msg::Float64>,
    anomaly: Publisher<msg::Bool>,
    alarm: Publisher<msg::AlarmEvent>,
    anomaly_map: Option<Publisher<msg::Image>>,
    diagnostics: Publisher<msg::DiagnosticArray>,
}

/// What the bridge published, by kind.
#[derive(Default)]
struct Published {
    scores: u64,
    alarm_events: u64,
    anomaly_maps: u64,
}

/// An answer of the session numbered `.0`; `None`: its stream ended cleanly.
type Answer = (u64, Option<Result<Update, ClientError>>);

/// The session side of the bridge.
struct Link {
    options: BridgeOptions,
    resolved: Resolved,
    client: Option<Client>,
    sender: Option<SessionSender>,
    generation: u64,
    camera: Option<proto::CameraInfo>,
    early_joints: VecDeque<proto::JointState>,
    next_open: Instant,
    answers: mpsc::UnboundedSender<Answer>,
    state: BridgeState,
    /// Images sent in a row without depth.
    without_depth: u64,
}

impl Link {
    const EARLY_JOINTS: usize = 200;
    const REOPEN_AFTER: Duration = Duration::from_secs(1);
    /// Images in a row sent without depth (a depth topic set) before a warning.
    const WITHOUT_DEPTH_WARNING: u64 = 30;

    /// The open session's sender, opening one when there is none (at most once per
    /// [`Self::REOPEN_AFTER`]).
    async fn session(&mut self) -> Option<SessionSender> {
        if let Some(s) = &self.sender {
            return Some(s.clone());
        }
        if Instant::now() < self.next_open {
            return None;
        }
        match self.open().await {
            Ok(s) => Some(s),
            Err(e) => {
                self.state.connected = false;
                self.state.last_error = e.to_string();
                self.next_open = Instant::now() + Self::REOPEN_AFTER;
                tracing::warn!(
                    "cannot open the session: {e}; next try in {} s",
                    Self::REOPEN_AFTER.as_secs()
                );
                None
            }
        }
    }

    async fn open(&mut self) -> Result<SessionSender, ClientError> {
        let client = match &self.client {
            Some(c) => c.clone(),
            None => {
                let c = Client::connect(&self.options.server, self.options.client.clone()).await?;
                self.client = Some(c.clone());
                c
            }
        };
        let mut session: Session = client
            .open(self.options.open_session(&self.resolved, self.camera))
            .await?;
        let sender = session.take_sender().ok_or(ClientError::Closed)?;
        while let Some(j) = self.early_joints.pop_front() {
            sender.send(In::Joints(j)).await?;
        }
        self.generation += 1;
        let (generation, answers) = (self.generation, self.answers.clone());
        tokio::spawn(async move {
            loop {
                let answer = session.next().await;
                let end = !matches!(answer, Some(Ok(_)));
                if answers.send((generation, answer)).is_err() || end {
                    break;
                }
            }
        });
        self.sender = Some(sender.clone());
        Ok(sender)
    }

    /// The stream of the current session broke: the next image opens it again.
    fn lost(&mut self, why: String) {
        if self.sender.take().is_some() {
            self.state.reconnects += 1;
        }
        self.state.connected = false;
        tracing::warn!("stream ended: {why}; reconnecting at the next image");
        self.state.last_error = why;
    }

    async fn on_image(&mut self, image: proto::Image) {
        let Some(s) = self.session().await else {
            return;
        };
        let with_depth = image.depth.is_some();
        if let Err(e) = s.send(In::Image(image)).await {
            self.lost(e.to_string());
            return;
        }
        self.state.images_sent += 1;
        self.state.last_image = Some(Instant::now());
        if with_depth {
            self.state.images_with_depth += 1;
            self.without_depth = 0;
        } else if self.options.depth_topic().is_some() {
            self.without_depth += 1;
            if self.without_depth == Self::WITHOUT_DEPTH_WARNING {
                let topic = self
                    .resolved
                    .topics
                    .iter()
                    .find(|(k, _)| k == "depth_topic")
                    .map_or("the depth topic", |(_, v)| v.as_str());
                tracing::warn!(
                    "{} images in a row sent without a depth image: none on {topic} within {} ms \
                     of their stamps; the server uses the profile's assumed depth",
                    Self::WITHOUT_DEPTH_WARNING,
                    self.options.max_depth_gap_ms
                );
            }
        }
    }

    /// Images that went out of the depth pairing, to the session in order.
    async fn on_images(&mut self, images: Vec<proto::Image>) {
        for image in images {
            self.on_image(image).await;
        }
    }

    async fn on_joints(&mut self, joints: proto::JointState) {
        match &self.sender {
            Some(s) => {
                if let Err(e) = s.send(In::Joints(joints)).await {
                    self.lost(e.to_string());
                }
            }
            None => {
                if self.early_joints.len() == Self::EARLY_JOINTS {
                    self.early_joints.pop_front();
                }
                self.early_joints.push_back(joints);
            }
        }
    }
}

/// Runs the bridge until `shutdown` completes, then finishes the session (the server
/// scores what it holds) and publishes the last scores, waiting at most 10 s for them.
pub async fn run(
    options: BridgeOptions,
    shutdown: impl Future<Output = ()>,
) -> Result<BridgeReport, BridgeError> {
    let suffix = format!("{:08x}", fastrand::u32(..));
    let resolved = options.resolve(&suffix)?;
    let topic = |key: &str| -> &str {
        resolved
            .topics
            .iter()
            .find(|(k, _)| k == key)
            .map_or("", |(_, v)| v.as_str())
    };

    let context = Context::with_options(ContextOptions::new().domain_id(options.domain_id))
        .map_err(dds("the DDS participant"))?;
    let node_name = NodeName::new(
        if resolved.namespace.is_empty() {
            "/"
        } else {
            &resolved.namespace
        },
        &options.node_name,
    )
    .map_err(dds("the node name"))?;
    let mut node: Node = context
        .new_node(node_name, NodeOptions::new().enable_rosout(true))
        .map_err(dds("the node"))?;
    let fq_node = node.fully_qualified_name();

    let sensor = |depth| QosProfile::subscription_default().history(History::KeepLast { depth });
    let reliable = QosProfile::publisher_default().history(History::KeepLast { depth: 10 });
    let make_topic = |name: &str, ty, qos: &QosProfile| {
        node.create_topic(&ros_name(name)?, ty, qos)
            .map_err(dds(name))
    };
    let image_topic = make_topic(
        topic("image_topic"),
        if options.compressed {
            types::compressed_image()
        } else {
            types::image()
        },
        &sensor(5),
    )?;
    let depth_topic = match options.depth_topic() {
        Some(_) => Some(make_topic(
            topic("depth_topic"),
            types::image(),
            &sensor(5),
        )?),
        None => None,
    };
    let camera_topic = make_topic(topic("camera_info_topic"), types::camera_info(), &sensor(1))?;
    let joint_topics = (0..options.joint_states_topics.len())
        .map(|i| {
            make_topic(
                topic(&format!("joint_states_topics[{i}]")),
                types::joint_state(),
                &sensor(100),
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let frame_score_topic =
        make_topic(topic("frame_score_topic"), types::frame_score(), &reliable)?;
    let score_topic = make_topic(topic("score_topic"), types::float64(), &reliable)?;
    let anomaly_topic = make_topic(topic("anomaly_topic"), types::bool(), &reliable)?;
    let alarm_topic = make_topic(
        topic("alarm_topic"),
        types::alarm_event(),
        &reliable.clone().durability(Durability::TransientLocal),
    )?;
    let anomaly_map_topic = if options.anomaly_maps {
        Some(make_topic(
            topic("anomaly_map_topic"),
            types::image(),
            &reliable,
        )?)
    } else {
        None
    };
    let diagnostics_topic = make_topic("/diagnostics", types::diagnostic_array(), &reliable)?;

    let out = Outputs {
        frame_score: node
            .create_publisher(&frame_score_topic, None)
            .map_err(dds("publisher"))?,
        score: node
            .create_publisher(&score_topic, None)
            .map_err(dds("publisher"))?,
        anomaly: node
            .create_publisher(&anomaly_topic, None)
            .map_err(dds("publisher"))?,
        alarm: node
            .create_publisher(&alarm_topic, None)
            .map_err(dds("publisher"))?,
        anomaly_map: match &anomaly_map_topic {
            Some(t) => Some(node.create_publisher(t, None).map_err(dds("publisher"))?),
            None => None,
        },
        diagnostics: node
            .create_publisher(&diagnostics_topic, None)
            .map_err(dds("publisher"))?,
    };
    // Images of either type become one stream of `Incoming`.
    let raw_images: Option<Subscription<msg::Image>>;
    let compressed_images: Option<Subscription<msg::CompressedImage>>;
    if options.compressed {
        raw_images = None;
        compressed_images = Some(
            node.create_subscription(&image_topic, None)
                .map_err(dds("subscription"))?,
        );
    } else {
        raw_images = Some(
            node.create_subscription(&image_topic, None)
                .map_err(dds("subscription"))?,
        );
        compressed_images = None;
    }
    let depth_sub: Option<Subscription<msg::Image>> = match &depth_topic {
        Some(t) => Some(
            node.create_subscription(t, None)
                .map_err(dds("subscription"))?,
        ),
        None => None,
    };
    let camera_sub: Subscription<msg::CameraInfo> = node
        .create_subscription(&camera_topic, None)
        .map_err(dds("subscription"))?;
    let joint_subs = joint_topics
        .iter()
        .map(|t| node.create_subscription::<msg::JointState>(t, None))
        .collect::<Result<Vec<_>, _>>()
        .map_err(dds("subscription"))?;
    let spinner = node.spinner().map_err(dds("the node's spinner"))?;
    let spin = tokio::spawn(spinner.spin());

    let unreadable = |what: &'static str| {
        move |e: ros2_client::ReadError| Incoming::Unreadable(format!("{what}: {e}"))
    };
    let images: BoxStream<'_, Incoming> = match (&raw_images, &compressed_images) {
        (Some(s), _) => s
            .async_stream()
            .map(|r| match r {
                Ok((m, _)) => {
                    let frame = m.header.frame_id.clone();
                    Incoming::Image(Ok(m.into()), frame)
                }
                Err(e) => unreadable("image")(e),
            })
            .boxed(),
        (None, Some(s)) => s
            .async_stream()
            .map(|r| match r {
                Ok((m, _)) => {
                    let frame = m.header.frame_id.clone();
                    Incoming::Image(m.try_into(), frame)
                }
                Err(e) => unreadable("image")(e),
            })
            .boxed(),
        (None, None) => stream::pending().boxed(),
    };
    let depths: BoxStream<'_, Incoming> = match &depth_sub {
        Some(s) => s
            .async_stream()
            .map(|r| match r {
                Ok((m, _)) => {
                    let (stamp, depth) = m.into_depth();
                    Incoming::Depth(stamp, depth)
                }
                Err(e) => unreadable("depth image")(e),
            })
            .boxed(),
        None => stream::pending().boxed(),
    };
    let cameras = camera_sub.async_stream().map(|r| match r {
        Ok((m, _)) => Incoming::Camera(Box::new(m)),
        Err(e) => unreadable("camera info")(e),
    });
    let joints = stream::select_all(joint_subs.iter().map(|s| {
        s.async_stream()
            .map(|r| match r {
                Ok((m, _)) => Incoming::Joints(m),
                Err(e) => unreadable("joint state")(e),
            })
            .boxed()
    }));
    let mut incoming = stream::select(
        stream::select(stream::select(images, depths), cameras.boxed()),
        joints,
    );

    let (answers_tx, mut answers) = mpsc::unbounded_channel::<Answer>();
    let mut link = Link {
        options: options.clone(),
        resolved: resolved.clone(),
        client: None,
        sender: None,
        generation: 0,
        camera: None,
        early_joints: VecDeque::new(),
        next_open: Instant::now(),
        answers: answers_tx,
        state: BridgeState::default(),
        without_depth: 0,
    };
    let mut pairer = options.depth_pairer();
    let mut frame_ids = FrameIds::default();
    let mut published = Published::default();
    let mut diagnostics = tokio::time::interval(options.diagnostics_period);
    diagnostics.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    tracing::info!(
        "vamos bridge {fq_node}: streaming {}{} and {} to {} as robot {} (profile {}, session {})",
        topic("image_topic"),
        match options.depth_topic() {
            Some(_) => format!(
                " with depth from {} (within {} ms)",
                topic("depth_topic"),
                options.max_depth_gap_ms
            ),
            None => String::new(),
        },
        resolved
            .topics
            .iter()
            .filter(|(k, _)| k.starts_with("joint_states"))
            .map(|(_, v)| v.as_str())
            .collect::<Vec<_>>()
            .join(", "),
        options.server,
        resolved.robot_id,
        options.profile,
        resolved.session_id,
    );

    let publish_answer =
        |link: &mut Link, frame_ids: &mut FrameIds, published: &mut Published, answer: Answer| {
            let (generation, answer) = answer;
            match answer {
                Some(Ok(Update::Score(s))) => {
                    link.state.on_score(&s, Instant::now());
                    let frame_id = frame_ids.pop(s.stamp_ns);
                    match msg::FrameScore::from_proto(&s, frame_id, &link.state.session_id) {
                        Some(m) => {
                            let (score, anomaly) = (m.score, m.anomaly);
                            if let Some(maps) = &out.anomaly_map
                                && !s.anomaly_map.is_empty()
                            {
                                match msg::Image::anomaly_map(&s.anomaly_map, m.header.clone()) {
                                    Ok(map) => match maps.publish(map) {
                                        Ok(()) => published.anomaly_maps += 1,
                                        Err(e) => tracing::warn!("publishing an anomaly map: {e}"),
                                    },
                                    Err(e) => tracing::warn!("{e}"),
                                }
                            }
                            let results = [
                                out.frame_score.publish(m).err().map(|e| e.to_string()),
                                out.score
                                    .publish(msg::Float64 { data: score })
                                    .err()
                                    .map(|e| e.to_string()),
                                out.anomaly
                                    .publish(msg::Bool { data: anomaly })
                                    .err()
                                    .map(|e| e.to_string()),
                            ];
                            if let Some(e) = results.into_iter().flatten().next() {
                                tracing::warn!("publishing a score: {e}");
                            } else {
                                published.scores += 1;
                            }
                        }
                        None => tracing::warn!(
                            "score of stamp {} ns not published: outside ROS time",
                            s.stamp_ns
                        ),
                    }
                }
                Some(Ok(Update::Event(e))) => {
                    link.state.on_event(&e);
                    if e.kind() == proto::session_event::Kind::MessageError {
                        tracing::warn!("vamos refused a message: {}", e.detail);
                    }
                }
                Some(Ok(Update::Alarm(a))) => {
                    let frame_id = frame_ids.last_scored.clone();
                    match msg::AlarmEvent::from_proto(&a, frame_id, &link.resolved.robot_id) {
                        Some(m) => {
                            tracing::info!(
                                "alarm {} {} (detector {:?}, start frame {})",
                                m.alarm_id,
                                if m.edge == msg::AlarmEvent::STARTED {
                                    "started"
                                } else {
                                    "ended"
                                },
                                m.detector,
                                m.start_frame
                            );
                            match out.alarm.publish(m) {
                                Ok(()) => published.alarm_events += 1,
                                Err(e) => tracing::warn!("publishing an alarm event: {e}"),
                            }
                        }
                        None => tracing::warn!(
                            "alarm event {} not published: no edge, or a stamp outside ROS time",
                            a.alarm_id
                        ),
                    }
                }
                Some(Ok(Update::Sent { .. })) => {}
                Some(Err(e)) if generation == link.generation => link.lost(e.to_string()),
                None if generation == link.generation => {
                    link.lost("the server ended the session".into())
                }
                _ => {}
            }
        };
    let publish_diagnostics = |link: &Link| {
        let (level, message, values) = link
            .state
            .diagnostic(Instant::now(), Duration::from_secs(5));
        let values: Vec<msg::KeyValue> = [
            ("robot_id".to_string(), link.resolved.robot_id.clone()),
            ("profile".to_string(), link.options.profile.clone()),
        ]
        .into_iter()
        .chain(values)
        .chain(link.resolved.topics.iter().cloned())
        .map(|(key, value)| msg::KeyValue { key, value })
        .collect();
        let array = msg::DiagnosticArray {
            header: msg::Header {
                stamp: msg::Time::now(),
                frame_id: String::new(),
            },
            status: vec![msg::DiagnosticStatus {
                level: level as u8,
                name: format!("vamos: {fq_node}"),
                message,
                hardware_id: link.resolved.robot_id.clone(),
                values,
            }],
        };
        if let Err(e) = out.diagnostics.publish(array) {
            tracing::warn!("publishing diagnostics: {e}");
        }
    };

    tokio::pin!(shutdown);
    loop {
        // The oldest image waiting for its depth image goes when its hold ends.
        let hold_ends = pairer.as_ref().and_then(DepthPairer::deadline);
        tokio::select! {
            biased;
            () = &mut shutdown => break,
            Some(answer) = answers.recv() => {
                publish_answer(&mut link, &mut frame_ids, &mut published, answer);
            }
            _ = diagnostics.tick() => {
                publish_diagnostics(&link);
            }
            () = tokio::time::sleep_until(
                hold_ends.map_or_else(tokio::time::Instant::now, tokio::time::Instant::from_std)
            ), if hold_ends.is_some() => {
                if let Some(p) = pairer.as_mut() {
                    link.on_images(p.release_due(Instant::now())).await;
                }
            }
            Some(item) = incoming.next() => match item {
                Incoming::Image(Ok(image), frame_id) => {
                    frame_ids.remember(image.stamp_ns, frame_id);
                    match pairer.as_mut() {
                        Some(p) => link.on_images(p.push_image(image, Instant::now())).await,
                        None => link.on_image(image).await,
                    }
                }
                Incoming::Depth(stamp, depth) => {
                    if let Some(p) = pairer.as_mut() {
                        link.on_images(p.push_depth(stamp, depth, Instant::now())).await;
                    }
                }
                Incoming::Image(Err(e), _) => {
                    link.state.refused += 1;
                    tracing::warn!("image ignored: {e}");
                }
                Incoming::Camera(info) => {
                    if link.camera.is_none() {
                        match proto::CameraInfo::try_from(&*info) {
                            Ok(c) => link.camera = Some(c),
                            Err(e) => tracing::warn!("camera info ignored: {e}"),
                        }
                    }
                }
                Incoming::Joints(j) => link.on_joints(j.into()).await,
                Incoming::Unreadable(why) => {
                    link.state.refused += 1;
                    tracing::warn!("unreadable sample: {why}");
                }
            },
        }
    }

    // The images still waiting for depth go with what depth there is.
    if let Some(p) = pairer.as_mut() {
        let waiting = p.drain();
        if !waiting.is_empty() && link.sender.is_some() {
            link.on_images(waiting).await;
        }
    }
    // Finish: the server scores what it holds; its last scores are still published.
    let had_session = link.sender.take().is_some();
    if had_session {
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        let current = link.generation;
        while let Ok(Some(answer)) = tokio::time::timeout_at(deadline, answers.recv()).await {
            let ended = answer.0 == current && !matches!(answer.1, Some(Ok(_)));
            publish_answer(&mut link, &mut frame_ids, &mut published, answer);
            if ended {
                break;
            }
        }
    }
    link.state.connected = false;
    publish_diagnostics(&link);
    node.stop_spinner();
    spin.abort();
    Ok(BridgeReport {
        images_sent: link.state.images_sent,
        scores_published: published.scores,
        reconnects: link.state.reconnects,
        refused: link.state.refused,
        dropped: link.state.dropped,
        alarm_events_published: published.alarm_events,
        anomaly_maps_published: published.anomaly_maps,
        session_id: link.state.session_id,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_resolve_under_the_namespace_with_the_robot_and_session_ids() {
        let mut o = BridgeOptions::new("http://127.0.0.1:8081", "arm");
        o.namespace = "robot1".into();
        o.joint_states_topics = vec!["joint_states".into(), "/gripper/joint_states".into()];
        let r = o.resolve("abcd").unwrap();
        assert_eq!(
            (r.robot_id.as_str(), r.session_id.as_str()),
            ("robot1", "robot1-abcd")
        );
        let get = |k: &str| r.topics.iter().find(|(key, _)| key == k).unwrap().1.clone();
        assert_eq!(get("image_topic"), "/robot1/camera/image_raw");
        assert_eq!(get("frame_score_topic"), "/robot1/vamos/frame_score");
        assert_eq!(get("joint_states_topics[1]"), "/gripper/joint_states");
        assert_eq!(get("alarm_topic"), "/robot1/vamos/alarm");
        assert!(
            r.topics.iter().all(|(k, _)| k != "anomaly_map_topic"),
            "no map topic unless maps are asked for"
        );
        o.anomaly_maps = true;
        let r = o.resolve("abcd").unwrap();
        let get = |k: &str| r.topics.iter().find(|(key, _)| key == k).unwrap().1.clone();
        assert_eq!(get("anomaly_map_topic"), "/robot1/vamos/anomaly_map");
        o.anomaly_map_topic = "vamos//map".into();
        assert!(matches!(o.resolve("x"), Err(BridgeError::Name(_))));
        o.anomaly_map_topic = "vamos/anomaly_map".into();
        o.profile.clear();
        assert!(o.resolve("x").unwrap_err().to_string().contains("profile"));
        let mut o = BridgeOptions::new("http://h", "arm");
        o.image_topic = "cam//img".into();
        assert!(matches!(o.resolve("x"), Err(BridgeError::Name(_))));
    }

    #[test]
    fn a_depth_topic_is_off_by_default_and_resolved_when_set() {
        let mut o = BridgeOptions::new("http://h", "arm");
        o.namespace = "/robot1".into();
        let has_depth = |o: &BridgeOptions| {
            o.resolve("x")
                .unwrap()
                .topics
                .into_iter()
                .find(|(k, _)| k == "depth_topic")
        };
        assert_eq!(has_depth(&o), None);
        assert!(o.depth_pairer().is_none());
        o.depth_topic = Some(String::new());
        assert_eq!(has_depth(&o), None, "empty is off");
        o.depth_topic = Some("camera/aligned_depth_to_color/image_raw".into());
        assert_eq!(
            has_depth(&o),
            Some((
                "depth_topic".into(),
                "/robot1/camera/aligned_depth_to_color/image_raw".into()
            ))
        );
        assert!(o.depth_pairer().is_some());
        let keys: Vec<String> = o
            .resolve("x")
            .unwrap()
            .topics
            .into_iter()
            .map(|t| t.0)
            .collect();
        assert!(keys.is_sorted(), "{keys:?}");
        o.depth_topic = Some("depth//image".into());
        assert!(matches!(o.resolve("x"), Err(BridgeError::Name(_))));
        o.depth_topic = Some("/depth".into());
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY, 1000.5] {
            o.max_depth_gap_ms = bad;
            assert!(
                o.resolve("x")
                    .unwrap_err()
                    .to_string()
                    .contains("depth gap"),
                "{bad}"
            );
        }
    }

    #[test]
    fn anomaly_maps_are_asked_of_the_server_only_when_published() {
        let mut o = BridgeOptions::new("http://h", "arm");
        o.namespace = "/robot1".into();
        o.task = "pick".into();
        let r = o.resolve("abcd").unwrap();
        let open = o.open_session(&r, None);
        assert!(!open.anomaly_maps, "off by default");
        assert_eq!(
            (
                open.robot_id.as_str(),
                open.session_id.as_str(),
                open.profile.as_str(),
                open.task.as_str()
            ),
            ("robot1", "robot1-abcd", "arm", "pick")
        );
        o.anomaly_maps = true;
        let r = o.resolve("abcd").unwrap();
        assert!(o.open_session(&r, None).anomaly_maps);
    }

    #[test]
    fn frame_ids_are_kept_by_stamp_and_bounded() {
        let mut f = FrameIds::default();
        for i in 0..300 {
            f.remember(i, format!("f{i}"));
        }
        assert_eq!(f.by_stamp.len(), FrameIds::CAPACITY);
        assert_eq!(f.pop(299), "f299");
        assert_eq!(f.pop(10), "f299", "forgotten stamps get the latest frame");
        assert_eq!(f.pop(100), "f100");
        assert_eq!(
            f.last_scored, "f100",
            "an alarm event takes the last score's frame"
        );
    }
}
