//! The HTTP connection loop of both listeners (gRPC over HTTP/2, REST over HTTP/1.1 or
//! 2), with what `axum::serve` lacks for a server on a network:
//! - a cap on open connections: past it a new connection is closed at once, so
//!   connections never exhaust the process's file descriptors (the default cap leaves
//!   headroom under `RLIMIT_NOFILE` for the data directory, models and logs);
//! - a header-read timeout: a client must send its request head within it (HTTP/1), or
//!   its first bytes (any protocol); past three quarters of the cap the timeout is much
//!   shorter, so half-open connections cannot crowd out a health check that sends its
//!   request at once;
//! - HTTP/2 keep-alive pings, so a vanished peer's connection is closed;
//! - TLS handshakes inside the connection's slot, with their own timeout;
//! - graceful shutdown: no new connections, open ones finish their requests.

use crate::session::metrics::Metrics;
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto::Builder;
use hyper_util::service::TowerToHyperService;
use std::future::Future;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpListener;
use tokio::sync::Semaphore;
use tokio_rustls::TlsAcceptor;

/// Longest TLS handshake before the connection is dropped.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// A connection's byte stream, plain or TLS.
trait Io: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Io for T {}

/// Limits of the connection loop.
#[derive(Debug, Clone, Copy)]
pub struct ConnLimits {
    /// Most connections open at once (both listeners share it).
    pub max_connections: usize,
    /// Time a connection has for its first bytes and each HTTP/1 request head.
    pub header_timeout: Duration,
    /// The same while more than three quarters of the cap are in use.
    pub pressed_header_timeout: Duration,
    /// HTTP/2 ping interval (a peer that does not answer within it is dropped).
    pub keep_alive: Duration,
}

/// The default connection cap: `RLIMIT_NOFILE`'s soft limit less 64 descriptors of
/// headroom (files, models, logs), at most 4096, at least 16.
pub fn default_max_connections() -> usize {
    let soft = std::fs::read_to_string("/proc/self/limits")
        .ok()
        .and_then(|text| {
            text.lines()
                .find(|l| l.starts_with("Max open files"))
                .and_then(|l| l.split_whitespace().nth(3))
                .and_then(|v| v.parse::<usize>().ok())
        })
        .unwrap_or(1024);
    soft.saturating_sub(64).clamp(16, 4096)
}

/// The connections of both listeners: one count, one cap.
#[derive(Clone)]
pub struct Connections {
    limits: ConnLimits,
    slots: Arc<Semaphore>,
    normal: Arc<Builder<TokioExecutor>>,
    pressed: Arc<Builder<TokioExecutor>>,
    metrics: Metrics,
}

fn builder(header_timeout: Duration, keep_alive: Duration) -> Builder<TokioExecutor> {
    let mut b = Builder::new(TokioExecutor::new());
    b.http1()
        .timer(TokioTimer::new())
        .header_read_timeout(header_timeout);
    b.http2()
        .timer(TokioTimer::new())
        .enable_connect_protocol()
        .keep_alive_interval(keep_alive)
        .keep_alive_timeout(keep_alive);
    b
}

impl Connections {
    /// A loop with `limits`, counting in `metrics`.
    pub fn new(limits: ConnLimits, metrics: Metrics) -> Self {
        Self {
            slots: Arc::new(Semaphore::new(limits.max_connections)),
            normal: Arc::new(builder(limits.header_timeout, limits.keep_alive)),
            pressed: Arc::new(builder(limits.pressed_header_timeout, limits.keep_alive)),
            limits,
            metrics,
        }
    }

