//! The HTTP connection loop of both listeners (gRPC over HTTP/2, REST over HTTP/1.1 or
//! 2), with what `axum::serve` lacks for a server on a network:
//! - a cap on open connections, so connections never exhaust the process's file
//!   descriptors (the default cap leaves headroom under `RLIMIT_NOFILE` for the data
//!   directory, models and logs). When it is reached, a new connection takes the place of
//!   an idle one (no request in flight; the idlest of a random sample), so a client that
//!   sends its request at once always gets in while any connection is idle; only when
//!   none is, or too many newcomers already wait for a place, it is closed at once;
//! - a cap per client address (an IPv6 client's whole /64), below the server's cap, so one
//!   client cannot fill it and health checks and the admin from elsewhere still get in;
//! - a header-read timeout: a client must send its request head within it (HTTP/1), or
//!   its first bytes (any protocol); past three quarters of the cap the timeout is much
//!   shorter, so half-open connections cannot crowd out a health check that sends its
//!   request at once;
//! - an idle timeout: a connection with no request in flight for that long is closed
//!   (HTTP/2: GOAWAY), whatever else the peer sends: answering keep-alive PINGs or
//!   sending SETTINGS is not activity. Past three quarters of the cap it is much shorter;
//! - a request-body timeout: a body that sends nothing for that long while the server
//!   reads it fails, so a stalled upload cannot hold its slot (nor a JSON route wait on a
//!   `Content-Length` that never comes);
//! - HTTP/2 keep-alive pings, so a vanished peer's connection is closed;
//! - TLS handshakes inside the connection's slot, with their own timeout;
//! - graceful shutdown: no new connections, open ones finish their requests.

use crate::session::metrics::Metrics;
use axum::body::{Body, Bytes};
use axum::http::{Request, Response};
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto::Builder;
use hyper_util::service::TowerToHyperService;
use std::collections::HashMap;
use std::convert::Infallible;
use std::future::Future;
use std::net::{IpAddr, Ipv6Addr};
use std::pin::Pin;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::TcpListener;
use tokio::sync::Semaphore;
use tokio::time::Instant;
use tokio_rustls::TlsAcceptor;

/// Longest TLS handshake before the connection is dropped.
const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// How long a connection told to close when idle (HTTP/2: GOAWAY) has to go before it is
/// dropped, for a peer that ignores the GOAWAY and its PING.
const CLOSE_GRACE: Duration = Duration::from_secs(5);

/// Newcomers that may wait at once for the place of an evicted idle connection (each holds
/// a socket meanwhile, within the cap's headroom of descriptors).
const MAX_WAITING: usize = 16;

/// How long a newcomer waits for the place of the connection it evicted.
const EVICT_WAIT: Duration = Duration::from_secs(1);

/// Connections looked at to choose one to evict (a random sample: the choice costs the
/// same however many are open).
const EVICT_SAMPLE: usize = 16;

/// A connection's byte stream, plain or TLS.
trait Io: AsyncRead + AsyncWrite + Unpin + Send {}
impl<T: AsyncRead + AsyncWrite + Unpin + Send> Io for T {}

/// Limits of the connection loop.
#[derive(Debug, Clone, Copy)]
pub struct ConnLimits {
    /// Most connections open at once (both listeners share it).
    pub max_connections: usize,
    /// Most connections open at once from one client address (an IPv6 /64).
    pub max_per_address: usize,
    /// Time a connection has for its first bytes and each HTTP/1 request head.
    pub header_timeout: Duration,
    /// The same while more than three quarters of the cap are in use.
    pub pressed_header_timeout: Duration,
    /// A connection with no request in flight for this long is closed.
    pub idle_timeout: Duration,
    /// The same while more than three quarters of the cap are in use.
    pub pressed_idle_timeout: Duration,
    /// A request body that sends nothing for this long while it is read fails.
    pub body_timeout: Duration,
    /// HTTP/2 ping interval (a peer that does not answer within it is dropped).
    pub keep_alive: Duration,
}

