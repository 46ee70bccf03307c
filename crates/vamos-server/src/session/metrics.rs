//! Prometheus metrics of the service. Labels are bounded: profile, model, stage,
//! detector, reason; never session or robot ids. Model versions come and go with every
//! upload, so the inference histogram keeps the [`MODEL_SERIES`] most recently used ones.

use prometheus::{
    Encoder, Gauge, GaugeVec, HistogramOpts, HistogramVec, IntCounter, IntCounterVec, IntGauge,
    IntGaugeVec, Opts, Registry, TextEncoder,
};

/// Latency buckets, seconds: 1 ms .. 5 s.
const LATENCY_BUCKETS: &[f64] = &[
    0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.075, 0.1, 0.15, 0.25, 0.5, 1.0, 2.5, 5.0,
];

/// Request durations, seconds: 1 ms .. 1 h (a gRPC stream lasts as long as its session).
const REQUEST_BUCKETS: &[f64] = &[
    0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0,
    300.0, 900.0, 3600.0,
];

/// Model versions (`name@version`) the inference histogram keeps series for; the least
/// recently first used beyond them is removed.
pub const MODEL_SERIES: usize = 16;

/// The service's metrics, registered in their own registry.
#[derive(Clone)]
pub struct Metrics {
    registry: Registry,
    /// Frames scored, by profile.
    pub frames: IntCounterVec,
    /// Frames with the anomaly flag, by profile and detector.
    pub anomalies: IntCounterVec,
    /// Alarms started (debounced), by profile and the detector that fired first.
    pub alarms: IntCounterVec,
    /// Images not scored, by profile and reason (`queue_full`, `rejected`,
    /// `bad_message`, `undelivered`).
    pub drops: IntCounterVec,
    /// Single messages refused without ending their session, by profile and kind.
    pub message_errors: IntCounterVec,
    /// Time per pipeline stage, seconds, by stage.
    pub stage_seconds: HistogramVec,
    /// Image arrival to score sent, seconds, by profile.
    pub latency_seconds: HistogramVec,
    /// Flow-predictor inference time per frame, seconds, by model (see
    /// [`Self::observe_inference`]).
    inference_seconds: HistogramVec,
    /// The model labels `inference_seconds` has series for, oldest first.
    inference_models: std::sync::Arc<std::sync::RwLock<std::collections::VecDeque<String>>>,
    /// Open sessions, by profile.
    pub sessions_active: IntGaugeVec,
    /// Sessions opened, by profile and outcome of the open (`ok`, `refused`).
    pub sessions_opened: IntCounterVec,
    /// Images waiting in session queues, all sessions.
    pub queue_depth: IntGauge,
    /// Build information (value 1).
    pub build_info: GaugeVec,
    /// The shared store's generation published (writer) or applied (reader); 0 without.
    pub shared_store_generation: IntGauge,
    /// Failed rounds with the shared store.
    pub shared_store_errors: IntCounter,
    /// Last successful round with the shared store, seconds since the Unix epoch.
    pub shared_store_last_sync: Gauge,
    /// Scoring workers running (health and readiness fail at 0).
    pub workers_alive: IntGauge,
    /// The cores live sessions may load (`[service] admission_load` of the workers).
    pub capacity_cores: Gauge,
    /// The live sessions' measured load, cores (see [`super::capacity`]).
    pub load_cores: Gauge,
    /// Scoring workers restarted after a panic outside a frame.
    pub worker_restarts: IntCounter,
    /// Frames whose scoring panicked (reported to the session as failed), by profile.
    pub scoring_panics: IntCounterVec,
    /// Bytes held for sessions under the server's memory budget (buffered images and
    /// joint states, images being decoded).
    pub memory_budget_used: IntGauge,
    /// Temporary disk held by uploads in progress, bytes.
    pub upload_disk_used: IntGauge,
    /// Uploads and episode-scoring requests refused before their body was read, by
    /// reason (`busy`, `disk`, `sessions`).
    pub uploads_refused: IntCounterVec,
    /// Connections open, both listeners.
    pub connections_open: IntGauge,
    /// Connections closed at once, by reason: `cap` (the server's connection cap) or
    /// `address` (the cap of one client address).
    pub connections_refused: IntCounterVec,
    /// Connections the server closed, by reason: `idle` (no request in flight for the
    /// idle time; keep-alive pings do not count), `evicted` (an idle one that made room
    /// for a newcomer at the cap) or `stalled` (a request body that sent nothing for the
    /// body timeout: the request fails, and on HTTP/1 its connection).
    pub connections_closed: IntCounterVec,
    /// HTTP requests answered, by method, route (the path template, `unmatched` for
    /// unknown paths) and status code.
    pub http_requests: IntCounterVec,
    /// HTTP request to end of response body, seconds, by method and route.
    pub http_request_seconds: HistogramVec,
    /// gRPC calls ended, by method (`/package.Service/Method`, `unmatched` for unknown
    /// ones) and status code name (`Ok`, `Unavailable`, ...; `Cancelled` when the client
    /// went away before the status).
    pub grpc_requests: IntCounterVec,
    /// gRPC call start to its status, seconds, by method.
    pub grpc_request_seconds: HistogramVec,
}

