//! Start and shutdown of the server: the data directory and the shared store opened,
//! the listeners bound (gRPC and REST on one port or two, TLS, the connection loop),
//! tokens checked, the hub's workers started, the sweeper and the fleet sync run; then
//! on [`RunningServer::shutdown`] (or SIGTERM/SIGINT with [`serve`]) new sessions are
//! refused, queued frames scored (up to `shutdown_grace_s`), every stream closed with
//! UNAVAILABLE.

use super::{ServiceError, conn, tls};
use crate::api::auth::{self, Tokens};
use crate::api::grpc::MonitorService;
use crate::api::{Shared, proto, rest};
use crate::config::{FleetRole, Settings};
use crate::session::budget::{MinRate, Uploads};
use crate::session::fleet::Fleet;
use crate::session::jobs::Jobs;
use crate::session::metrics::Metrics;
use crate::session::{Hub, ProfileCatalog};
use crate::store::{ModelValidator, Store, StoreLimits};
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use tokio::net::TcpListener;

fn is_loopback(addr: &SocketAddr) -> bool {
    addr.ip().is_loopback()
}

async fn bind(addr: &str) -> Result<TcpListener, ServiceError> {
    TcpListener::bind(addr)
        .await
        .map_err(|e| ServiceError::Listen {
            addr: addr.into(),
            reason: e.to_string(),
        })
}

/// A server that is running.
pub struct RunningServer {
    /// The gRPC address bound (an ephemeral port resolved).
    pub grpc_addr: SocketAddr,
    /// The REST address bound (the same as `grpc_addr` when shared).
    pub rest_addr: SocketAddr,
    /// The shared state.
    pub shared: Arc<Shared>,
    tasks: Vec<tokio::task::JoinHandle<Result<(), ServiceError>>>,
    transport_stop: tokio::sync::watch::Sender<bool>,
}

impl RunningServer {
    /// Stops: no new sessions, queued frames scored (up to the grace time), streams
    /// closed with UNAVAILABLE, listeners closed.
    pub async fn shutdown(self) -> Result<(), ServiceError> {
        tracing::info!("shutting down");
        let _ = self.shared.stop.send(true);
        let hub = self.shared.hub.clone();
        let grace = Duration::from_secs_f64(self.shared.settings.service.shutdown_grace_s.max(0.0));
        let _ = tokio::task::spawn_blocking(move || hub.shutdown(grace)).await;
        // Calibration jobs stop before their next episode; they hold the data directory.
        let jobs = self.shared.jobs.clone();
        let stopped = tokio::task::spawn_blocking(move || jobs.stop_all(grace)).await;
        if !matches!(stopped, Ok(true)) {
            tracing::warn!("a calibration job was still running at shutdown");
        }
        let _ = self.transport_stop.send(true);
        for t in self.tasks {
            match t.await {
                Ok(r) => r?,
                Err(e) => return Err(ServiceError::Transport(e.to_string())),
            }
        }
        tracing::info!("stopped");
        Ok(())
    }
}

/// Builds and starts servers.
pub struct Server;