impl ConnLimits {
    /// The per-address cap when none is set: a quarter of the server's cap, at least 8.
    pub fn default_per_address(max_connections: usize) -> usize {
        (max_connections / 4).max(8).min(max_connections)
    }
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
    addresses: Arc<Mutex<HashMap<IpAddr, usize>>>,
    open: Arc<Mutex<Registry>>,
    waiting: Arc<std::sync::atomic::AtomicUsize>,
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

/// The address a client's connections are counted under: an IPv4 address, or an IPv6
/// address's /64 (one host's usual allocation; an IPv4-mapped address counts as IPv4).
fn address_key(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V4(_) => ip,
        IpAddr::V6(v6) => match v6.to_ipv4_mapped() {
            Some(v4) => IpAddr::V4(v4),
            None => {
                let s = v6.segments();
                IpAddr::V6(Ipv6Addr::new(s[0], s[1], s[2], s[3], 0, 0, 0, 0))
            }
        },
    }
}

/// One client address's place among the open connections, given back on drop.
struct AddressSlot {
    addresses: Arc<Mutex<HashMap<IpAddr, usize>>>,
    key: IpAddr,
}

impl Drop for AddressSlot {
    fn drop(&mut self) {
        let mut map = self.addresses.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(n) = map.get_mut(&self.key) {
            *n -= 1;
            if *n == 0 {
                map.remove(&self.key);
            }
        }
    }
}

impl Connections {
    /// A loop with `limits`, counting in `metrics`.
    pub fn new(limits: ConnLimits, metrics: Metrics) -> Self {
        Self {
            slots: Arc::new(Semaphore::new(limits.max_connections)),
            addresses: Arc::default(),
            open: Arc::default(),
            waiting: Arc::default(),
            normal: Arc::new(builder(limits.header_timeout, limits.keep_alive)),
            pressed: Arc::new(builder(limits.pressed_header_timeout, limits.keep_alive)),
            limits,
            metrics,
        }
    }

    /// A place for one more connection from `ip`, unless that address is at its cap.
    fn admit_address(&self, ip: IpAddr) -> Option<AddressSlot> {
        let key = address_key(ip);
        let mut map = self.addresses.lock().unwrap_or_else(|e| e.into_inner());
        let n = map.entry(key).or_insert(0);
        if *n >= self.limits.max_per_address {
            return None;
        }
        *n += 1;
        Some(AddressSlot {
            addresses: self.addresses.clone(),
            key,
        })
    }

    /// Tells an idle connection (no request in flight; the idlest of a random sample) to
    /// go at once, making room for a newcomer; `false` when none of the sample is idle.
    fn evict_idle(&self) -> bool {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        let n = open.entries.len();
        if n == 0 {
            return false;
        }
        let victim = (0..EVICT_SAMPLE)
            .filter_map(|_| {
                let i = fastrand::usize(..n);
                let since = open.entries[i].as_ref()?.activity.idle_since()?;
                Some((since, i))
            })
            .min();
        let Some((_, i)) = victim else {
            return false;
        };
        if let Some(c) = open.remove(i) {
            c.evict.notify_one();
            self.metrics
                .connections_closed
                .with_label_values(&["evicted"])
                .inc();
        }
        true
    }

