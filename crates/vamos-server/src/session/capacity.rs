//! The scoring capacity: what each live session costs the worker pool, measured as it
//! runs, and whether one more session fits.
//!
//! A session's load is its workers' time per scored frame over the time between its
//! images (both moving averages), in cores: a robot streaming 10 Hz into a profile that
//! takes 20 ms per frame loads 0.2 core. A session's frames are scored one at a time, so
//! it loads at most one core (a client that sends in bursts counts as one busy worker).
//! The capacity is `[service] admission_load` of the scoring workers.
//!
//! A client that says its image rate (`OpenSession.image_rate_hz`) is admitted when the
//! live sessions' load plus its profile's measured time per frame at that rate fits, and
//! holds that estimate until its own frames are measured: sessions opening together are
//! admitted exactly as far as they fit, and the admitted ones keep their latency. A rate
//! that needs more than one worker is refused even on an idle server (no server could
//! keep it). A client that does not say is admitted while the load measured so far is under the
//! capacity, and counts once measured. An idle server admits any session, and so does a
//! profile no session has measured yet: a session that alone cannot keep up loses frames
//! explicitly (`frames_lost`, `FRAMES_DROPPED`), never silently. Uploaded episodes are not
//! admitted by load: their queue paces them, and they take what is left.

use super::state::lock;
use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
use std::time::Instant;

/// Weight of the newest sample in the moving averages (about the last 20 frames count).
const EWMA_WEIGHT: f64 = 0.1;

/// An exponentially weighted moving average; the first sample starts it.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Ewma(Option<f64>);

impl Ewma {
    fn add(&mut self, v: f64) {
        if !v.is_finite() || v < 0.0 {
            return;
        }
        self.0 = Some(match self.0 {
            None => v,
            Some(m) => m + EWMA_WEIGHT * (v - m),
        });
    }

    fn get(self) -> Option<f64> {
        self.0
    }
}

/// One session's measured cost (kept in its state).
#[derive(Debug, Default)]
pub(super) struct SessionLoad {
    /// Worker seconds per scored frame.
    frame_s: Ewma,
    /// Seconds between the session's images as they arrive.
    interval_s: Ewma,
    last_arrival: Option<Instant>,
}

impl SessionLoad {
    /// An image arrived now.
    pub(super) fn arrived(&mut self, now: Instant) {
        if let Some(last) = self.last_arrival.replace(now) {
            self.interval_s.add(now.duration_since(last).as_secs_f64());
        }
    }

    /// A frame took the worker `seconds`.
    pub(super) fn scored(&mut self, seconds: f64) {
        self.frame_s.add(seconds);
    }

    /// Cores the session keeps busy (at most one), once both figures are measured.
    fn cores(&self) -> Option<f64> {
        let (f, i) = (self.frame_s.get()?, self.interval_s.get()?);
        Some(if i > 0.0 { (f / i).min(1.0) } else { 1.0 })
    }
}

/// Why a session was not admitted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}", refusal_text(self))]
pub struct OverCapacity {
    /// The live sessions' load, cores.
    pub load: f64,
    /// The limit, cores.
    pub capacity: f64,
    /// Scoring workers.
    pub workers: usize,
    /// `[service] admission_load`.
    pub fraction: f64,
    /// The profile asked for.
    pub profile: String,
    /// What the new session would add, cores (0 when its rate was not said).
    pub adds: f64,
    /// Its profile's measured time per frame, ms (0 when not measured).
    pub frame_ms: f64,
    /// The rate the client said, Hz (0 when not said).
    pub rate_hz: f64,
    /// The server's CPU time per second of worker time, included in `load` and `adds`.
    pub overhead: f64,
}

fn refusal_text(e: &OverCapacity) -> String {
    let worker_cores = e.frame_ms * 1e-3 * e.rate_hz;
    if worker_cores > 1.0 {
        return format!(
            "a session of profile {:?} at {:.1} Hz needs {worker_cores:.2} cores ({:.1} ms per \
             frame measured), more than the one worker that scores a session's frames in \
             order: no server can keep it; send fewer images or use a lighter profile",
            e.profile, e.rate_hz, e.frame_ms
        );
    }
    format!(
        "the server's scoring capacity is in use: live sessions load {:.2} of {:.2} cores \
         ({} workers x [service] admission_load {}; the server's CPU is {:.2}x its workers' \
         time){}",
        e.load,
        e.capacity,
        e.workers,
        e.fraction,
        e.overhead,
        adds_text(e.adds, e.frame_ms, e.rate_hz, &e.profile)
    )
}

fn adds_text(adds: f64, frame_ms: f64, rate_hz: f64, profile: &str) -> String {
    if rate_hz > 0.0 {
        format!(
            ", and a session of profile {profile:?} adds about {adds:.2} ({frame_ms:.1} ms per \
             frame measured, at the {rate_hz:.1} Hz it asks for)"
        )
    } else {
        String::new()
    }
}