fn must<T>(r: prometheus::Result<T>) -> T {
    // Metric definitions are constants of this file: an error is a bug caught by the
    // tests, not a run-time condition.
    match r {
        Ok(v) => v,
        Err(e) => panic!("metric definition: {e}"),
    }
}

impl Metrics {
    /// Creates and registers every metric.
    #[allow(clippy::new_without_default)]
    pub fn new() -> Self {
        let registry = Registry::new();
        let counter = |name: &str, help: &str, labels: &[&str]| {
            let c = must(IntCounterVec::new(Opts::new(name, help), labels));
            must(registry.register(Box::new(c.clone())));
            c
        };
        let histogram = |name: &str, help: &str, labels: &[&str]| {
            let h = must(HistogramVec::new(
                HistogramOpts::new(name, help).buckets(LATENCY_BUCKETS.to_vec()),
                labels,
            ));
            must(registry.register(Box::new(h.clone())));
            h
        };
        let frames = counter(
            "vamos_frames_processed_total",
            "Frames scored",
            &["profile"],
        );
        let anomalies = counter(
            "vamos_anomalies_total",
            "Frames flagged anomalous",
            &["profile", "detector"],
        );
        let alarms = counter(
            "vamos_alarms_total",
            "Alarms started (debounced k of n frames)",
            &["profile", "detector"],
        );
        let drops = counter(
            "vamos_frames_dropped_total",
            "Images not scored",
            &["profile", "reason"],
        );
        let message_errors = counter(
            "vamos_message_errors_total",
            "Messages refused without ending their session",
            &["profile", "kind"],
        );
        let stage_seconds = histogram("vamos_stage_seconds", "Time per pipeline stage", &["stage"]);
        let latency_seconds = histogram(
            "vamos_score_latency_seconds",
            "Image arrival to score sent",
            &["profile"],
        );
        let inference_seconds = histogram(
            "vamos_model_inference_seconds",
            "Flow-predictor inference per frame",
            &["model"],
        );
        let sessions_active = must(IntGaugeVec::new(
            Opts::new("vamos_sessions_active", "Open sessions"),
            &["profile"],
        ));
        must(registry.register(Box::new(sessions_active.clone())));
        let sessions_opened = counter(
            "vamos_sessions_opened_total",
            "Session opens",
            &["profile", "outcome"],
        );
        let queue_depth = must(IntGauge::new(
            "vamos_queue_depth",
            "Images waiting in session queues",
        ));
        must(registry.register(Box::new(queue_depth.clone())));
        let build_info = must(GaugeVec::new(
            Opts::new("vamos_build_info", "Build information"),
            &["version"],
        ));
        must(registry.register(Box::new(build_info.clone())));
        build_info
            .with_label_values(&[env!("CARGO_PKG_VERSION")])
            .set(1.0);
        let shared_store_generation = must(IntGauge::new(
            "vamos_shared_store_generation",
            "Shared-store generation published or applied (0: none)",
        ));
        must(registry.register(Box::new(shared_store_generation.clone())));
        let shared_store_errors = must(IntCounter::new(
            "vamos_shared_store_errors_total",
            "Failed rounds with the shared store",
        ));
        must(registry.register(Box::new(shared_store_errors.clone())));
        let shared_store_last_sync = must(Gauge::new(
            "vamos_shared_store_last_sync_timestamp_seconds",
            "Last successful round with the shared store (Unix time; 0: never)",
        ));
        must(registry.register(Box::new(shared_store_last_sync.clone())));
        let float_gauge = |name: &str, help: &str| {
            let g = must(Gauge::new(name, help));
            must(registry.register(Box::new(g.clone())));
            g
        };
        let capacity_cores = float_gauge(
            "vamos_capacity_cores",
            "Cores live sessions may load ([service] admission_load of the scoring workers)",
        );
        let load_cores = float_gauge(
            "vamos_load_cores",
            "Live sessions' measured load: worker time per frame over time between images, summed",
        );
        let gauge = |name: &str, help: &str| {
            let g = must(IntGauge::new(name, help));
            must(registry.register(Box::new(g.clone())));
            g
        };
        let workers_alive = gauge("vamos_workers_alive", "Scoring workers running");
        let worker_restarts = must(IntCounter::new(
            "vamos_worker_restarts_total",
            "Scoring workers restarted after a panic",
        ));
        must(registry.register(Box::new(worker_restarts.clone())));
        let scoring_panics = counter(
            "vamos_scoring_panics_total",
            "Frames whose scoring panicked (reported to their session as failed)",
            &["profile"],
        );
        let memory_budget_used = gauge(
            "vamos_memory_budget_used_bytes",
            "Bytes held under the server's memory budget",
        );
        let upload_disk_used = gauge(
            "vamos_upload_disk_used_bytes",
            "Temporary disk held by uploads in progress",
        );
        let uploads_refused = counter(
            "vamos_uploads_refused_total",
            "Uploads refused before their body was read",
            &["reason"],
        );
        let connections_open = gauge("vamos_connections_open", "Connections open");
        let connections_refused = counter(
            "vamos_connections_refused_total",
            "Connections closed at once, by reason: the server's cap or one address's cap",
            &["reason"],
        );
        let connections_closed = counter(
            "vamos_connections_closed_total",
            "Connections closed by the server: idle past the idle time, evicted for a newcomer at the cap, or a request body stalled (the request fails)",
            &["reason"],
        );
        let request_histogram = |name: &str, help: &str, labels: &[&str]| {
            let h = must(HistogramVec::new(
                HistogramOpts::new(name, help).buckets(REQUEST_BUCKETS.to_vec()),
                labels,
            ));
            must(registry.register(Box::new(h.clone())));
            h
        };
        let http_requests = counter(
            "vamos_http_requests_total",
            "HTTP requests answered",
            &["method", "route", "status"],
        );
        let http_request_seconds = request_histogram(
            "vamos_http_request_duration_seconds",
            "HTTP request to end of response",
            &["method", "route"],
        );
        let grpc_requests = counter(
            "vamos_grpc_requests_total",
            "gRPC calls ended",
            &["method", "code"],
        );
        let grpc_request_seconds = request_histogram(
            "vamos_grpc_request_duration_seconds",
            "gRPC call start to its status",
            &["method"],
        );
        // process_cpu_seconds_total, process_resident_memory_bytes, ... (Linux).
        #[cfg(target_os = "linux")]
        must(registry.register(Box::new(
            prometheus::process_collector::ProcessCollector::for_self(),
        )));
        Self {
            registry,
            frames,
            anomalies,
            alarms,
            drops,
            message_errors,
            stage_seconds,
            latency_seconds,
            inference_seconds,
            inference_models: Default::default(),
            sessions_active,
            sessions_opened,
            queue_depth,
            build_info,
            shared_store_generation,
            shared_store_errors,
            shared_store_last_sync,
            workers_alive,
            capacity_cores,
            load_cores,
            worker_restarts,
            scoring_panics,
            memory_budget_used,
            upload_disk_used,
            uploads_refused,
            connections_open,
            connections_refused,
            connections_closed,
            http_requests,
            http_request_seconds,
            grpc_requests,
            grpc_request_seconds,
        }
    }