impl Server {
    /// Binds the gRPC and REST listeners and starts serving `profiles`.
    pub async fn start(
        settings: Settings,
        profiles: ProfileCatalog,
    ) -> Result<RunningServer, ServiceError> {
        let cfg = settings.service.clone();
        if cfg.mmap_threshold_kib > 0
            && !super::memory::fix_mmap_threshold(cfg.mmap_threshold_kib.saturating_mul(1024))
        {
            tracing::warn!(
                kib = cfg.mmap_threshold_kib,
                "[service] mmap_threshold_kib not taken (glibc on Linux only, below 2 GiB)"
            );
        }
        let tokens = Tokens::new(&cfg.admin_token_sha256, &cfg.robot_token_sha256, None, None)
            .map_err(|e| ServiceError::Config(e.to_string()))?
            .with_digests(auth::env_token_digests())
            .with_viewers(&cfg.viewer_token_sha256, auth::env_viewer_digests())
            .map_err(|e| ServiceError::Config(e.to_string()))?;
        let store = Store::open(
            &cfg.data_dir,
            StoreLimits {
                max_model_bytes: cfg.max_model_bytes,
                max_robot_bytes: cfg.max_robot_bytes,
            },
        )?;
        let fleet = match &cfg.shared_store {
            Some(c) => Some(Arc::new(Fleet::new(c, store.clone())?)),
            None => None,
        };
        if let Some(f) = &fleet {
            // Serve what the fleet has from the start; an unreachable shared store is
            // retried in the background while the local copy serves.
            match tokio::time::timeout(FIRST_SYNC_TIMEOUT, f.sync()).await {
                Ok(Ok(_)) => {}
                Ok(Err(e)) => tracing::warn!("shared store: {e} (retrying in the background)"),
                Err(_) => tracing::warn!(
                    "shared store: no answer in {FIRST_SYNC_TIMEOUT:?} (retrying in the background)"
                ),
            }
        }
        for p in store.problems() {
            tracing::warn!(kind = p.kind, name = %p.name, "data directory: {}", p.reason);
        }
        let shared_port = cfg.grpc_addr == cfg.rest_addr;
        let grpc_listener = bind(&cfg.grpc_addr).await?;
        let grpc_addr = grpc_listener
            .local_addr()
            .map_err(|e| ServiceError::Listen {
                addr: cfg.grpc_addr.clone(),
                reason: e.to_string(),
            })?;
        let rest_listener = if shared_port {
            None
        } else {
            Some(bind(&cfg.rest_addr).await?)
        };
        let rest_addr = match &rest_listener {
            Some(l) => l.local_addr().map_err(|e| ServiceError::Listen {
                addr: cfg.rest_addr.clone(),
                reason: e.to_string(),
            })?,
            None => grpc_addr,
        };
        if !tokens.enabled() {
            let remote = !is_loopback(&grpc_addr) || !is_loopback(&rest_addr);
            if remote && !cfg.allow_unauthenticated_remote {
                return Err(ServiceError::Config(
                    "no tokens are configured (VAMOS_ADMIN_TOKEN, VAMOS_ROBOT_TOKEN or \
                     [service] *_token_sha256), so the server listens on loopback only; set \
                     service.allow_unauthenticated_remote = true to override"
                        .into(),
                ));
            }
            tracing::warn!(
                "no tokens configured: every caller is admin (listening on {grpc_addr} and {rest_addr})"
            );
        }
        // Uploaded models are validated by `vamos model inspect` in a child process.
        let validator_exe = cfg.model_validator.clone().or_else(|| {
            std::env::current_exe()
                .ok()
                .filter(|p| p.file_stem().is_some_and(|s| s == "vamos"))
        });
        let model_validator = ModelValidator::new(
            validator_exe,
            cfg.model_validation_mb.saturating_mul(1 << 20),
            Duration::from_secs_f64(cfg.model_validation_s.max(1.0)),
            settings.model.clone(),
        );
        if model_validator.in_process() {
            tracing::warn!(
                "no vamos executable to validate uploaded models in a child process \
                 ([service] model_validator): they are validated in this process, unbounded"
            );
        }
        let metrics = Metrics::new();
        let metrics_for_uploads = metrics.upload_disk_used.clone();
        let hub = Hub::start(cfg.clone(), metrics);
        // The live view's ended sessions, as the data directory kept them.
        hub.restore_ended_sessions(&store);
        let (stop, _) = tokio::sync::watch::channel(false);
        let profiles = Arc::new(profiles.with_store(store.clone(), settings.clone()));
        let shared = Arc::new(Shared {
            settings,
            hub,
            profiles,
            jobs: Arc::new(Jobs::new(store.clone(), cfg.max_jobs)),
            store,
            fleet,
            tokens,
            stop,
            ready: AtomicBool::new(false),
            uploads: Uploads::new(
                cfg.max_uploads,
                match cfg.max_upload_disk_mb {
                    0 => crate::session::budget::default_upload_disk(&cfg.data_dir),
                    mb => mb << 20,
                },
                metrics_for_uploads,
                MinRate {
                    bytes_per_s: cfg.min_upload_rate_kib_s << 10,
                    grace: Duration::from_secs_f64(cfg.upload_grace_s.max(0.0)),
                },
            ),
            model_validation: tokio::sync::Mutex::new(()),
            model_validator,
        });
        let (transport_stop, _) = tokio::sync::watch::channel(false);
        let mut tasks = Vec::new();

        let (health, health_service) = tonic_health::server::health_reporter();
        health
            .set_serving::<proto::monitor_server::MonitorServer<MonitorService>>()
            .await;
        let reflection_v1 = tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(proto::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
            .build_v1()
            .map_err(|e| ServiceError::Config(e.to_string()))?;
        let reflection_v1alpha = tonic_reflection::server::Builder::configure()
            .register_encoded_file_descriptor_set(proto::FILE_DESCRIPTOR_SET)
            .register_encoded_file_descriptor_set(tonic_health::pb::FILE_DESCRIPTOR_SET)
            .build_v1alpha()
            .map_err(|e| ServiceError::Config(e.to_string()))?;
        let monitor =
            proto::monitor_server::MonitorServer::new(MonitorService::new(shared.clone()))
                .max_decoding_message_size(cfg.max_message_bytes)
                .max_encoding_message_size(cfg.max_message_bytes);
        let routes = tonic::service::Routes::new(monitor)
            .add_service(health_service)
            .add_service(reflection_v1)
            .add_service(reflection_v1alpha);

        let rest_router = rest::router(shared.clone());
        let grpc_router = routes.prepare().into_axum_router();
        let tls = match &cfg.tls {
            Some(t) => Some(tokio_rustls::TlsAcceptor::from(tls::server_config(t)?)),
            None => None,
        };
        let max_connections = match cfg.max_connections {
            0 => conn::default_max_connections(),
            n => n,
        };
        let idle = Duration::from_secs_f64(cfg.connection_idle_s.max(0.5));
        let connections = conn::Connections::new(
            conn::ConnLimits {
                max_connections,
                max_per_address: match cfg.max_connections_per_address {
                    0 => conn::ConnLimits::default_per_address(max_connections),
                    n => n,
                },
                header_timeout: Duration::from_secs_f64(cfg.header_timeout_s.max(0.1)),
                pressed_header_timeout: Duration::from_secs_f64(
                    (cfg.header_timeout_s / 10.0).clamp(0.1, 1.0),
                ),
                idle_timeout: idle,
                pressed_idle_timeout: (idle / 10)
                    .clamp(Duration::from_millis(500), Duration::from_secs(5)),
                body_timeout: Duration::from_secs_f64(cfg.body_timeout_s.max(0.5)),
                // Pings well inside the idle time (they are not activity, but they find a
                // vanished peer of a long stream).
                keep_alive: (idle / 3).clamp(Duration::from_secs(1), Duration::from_secs(20)),
            },
            shared.metrics().clone(),
        );
        let mut serve = |listener: TcpListener, app: axum::Router| -> Result<(), ServiceError> {
            let mut rx = transport_stop.subscribe();
            let signal = async move {
                let _ = rx.wait_for(|v| *v).await;
            };
            let connections = connections.clone();
            let tls = tls.clone();
            tasks.push(tokio::spawn(async move {
                connections.serve(listener, tls, app, signal).await;
                Ok(())
            }));
            Ok(())
        };
        // gRPC (HTTP/2, content-type application/grpc) and REST are both axum routers;
        // on one port they are merged. Unknown paths: gRPC UNIMPLEMENTED or REST 404.
        // Request ids, spans and request metrics wrap each whole router (api::observe).
        let observed = |r: axum::Router| crate::api::observe::layer(r, shared.metrics().clone());
        match rest_listener {
            Some(rest_listener) => {
                serve(
                    rest_listener,
                    observed(rest_router.fallback(rest::not_found)),
                )?;
                serve(
                    grpc_listener,
                    observed(grpc_router.fallback(rest::not_found)),
                )?;
            }
            None => serve(
                grpc_listener,
                observed(grpc_router.merge(rest_router).fallback(rest::not_found)),
            )?,
        }
        // Images that waited long enough for joint states; detached sessions past their
        // window; over-age sessions; unused heap memory back to the system.
        // gRPC health follows the scoring capacity: NOT_SERVING while no worker runs.
        let sweeper = shared.clone();
        let mut stop_rx = shared.stop.subscribe();
        let trim_every = Duration::try_from_secs_f64(shared.hub.config().trim_memory_s)
            .ok()
            .filter(|d| !d.is_zero());
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(50));
            let mut serving = true;
            let mut trimmed = tokio::time::Instant::now();
            loop {
                tokio::select! {
                    // Stop first: the workers end at shutdown, which is no outage to report
                    // (stop is sent before the hub shuts down).
                    biased;
                    _ = stop_rx.changed() => return,
                    _ = tick.tick() => {
                        sweeper.hub.sweep();
                        if trim_every.is_some_and(|d| trimmed.elapsed() >= d) {
                            trimmed = tokio::time::Instant::now();
                            tokio::task::spawn_blocking(|| {
                                if let Some(bytes) = super::memory::trim() {
                                    tracing::debug!(bytes, "unused heap memory given back");
                                }
                            });
                        }
                        let can_score = sweeper.hub.live_workers() > 0;
                        if !can_score && *stop_rx.borrow() {
                            return;
                        }
                        if can_score != serving {
                            serving = can_score;
                            type Monitor = proto::monitor_server::MonitorServer<MonitorService>;
                            if serving {
                                health.set_serving::<Monitor>().await;
                            } else {
                                tracing::error!("no scoring worker is running: health NOT_SERVING");
                                health.set_not_serving::<Monitor>().await;
                            }
                        }
                    }
                }
            }
        });
        if let Some(f) = shared.fleet.clone() {
            record_fleet(&shared, &f);
            tasks.push(tokio::spawn(run_fleet(shared.clone(), f)));
        }
        shared
            .ready
            .store(true, std::sync::atomic::Ordering::SeqCst);
        tracing::info!(%grpc_addr, %rest_addr, "vamos serving");
        Ok(RunningServer {
            grpc_addr,
            rest_addr,
            shared,
            tasks,
            transport_stop,
        })
    }
}