/// The pool's capacity and the live sessions' load.
#[derive(Debug)]
pub struct Capacity {
    workers: usize,
    fraction: f64,
    /// The live sessions' load, millicores (each session's share in its
    /// [`SessionShare`]).
    load_millicores: AtomicI64,
    /// Worker seconds per frame of each profile, from the frames of all its sessions.
    profiles: Mutex<HashMap<String, Ewma>>,
    /// Worker time spent on frames of all sessions (episodes too), microseconds.
    worked_us: AtomicU64,
    /// The server's CPU time per second of worker time.
    overhead: Mutex<Overhead>,
    /// Held while a session is admitted, so two opening at once both see the other.
    admitting: Mutex<()>,
}

/// How much CPU the whole server spends per second its workers score: the gRPC and HTTP
/// threads, the kernels' own threads, the recordings' writer. Sampled every few seconds
/// of wall time from the process's CPU time (`getrusage`) over the workers' time.
#[derive(Debug, Default)]
struct Overhead {
    /// The last sample: when, process CPU seconds, worker microseconds.
    last: Option<(Instant, f64, u64)>,
    factor: Ewma,
}

/// Seconds between two samples of the overhead.
const OVERHEAD_EVERY_S: f64 = 2.0;
/// Worker seconds a sample needs to be counted (less is too little work to tell).
const OVERHEAD_MIN_WORK_S: f64 = 0.5;

impl Overhead {
    /// Whether a sample at `now` would be taken (the first, or one a period after the last).
    fn due(&self, now: Instant) -> bool {
        self.last
            .is_none_or(|(t, _, _)| now.duration_since(t).as_secs_f64() >= OVERHEAD_EVERY_S)
    }

    /// A sample at `now`: the process has used `cpu_s` so far, the workers `worked_us`.
    fn sample(&mut self, now: Instant, cpu_s: f64, worked_us: u64) {
        let Some((_, cpu0, worked0)) = self.last else {
            self.last = Some((now, cpu_s, worked_us));
            return;
        };
        if !self.due(now) {
            return;
        }
        let worked_s = worked_us.saturating_sub(worked0) as f64 * 1e-6;
        if worked_s >= OVERHEAD_MIN_WORK_S {
            self.factor.add(((cpu_s - cpu0) / worked_s).clamp(1.0, 4.0));
        }
        self.last = Some((now, cpu_s, worked_us));
    }

    fn factor(&self) -> f64 {
        self.factor.get().unwrap_or(1.0)
    }
}

/// The process's CPU time so far, seconds (user + system).
fn process_cpu_s() -> Option<f64> {
    // SAFETY: getrusage writes the struct it is given and nothing else.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return None;
    }
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    Some(s(usage.ru_utime) + s(usage.ru_stime))
}

/// A session's part of the pool's load, millicores.
#[derive(Debug, Default)]
pub struct SessionShare(AtomicI64);

impl Capacity {
    /// `workers` scoring workers, of which `fraction` may be promised to live sessions
    /// (0: no admission by load).
    pub fn new(workers: usize, fraction: f64) -> Self {
        Self {
            workers,
            fraction: if fraction.is_finite() {
                fraction.max(0.0)
            } else {
                0.0
            },
            load_millicores: AtomicI64::new(0),
            profiles: Mutex::new(HashMap::new()),
            worked_us: AtomicU64::new(0),
            overhead: Mutex::new(Overhead::default()),
            admitting: Mutex::new(()),
        }
    }

    /// The server's CPU time per second of its workers' time (1 until measured).
    pub fn overhead(&self) -> f64 {
        lock(&self.overhead).factor()
    }

    /// A worker spent `seconds` on a frame (of any session, episodes too).
    pub(super) fn worked(&self, seconds: f64) {
        let us = (seconds.max(0.0) * 1e6) as u64;
        let total = self.worked_us.fetch_add(us, Ordering::Relaxed) + us;
        // One worker samples at a time, the others go on; the process's CPU time is read
        // only when a sample is due, not on every frame.
        let now = Instant::now();
        if let Ok(mut o) = self.overhead.try_lock()
            && o.due(now)
            && let Some(cpu) = process_cpu_s()
        {
            o.sample(now, cpu, total);
        }
    }

    /// The cores live sessions may load.
    pub fn capacity_cores(&self) -> f64 {
        self.workers as f64 * self.fraction
    }

    /// The live sessions' measured load, cores of the whole server's CPU: their workers'
    /// time times the [overhead](Self::overhead).
    pub fn load_cores(&self) -> f64 {
        self.worker_load() * self.overhead()
    }