    /// More than three quarters of the connection cap are in use.
    fn pressed(&self) -> bool {
        let in_use = self.limits.max_connections - self.slots.available_permits();
        4 * in_use > 3 * self.limits.max_connections
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
        let (closing, _) = tokio::sync::watch::channel(false);
        // Every connection task holds a sender: the channel closes when the last one ends.
        let (tasks, mut all_done) = tokio::sync::mpsc::channel::<Infallible>(1);
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
            // This address at its cap, or the server full with no idle connection to
            // give way: closed at once (dropping the stream), before a byte is read. Full
            // with an idle one: that one goes, and the newcomer waits for its place.
            let refuse = |reason: &str| {
                self.metrics
                    .connections_refused
                    .with_label_values(&[reason])
                    .inc();
            };
            let Some(address_slot) = self.admit_address(addr.ip()) else {
                refuse("address");
                drop(io);
                continue;
            };
            let slot = match self.slots.clone().try_acquire_owned() {
                Ok(slot) => Some(slot),
                Err(_) => {
                    let waiters = self.waiting.fetch_add(1, Ordering::SeqCst);
                    if waiters < MAX_WAITING && self.evict_idle() {
                        None
                    } else {
                        self.waiting.fetch_sub(1, Ordering::SeqCst);
                        refuse("cap");
                        drop((io, address_slot));
                        continue;
                    }
                }
            };
            let pressed = self.pressed();
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
            let activity = Arc::new(Activity::new());
            let service = TowerToHyperService::new(Tracked {
                app: app.clone(),
                activity: activity.clone(),
                body_timeout: self.limits.body_timeout,
                metrics: self.metrics.clone(),
            });
            let this = self.clone();
            let mut closing = closing.subscribe();
            let tls = tls.clone();
            let done = tasks.clone();
            tokio::spawn(async move {
                let _done = done;
                let slot = match slot {
                    Some(slot) => slot,
                    None => {
                        let place =
                            tokio::time::timeout(EVICT_WAIT, this.slots.clone().acquire_owned())
                                .await;
                        this.waiting.fetch_sub(1, Ordering::SeqCst);
                        match place {
                            Ok(Ok(slot)) => slot,
                            _ => {
                                this.metrics
                                    .connections_refused
                                    .with_label_values(&["cap"])
                                    .inc();
                                return;
                            }
                        }
                    }
                };
                let registered = Arc::new(Registered {
                    activity: activity.clone(),
                    evict: tokio::sync::Notify::new(),
                });
                let place = this.open_insert(&registered);
                let gauge = this.metrics.connections_open.clone();
                gauge.inc();
                let io: Box<dyn Io> = match tls {
                    None => Box::new(io),
                    Some(acceptor) => {
                        match tokio::time::timeout(HANDSHAKE_TIMEOUT, acceptor.accept(io)).await {
                            Ok(Ok(tls)) => Box::new(tls),
                            Ok(Err(e)) => {
                                tracing::debug!(%addr, "TLS handshake failed: {e}");
                                gauge.dec();
                                this.open_remove(place, &registered);
                                return;
                            }
                            Err(_) => {
                                tracing::debug!(%addr, "TLS handshake timed out");
                                gauge.dec();
                                this.open_remove(place, &registered);
                                return;
                            }
                        }
                    }
                };
                let io = TokioIo::new(FirstBytes::new(io, first_bytes));
                let conn = builder.serve_connection_with_upgrades(io, service);
                tokio::pin!(conn);
                // Checked at least this often, so that a server coming under pressure
                // closes idle connections at the shorter timeout.
                let every = this.limits.pressed_idle_timeout;
                let check = tokio::time::sleep(every);
                tokio::pin!(check);
                let mut state = Closing::No;
                loop {
                    tokio::select! {
                        r = conn.as_mut() => {
                            if let Err(e) = r {
                                tracing::debug!("connection ended: {e}");
                            }
                            break;
                        }
                        () = registered.evict.notified() => {
                            tracing::debug!(%addr, "idle connection evicted for a newcomer");
                            break;
                        }
                        _ = closing.wait_for(|v| *v), if state == Closing::No => {
                            conn.as_mut().graceful_shutdown();
                            state = Closing::Shutdown;
                        }
                        () = &mut check, if state != Closing::Shutdown => {
                            let now = Instant::now();
                            if let Closing::Idle(since) = state {
                                // Told to go and still there: dropped, unless a request
                                // began before the GOAWAY reached the peer.
                                if activity.idle_since().is_some() && now >= since + CLOSE_GRACE {
                                    tracing::debug!(%addr, "idle connection dropped");
                                    break;
                                }
                                check.as_mut().reset(now + CLOSE_GRACE);
                                continue;
                            }
                            let limit = if this.pressed() {
                                this.limits.pressed_idle_timeout
                            } else {
                                this.limits.idle_timeout
                            };
                            match activity.idle_since() {
                                Some(since) if now >= since + limit => {
                                    this.metrics
                                        .connections_closed
                                        .with_label_values(&["idle"])
                                        .inc();
                                    conn.as_mut().graceful_shutdown();
                                    state = Closing::Idle(now);
                                    check.as_mut().reset(now + CLOSE_GRACE);
                                }
                                Some(since) => check.as_mut().reset((since + limit).min(now + every)),
                                None => check.as_mut().reset(now + every),
                            }
                        }
                    }
                }
                gauge.dec();
                this.open_remove(place, &registered);
                drop((slot, address_slot));
            });
        }
        drop(listener);
        let _ = closing.send(true);
        drop(tasks);
        let _ = all_done.recv().await;
    }
}