    /// Records one inference of `model` (`name@version`): the series of a model label
    /// not seen among the last [`MODEL_SERIES`] replaces the oldest one's.
    pub fn observe_inference(&self, model: &str, seconds: f64) {
        // Every frame reads; only a model label not seen before writes.
        let known = self
            .inference_models
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .iter()
            .any(|m| m == model);
        if !known {
            let mut models = self
                .inference_models
                .write()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            if !models.iter().any(|m| m == model) {
                models.push_back(model.to_string());
                while models.len() > MODEL_SERIES {
                    if let Some(old) = models.pop_front() {
                        let _ = self.inference_seconds.remove_label_values(&[&old]);
                    }
                }
            }
        }
        self.inference_seconds
            .with_label_values(&[model])
            .observe(seconds);
    }

    /// The text exposition format (`text/plain; version=0.0.4`).
    pub fn render(&self) -> String {
        let mut buf = Vec::new();
        if let Err(e) = TextEncoder::new().encode(&self.registry.gather(), &mut buf) {
            tracing::error!("metrics encoding failed: {e}");
        }
        String::from_utf8(buf).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exposition_has_the_metrics_and_their_labels() {
        let m = Metrics::new();
        m.frames.with_label_values(&["arm"]).inc_by(3);
        m.stage_seconds.with_label_values(&["flow"]).observe(0.02);
        m.drops.with_label_values(&["arm", "queue_full"]).inc();
        let text = m.render();
        assert!(
            text.contains("vamos_frames_processed_total{profile=\"arm\"} 3"),
            "{text}"
        );
        assert!(text.contains("vamos_stage_seconds_bucket{stage=\"flow\",le=\"0.025\"} 1"));
        assert!(text.contains("vamos_stage_seconds_bucket{stage=\"flow\",le=\"0.01\"} 0"));
        assert!(
            text.contains("vamos_frames_dropped_total{profile=\"arm\",reason=\"queue_full\"} 1")
        );
        assert!(text.contains(&format!(
            "vamos_build_info{{version=\"{}\"}} 1",
            env!("CARGO_PKG_VERSION")
        )));
        #[cfg(target_os = "linux")]
        assert!(text.contains("process_resident_memory_bytes"));
    }

    #[test]
    fn model_versions_beyond_the_last_few_lose_their_series() {
        let m = Metrics::new();
        let series = |m: &Metrics| {
            m.render()
                .lines()
                .filter(|l| l.starts_with("vamos_model_inference_seconds_count"))
                .count()
        };
        for v in 1..=MODEL_SERIES + 4 {
            m.observe_inference(&format!("flow@{v}"), 0.001);
            // The newest model again: still one series.
            m.observe_inference(&format!("flow@{v}"), 0.002);
        }
        assert_eq!(series(&m), MODEL_SERIES);
        let text = m.render();
        assert!(!text.contains("model=\"flow@4\""), "the oldest are gone");
        assert!(text.contains("vamos_model_inference_seconds_count{model=\"flow@5\"} 2"));
        let newest = format!("model=\"flow@{}\"", MODEL_SERIES + 4);
        assert!(text.contains(&newest), "{text}");
    }
}