    /// The live sessions' load in worker time, cores.
    fn worker_load(&self) -> f64 {
        self.load_millicores.load(Ordering::Relaxed).max(0) as f64 * 1e-3
    }

    /// Admits a live session of `profile` whose client sends `rate_hz` (if it says): its
    /// share holds the estimated load until the session's own frames are measured. Or
    /// says why not.
    pub fn admit(&self, profile: &str, rate_hz: Option<f64>) -> Result<SessionShare, OverCapacity> {
        let _one_at_a_time = lock(&self.admitting);
        let overhead = self.overhead();
        let (load, capacity) = (self.worker_load() * overhead, self.capacity_cores());
        if self.fraction <= 0.0 {
            return Ok(SessionShare::default());
        }
        let frame_s = lock(&self.profiles).get(profile).and_then(|e| e.get());
        let refused = |adds: f64, frame_s: f64, rate_hz: f64| OverCapacity {
            load,
            capacity,
            workers: self.workers,
            fraction: self.fraction,
            profile: profile.to_string(),
            adds,
            frame_ms: frame_s * 1e3,
            rate_hz,
            overhead,
        };
        // An idle server refuses no one.
        let idle = load <= 0.0;
        match (frame_s, rate_hz) {
            (Some(frame_s), Some(rate)) => {
                let worker_adds = (frame_s * rate).min(1.0);
                let adds = worker_adds * overhead;
                // More than one worker's time: it could never keep up, even alone.
                if frame_s * rate > 1.0 || (!idle && load + adds > capacity) {
                    return Err(refused(adds, frame_s, rate));
                }
                let reserved = (worker_adds * 1e3).round() as i64;
                self.load_millicores.fetch_add(reserved, Ordering::Relaxed);
                Ok(SessionShare(AtomicI64::new(reserved)))
            }
            // Nothing to estimate with: admitted while the measured load has room.
            _ if idle || load < capacity => Ok(SessionShare::default()),
            _ => Err(refused(0.0, frame_s.unwrap_or(0.0), 0.0)),
        }
    }

    /// A frame of a live session of `profile` took the worker `frame_s`; `load` is the
    /// session's measurement after it. Moves the session's share to its new load.
    pub(super) fn scored(
        &self,
        profile: &str,
        share: &SessionShare,
        load: &SessionLoad,
        frame_s: f64,
    ) {
        lock(&self.profiles)
            .entry(profile.to_string())
            .or_default()
            .add(frame_s);
        if let Some(cores) = load.cores() {
            let new = (cores * 1e3).round() as i64;
            let old = share.0.swap(new, Ordering::Relaxed);
            self.load_millicores.fetch_add(new - old, Ordering::Relaxed);
        }
    }