    /// Serves `app` on `listener` (TLS-wrapped with `tls`) until `shutdown` resolves,
    /// then lets open connections finish their requests.
    pub async fn serve(
        &self,
        listener: TcpListener,
        tls: Option<TlsAcceptor>,
        app: axum::Router,
        shutdown: impl Future<Output = ()> + Send,
    ) {
        let graceful = hyper_util::server::graceful::GracefulShutdown::new();
        tokio::pin!(shutdown);
        loop {
            let accepted = tokio::select! {
                c = listener.accept() => c,
                () = &mut shutdown => break,
            };
            let (io, addr) = match accepted {
                Ok(c) => c,
                Err(e) => {
                    // Out of descriptors, or the peer gone before accept: wait a little.
                    tracing::warn!("accept failed: {e}");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            };
            // Scores are small writes that follow large reads: with Nagle's algorithm a
            // score waits for the ACK of the server's last flow-control frame, which the
            // client delays (40 ms on Linux). Measured through `vamos bridge`: 37 ms added
            // per 320x240 frame with it, ~1 ms without.
            if let Err(e) = io.set_nodelay(true) {
                tracing::debug!("TCP_NODELAY on a connection from {addr}: {e}");
            }
            let Ok(slot) = self.slots.clone().try_acquire_owned() else {
                // Full: closed at once (dropping the stream), before a byte is read.
                self.metrics.connections_refused.inc();
                drop(io);
                continue;
            };
            let in_use = self.limits.max_connections - self.slots.available_permits();
            let pressed = 4 * in_use > 3 * self.limits.max_connections;
            let builder = if pressed {
                self.pressed.clone()
            } else {
                self.normal.clone()
            };
            let first_bytes = if pressed {
                self.limits.pressed_header_timeout
            } else {
                self.limits.header_timeout
            };
            let service = TowerToHyperService::new(app.clone());
            let gauge = self.metrics.connections_open.clone();
            let watcher = graceful.watcher();
            let tls = tls.clone();
            tokio::spawn(async move {
                gauge.inc();
                let io: Box<dyn Io> = match tls {
                    None => Box::new(io),
                    Some(acceptor) => {
                        match tokio::time::timeout(HANDSHAKE_TIMEOUT, acceptor.accept(io)).await {
                            Ok(Ok(tls)) => Box::new(tls),
                            Ok(Err(e)) => {
                                tracing::debug!(%addr, "TLS handshake failed: {e}");
                                gauge.dec();
                                return;
                            }
                            Err(_) => {
                                tracing::debug!(%addr, "TLS handshake timed out");
                                gauge.dec();
                                return;
                            }
                        }
                    }
                };
                let io = TokioIo::new(FirstBytes::new(io, first_bytes));
                let conn = builder.serve_connection_with_upgrades(io, service);
                if let Err(e) = watcher.watch(conn.into_owned()).await {
                    tracing::debug!("connection ended: {e}");
                }
                gauge.dec();
                drop(slot);
            });
        }
        drop(listener);
        graceful.shutdown().await;
    }
}

/// A stream that fails with `TimedOut` if its first bytes do not arrive within the
/// deadline (hyper's HTTP/1 header timeout does not cover a client that sends nothing,
/// nor the HTTP/2 preface).
struct FirstBytes<S> {
    inner: S,
    deadline: Option<std::pin::Pin<Box<tokio::time::Sleep>>>,
}

impl<S> FirstBytes<S> {
    fn new(inner: S, within: Duration) -> Self {
        Self {
            inner,
            deadline: Some(Box::pin(tokio::time::sleep(within))),
        }
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for FirstBytes<S> {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        use std::task::Poll;
        let before = buf.filled().len();
        let polled = std::pin::Pin::new(&mut self.inner).poll_read(cx, buf);
        match polled {
            Poll::Ready(Ok(())) if buf.filled().len() > before => {
                self.deadline = None;
                Poll::Ready(Ok(()))
            }
            Poll::Pending => {
                let expired = self
                    .deadline
                    .as_mut()
                    .is_some_and(|d| d.as_mut().poll(cx).is_ready());
                if expired {
                    Poll::Ready(Err(std::io::Error::new(
                        std::io::ErrorKind::TimedOut,
                        "no request in time",
                    )))
                } else {
                    Poll::Pending
                }
            }
            other => other,
        }
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for FirstBytes<S> {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.inner).poll_write(cx, buf)
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> std::task::Poll<std::io::Result<usize>> {
        std::pin::Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.inner.is_write_vectored()
    }
}