/// An open connection as the cap sees it: whether it is idle, and how to make it go.
struct Registered {
    activity: Arc<Activity>,
    evict: tokio::sync::Notify,
}

/// The open connections, in places that are reused (so a random place is a random
/// connection).
#[derive(Default)]
struct Registry {
    entries: Vec<Option<Arc<Registered>>>,
    free: Vec<usize>,
}

impl Registry {
    fn insert(&mut self, c: Arc<Registered>) -> usize {
        match self.free.pop() {
            Some(i) => {
                self.entries[i] = Some(c);
                i
            }
            None => {
                self.entries.push(Some(c));
                self.entries.len() - 1
            }
        }
    }

    fn remove(&mut self, i: usize) -> Option<Arc<Registered>> {
        let c = self.entries.get_mut(i)?.take()?;
        self.free.push(i);
        Some(c)
    }
}

impl Connections {
    fn open_insert(&self, c: &Arc<Registered>) -> usize {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        open.insert(c.clone())
    }

    /// Removes `c` from place `i` unless it was evicted (and the place reused) already.
    fn open_remove(&self, i: usize, c: &Arc<Registered>) {
        let mut open = self.open.lock().unwrap_or_else(|e| e.into_inner());
        if open
            .entries
            .get(i)
            .and_then(Option::as_ref)
            .is_some_and(|x| Arc::ptr_eq(x, c))
        {
            open.remove(i);
        }
    }
}

/// Where a connection is in being closed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Closing {
    /// Serving.
    No,
    /// Told to go (HTTP/2: GOAWAY) at this time because it was idle.
    Idle(Instant),
    /// The server is shutting down: open requests finish.
    Shutdown,
}

/// A connection's requests in flight, and since when it has had none.
struct Activity {
    state: Mutex<(usize, Instant)>,
}