/// How long the server waits for the shared store before it starts serving.
const FIRST_SYNC_TIMEOUT: Duration = Duration::from_secs(30);

/// Syncs with the shared store every poll interval until the server stops (the writer
/// publishes once more then, so no change is left behind).
async fn run_fleet(shared: Arc<Shared>, fleet: Arc<Fleet>) -> Result<(), ServiceError> {
    let mut stop_rx = shared.stop.subscribe();
    let mut tick = tokio::time::interval(fleet.poll_interval());
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        let stopping = tokio::select! {
            _ = tick.tick() => false,
            _ = stop_rx.wait_for(|v| *v) => true,
        };
        if stopping {
            if fleet.role() == FleetRole::Writer {
                match tokio::time::timeout(FIRST_SYNC_TIMEOUT, fleet.sync()).await {
                    Ok(Ok(_)) => {}
                    Ok(Err(e)) => tracing::warn!("shared store: last publication failed: {e}"),
                    Err(_) => tracing::warn!("shared store: last publication timed out"),
                }
            }
            return Ok(());
        }
        match fleet.sync().await {
            Ok(change) => {
                for (kind, name) in change.objects() {
                    match kind.as_str() {
                        "models" => shared.profiles.invalidate_model(&name),
                        "robots" => shared.profiles.invalidate_robot(&name),
                        _ => shared.profiles.invalidate_profile(&name),
                    }
                }
            }
            Err(e) => {
                shared.metrics().shared_store_errors.inc();
                tracing::warn!("shared store: {e}");
            }
        }
        record_fleet(&shared, &fleet);
    }
}

fn record_fleet(shared: &Shared, fleet: &Fleet) {
    let status = fleet.status();
    let m = shared.metrics();
    m.shared_store_generation.set(status.generation as i64);
    if let Some(t) = status.last_sync_unix_s {
        m.shared_store_last_sync.set(t as f64);
    }
}

/// `vamos serve`: serves until SIGTERM or SIGINT, then shuts down gracefully.
pub async fn serve(settings: Settings) -> Result<(), ServiceError> {
    let profiles = ProfileCatalog::load(&settings)?;
    let server = Server::start(settings, profiles).await?;
    wait_for_signal().await;
    server.shutdown().await
}

/// Completes at SIGTERM or Ctrl-C (Ctrl-C only where SIGTERM cannot be watched).
pub async fn wait_for_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = term.recv() => {}
                    _ = tokio::signal::ctrl_c() => {}
                }
            }
            Err(e) => {
                tracing::warn!("cannot watch SIGTERM ({e}); stopping on Ctrl-C only");
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}