    /// The session closed: its share leaves the load.
    pub(super) fn release(&self, share: &SessionShare) {
        let old = share.0.swap(0, Ordering::Relaxed);
        self.load_millicores.fetch_sub(old, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn measured(frame_s: f64, interval_s: f64) -> SessionLoad {
        let mut l = SessionLoad::default();
        let t = Instant::now();
        l.arrived(t);
        l.arrived(t + Duration::from_secs_f64(interval_s));
        l.scored(frame_s);
        l
    }

    #[test]
    fn sessions_are_admitted_while_their_measured_load_fits() {
        let cap = Capacity::new(2, 0.8);
        let ten_hz = Some(10.0);
        // An idle server admits anyone; a profile never measured holds nothing.
        let a = cap.admit("p", ten_hz).unwrap();
        assert_eq!(cap.load_cores(), 0.0);
        // 50 ms per frame at 10 Hz: half a core.
        let load = measured(0.05, 0.1);
        cap.scored("p", &a, &load, 0.05);
        assert!((cap.load_cores() - 0.5).abs() < 1e-9);
        // Sessions that say their rate hold their estimate at once, so a burst opening
        // together stops where it fits: a third loads 1.5 of 1.6 cores, a fourth would
        // load 2.0.
        let b = cap.admit("p", ten_hz).unwrap();
        assert!((cap.load_cores() - 1.0).abs() < 1e-9);
        let c = cap.admit("p", ten_hz).unwrap();
        assert!((cap.load_cores() - 1.5).abs() < 1e-9);
        // Measured, a session moves its share, it does not add to it.
        cap.scored("p", &b, &load, 0.05);
        cap.scored("p", &c, &load, 0.05);
        assert!((cap.load_cores() - 1.5).abs() < 1e-9);
        let err = cap.admit("p", ten_hz).unwrap_err();
        assert!(
            (err.load - 1.5).abs() < 1e-9 && (err.adds - 0.5).abs() < 1e-9,
            "{err}"
        );
        let text = err.to_string();
        for part in [
            "1.50 of 1.60 cores",
            "50.0 ms per frame",
            "10.0 Hz",
            "admission_load 0.8",
        ] {
            assert!(text.contains(part), "{part}: {text}");
        }
        // At 2 Hz it fits; a session that does not say its rate is admitted while the
        // measured load is under the capacity.
        let d = cap.admit("p", Some(2.0)).unwrap();
        assert!((cap.load_cores() - 1.6).abs() < 1e-9);
        assert!(
            cap.admit("p", None)
                .unwrap_err()
                .to_string()
                .ends_with("its workers' time)")
        );
        cap.release(&d);
        assert!(cap.admit("p", None).is_ok());
        // Another profile, never measured: admitted while there is room.
        assert!(cap.admit("q", ten_hz).is_ok());
        // A session that closes gives its share back, once.
        cap.release(&c);
        cap.release(&c);
        assert!((cap.load_cores() - 1.0).abs() < 1e-9);
        // Re-measured sessions move their share.
        cap.scored("p", &a, &measured(0.01, 0.1), 0.01);
        assert!(
            (cap.load_cores() - 0.6).abs() < 1e-9,
            "{}",
            cap.load_cores()
        );
        // On an idle server a burst of sessions of a measured profile holds its estimates
        // from the first, so it stops where it fits.
        let burst = Capacity::new(2, 0.8);
        let m = SessionShare::default();
        burst.scored("p", &m, &load, 0.05);
        burst.release(&m);
        assert_eq!(burst.load_cores(), 0.0);
        let admitted: Vec<_> = (0..6)
            .map_while(|_| burst.admit("p", ten_hz).ok())
            .collect();
        assert_eq!(admitted.len(), 3, "0.5 core each: 1.5 of 1.6 cores");
        // One session loads at most a core, however fast it sends.
        let bursty = SessionShare::default();
        let one = Capacity::new(1, 0.5);
        one.scored("p", &bursty, &measured(0.05, 0.001), 0.05);
        assert!((one.load_cores() - 1.0).abs() < 1e-9);
        assert!(one.admit("p", Some(15.0)).unwrap_err().adds <= 1.0);
        one.release(&bursty);
        assert!(one.admit("p", Some(15.0)).is_ok());
        // A rate no worker can hold (50 ms per frame at 30 Hz) is refused even on an
        // idle server, and says so.
        let never_measured = Capacity::new(2, 0.8);
        assert!(never_measured.admit("p", Some(30.0)).is_ok());
        let far = one.admit("p", Some(30.0)).unwrap_err().to_string();
        assert!(
            far.contains("needs 1.50 cores") && far.contains("no server can keep it"),
            "{far}"
        );
        // admission_load = 0: never refused.
        let off = Capacity::new(2, 0.0);
        off.scored("p", &a, &measured(1.0, 0.1), 1.0);
        assert!(off.admit("p", ten_hz).is_ok());
    }

    #[test]
    fn the_overhead_is_the_process_cpu_over_the_workers_time() {
        let mut o = Overhead::default();
        let t = Instant::now();
        let at = |s: f64| t + Duration::from_secs_f64(s);
        assert_eq!(o.factor(), 1.0);
        o.sample(at(0.0), 10.0, 0);
        // Too soon, then too little work: no figure.
        o.sample(at(1.0), 11.0, 900_000);
        o.sample(at(2.5), 11.0, 100_000);
        assert_eq!(o.factor(), 1.0);
        // 3 s of CPU for 2 s of scoring.
        o.sample(at(5.0), 14.0, 2_100_000);
        assert!((o.factor() - 1.5).abs() < 1e-9, "{}", o.factor());
        // The load and the admission count it.
        let cap = Capacity::new(2, 0.8);
        let a = cap.admit("p", Some(10.0)).unwrap();
        cap.scored("p", &a, &measured(0.05, 0.1), 0.05);
        *lock(&cap.overhead) = o;
        assert!((cap.load_cores() - 0.75).abs() < 1e-9);
        let b = cap.admit("p", Some(10.0)).unwrap();
        assert!((cap.load_cores() - 1.5).abs() < 1e-9);
        let err = cap.admit("p", Some(10.0)).unwrap_err();
        assert!((err.adds - 0.75).abs() < 1e-9, "{err}");
        assert!(err.to_string().contains("1.50x its workers' time"), "{err}");
        cap.release(&b);
        // A real sample: the process has used some CPU.
        assert!(process_cpu_s().is_some_and(|s| s > 0.0));
    }

    #[test]
    fn the_averages_ignore_nonsense_and_follow_recent_samples() {
        let mut e = Ewma::default();
        e.add(f64::NAN);
        e.add(-1.0);
        assert_eq!(e.get(), None);
        e.add(1.0);
        for _ in 0..100 {
            e.add(2.0);
        }
        assert!((e.get().unwrap() - 2.0).abs() < 1e-3);
    }
}