impl Activity {
    fn new() -> Self {
        Self {
            state: Mutex::new((0, Instant::now())),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, (usize, Instant)> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Since when no request has been in flight; `None` while one is.
    fn idle_since(&self) -> Option<Instant> {
        let (in_flight, since) = *self.lock();
        (in_flight == 0).then_some(since)
    }

    /// A request begins: in flight until the guard (held by its response body) drops.
    fn begin(self: &Arc<Self>) -> InFlight {
        self.lock().0 += 1;
        InFlight(self.clone())
    }
}

/// One request in flight on its connection: from its head to the end of its response
/// body (a gRPC stream's whole life).
struct InFlight(Arc<Activity>);

impl Drop for InFlight {
    fn drop(&mut self) {
        let mut state = self.0.lock();
        state.0 -= 1;
        if state.0 == 0 {
            state.1 = Instant::now();
        }
    }
}

/// The app as one connection serves it: each request counted in flight on the
/// connection, its body read under the body timeout.
#[derive(Clone)]
struct Tracked {
    app: axum::Router,
    activity: Arc<Activity>,
    body_timeout: Duration,
    metrics: Metrics,
}

impl<B> tower_service::Service<Request<B>> for Tracked
where
    B: http_body::Body<Data = Bytes> + Send + Unpin + 'static,
    B::Error: Into<axum::BoxError>,
{
    type Response = Response<Body>;
    type Error = Infallible;
    type Future = Pin<Box<dyn Future<Output = Result<Response<Body>, Infallible>> + Send>>;

    fn poll_ready(&mut self, _: &mut Context<'_>) -> Poll<Result<(), Infallible>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, req: Request<B>) -> Self::Future {
        let guard = self.activity.begin();
        let timeout = self.body_timeout;
        let metrics = self.metrics.clone();
        let req = req.map(|body| {
            Body::new(Watched {
                inner: body,
                timeout,
                waiting: None,
                metrics,
            })
        });
        let response = tower_service::Service::call(&mut self.app.clone(), req);
        Box::pin(async move {
            let response = response.await?;
            Ok(response.map(|body| {
                Body::new(Guarded {
                    inner: body,
                    _guard: guard,
                })
            }))
        })
    }
}

/// A response body that keeps its request in flight until it is sent or dropped.
struct Guarded {
    inner: Body,
    _guard: InFlight,
}

impl http_body::Body for Guarded {
    type Data = Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Bytes>, axum::Error>>> {
        Pin::new(&mut self.inner).poll_frame(cx)
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
    }
}

/// Why a request body failed: it sent nothing for the body timeout.
#[derive(Debug, thiserror::Error)]
#[error("the request body sent nothing for {0:?} ([service] body_timeout_s)")]
struct BodyStalled(Duration);

/// A request body that fails when the client sends nothing for `timeout` while the
/// server waits for it (time the server spends not reading does not count).
struct Watched<B> {
    inner: B,
    timeout: Duration,
    waiting: Option<Pin<Box<tokio::time::Sleep>>>,
    metrics: Metrics,
}

impl<B> http_body::Body for Watched<B>
where
    B: http_body::Body<Data = Bytes> + Unpin,
    B::Error: Into<axum::BoxError>,
{
    type Data = Bytes;
    type Error = axum::BoxError;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<http_body::Frame<Bytes>, axum::BoxError>>> {
        match Pin::new(&mut self.inner).poll_frame(cx) {
            Poll::Pending => {
                let timeout = self.timeout;
                let deadline = self
                    .waiting
                    .get_or_insert_with(|| Box::pin(tokio::time::sleep(timeout)));
                if deadline.as_mut().poll(cx).is_ready() {
                    self.metrics
                        .connections_closed
                        .with_label_values(&["stalled"])
                        .inc();
                    return Poll::Ready(Some(Err(Box::new(BodyStalled(timeout)))));
                }
                Poll::Pending
            }
            Poll::Ready(frame) => {
                self.waiting = None;
                Poll::Ready(frame.map(|f| f.map_err(Into::into)))
            }
        }
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> http_body::SizeHint {
        self.inner.size_hint()
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_address_is_counted_as_its_ipv4_or_its_ipv6_slash_64() {
        let key = |s: &str| address_key(s.parse().unwrap());
        assert_eq!(key("192.0.2.7"), key("192.0.2.7"));
        assert_ne!(key("192.0.2.7"), key("192.0.2.8"));
        assert_eq!(key("::ffff:192.0.2.7"), key("192.0.2.7"));
        assert_eq!(key("2001:db8:1:2:aaaa::1"), key("2001:db8:1:2:bbbb::9"));
        assert_ne!(key("2001:db8:1:2::1"), key("2001:db8:1:3::1"));
    }

    #[test]
    fn the_registry_reuses_places_and_forgets_what_it_removed() {
        let entry = || {
            Arc::new(Registered {
                activity: Arc::new(Activity::new()),
                evict: tokio::sync::Notify::new(),
            })
        };
        let mut r = Registry::default();
        let (a, b) = (entry(), entry());
        let ia = r.insert(a.clone());
        let ib = r.insert(b);
        assert_ne!(ia, ib);
        assert!(r.remove(ia).is_some_and(|x| Arc::ptr_eq(&x, &a)));
        assert!(r.remove(ia).is_none(), "removed once");
        assert_eq!(r.insert(entry()), ia, "the place is reused");
        assert_eq!(r.entries.len(), 2);
    }
}
