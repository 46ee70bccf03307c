//! Byte budgets: one count of the bytes that clients can make the server hold, against
//! a limit. The memory budget counts buffered images, joint states and images being
//! decoded; the upload budget counts the temporary disk of uploads. Work that would take
//! a count past its limit is refused with [`BudgetSpent`], a clear error, instead of
//! being allocated or written. A [`Charge`] gives its bytes back when dropped, so buffers
//! emptied on any path (scored, dropped, closed, failed) release what they held.

use prometheus::IntGauge;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use vamos_core::episode::{DecodeBudget, Reserved};

/// Refused: the budget cannot take `needed` more bytes.
#[derive(Debug, Clone, thiserror::Error)]
#[error(
    "the server's {what} is spent: {} more needed, {} of {} in use",
    mib(*needed), mib(*used), mib(*limit)
)]
pub struct BudgetSpent {
    /// Which budget (`memory budget`, `upload disk budget`).
    pub what: &'static str,
    /// Bytes asked for.
    pub needed: u64,
    /// Bytes held when asked.
    pub used: u64,
    /// The budget.
    pub limit: u64,
}

fn mib(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / f64::from(1 << 20))
}

/// A budget: a limit and the bytes charged against it.
#[derive(Debug)]
pub struct ByteBudget {
    what: &'static str,
    limit: u64,
    used: AtomicU64,
    gauge: IntGauge,
}

impl ByteBudget {
    /// A budget of `limit` bytes, named `what` in refusals, whose use is mirrored in
    /// `gauge`.
    pub fn new(what: &'static str, limit: u64, gauge: IntGauge) -> Arc<Self> {
        Arc::new(Self {
            what,
            limit,
            used: AtomicU64::new(0),
            gauge,
        })
    }

    /// The limit, bytes.
    pub fn limit(&self) -> u64 {
        self.limit
    }

    /// Bytes charged now.
    pub fn used(&self) -> u64 {
        self.used.load(Ordering::Relaxed)
    }

    fn take(&self, bytes: u64) -> Result<(), BudgetSpent> {
        let mut used = self.used.load(Ordering::Relaxed);
        loop {
            let next = used.saturating_add(bytes);
            if next > self.limit {
                return Err(BudgetSpent {
                    what: self.what,
                    needed: bytes,
                    used,
                    limit: self.limit,
                });
            }
            match self
                .used
                .compare_exchange_weak(used, next, Ordering::AcqRel, Ordering::Relaxed)
            {
                Ok(_) => break,
                Err(now) => used = now,
            }
        }
        self.gauge.add(bytes as i64);
        Ok(())
    }

    fn give(&self, bytes: u64) {
        self.used.fetch_sub(bytes, Ordering::AcqRel);
        self.gauge.sub(bytes as i64);
    }

    /// Charges `bytes`, or says why not.
    pub fn charge(self: &Arc<Self>, bytes: u64) -> Result<Charge, BudgetSpent> {
        self.take(bytes)?;
        Ok(Charge {
            budget: self.clone(),
            bytes,
        })
    }

    /// An empty charge, to be grown with [`Charge::resize`].
    pub fn empty(self: &Arc<Self>) -> Charge {
        Charge {
            budget: self.clone(),
            bytes: 0,
        }
    }
}

/// Bytes charged to a [`ByteBudget`], given back on drop.
#[derive(Debug)]
pub struct Charge {
    budget: Arc<ByteBudget>,
    bytes: u64,
}

impl Charge {
    /// The bytes held.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// Makes the charge `bytes`: shrinking always succeeds; growing is refused (and the
    /// charge left as it was) when the budget cannot take the difference.
    pub fn resize(&mut self, bytes: u64) -> Result<(), BudgetSpent> {
        if bytes > self.bytes {
            self.budget.take(bytes - self.bytes)?;
        } else {
            self.budget.give(self.bytes - bytes);
        }
        self.bytes = bytes;
        Ok(())
    }
}

impl Drop for Charge {
    fn drop(&mut self) {
        self.budget.give(self.bytes);
    }
}

/// A charge held by a frame and its clones ([`Reserved`]), given back when the last
/// one drops.
#[derive(Debug)]
pub struct SharedCharge(std::sync::Mutex<Charge>);

impl SharedCharge {
    /// `charge`, to share.
    pub fn new(charge: Charge) -> Arc<Self> {
        Arc::new(Self(std::sync::Mutex::new(charge)))
    }
}

impl Reserved for SharedCharge {
    fn resize(&self, bytes: u64) {
        let mut charge = self.0.lock().unwrap_or_else(|e| e.into_inner());
        // Shrinking always succeeds; growing past the budget keeps the charge as it was.
        let _ = charge.resize(bytes);
    }
}

/// How long an episode's image decoding waits for room in the memory budget before it
/// is refused (the frame is reported as refused, the episode goes on).
pub const DECODE_WAIT: std::time::Duration = std::time::Duration::from_secs(10);

/// The memory budget as an episode reader's [`DecodeBudget`]: an image's decoding waits
/// for room (frames being scored give theirs back) for up to `wait`, then is refused, as
/// a decoding larger than the whole budget is at once.
#[derive(Debug)]
pub struct DecodeRoom {
    budget: Arc<ByteBudget>,
    wait: std::time::Duration,
}

impl DecodeRoom {
    /// Decodings within `budget`, each waiting up to `wait` for room.
    pub fn new(budget: Arc<ByteBudget>, wait: std::time::Duration) -> Arc<Self> {
        Arc::new(Self { budget, wait })
    }
}

impl DecodeBudget for DecodeRoom {
    fn reserve(&self, bytes: u64) -> Result<Arc<dyn Reserved>, String> {
        if bytes > self.budget.limit() {
            return Err(format!(
                "decoding it takes {bytes} bytes, more than the server's whole memory budget \
                 of {} ([service] memory_budget_mb)",
                self.budget.limit()
            ));
        }
        let deadline = std::time::Instant::now() + self.wait;
        loop {
            match self.budget.charge(bytes) {
                Ok(c) => return Ok(SharedCharge::new(c)),
                Err(e) if std::time::Instant::now() >= deadline => {
                    return Err(format!("{e} ([service] memory_budget_mb)"));
                }
                Err(_) => std::thread::sleep(std::time::Duration::from_millis(20)),
            }
        }
    }
}

/// Uploads in progress: at most `max_uploads` at once, their temporary files within the
/// upload disk budget. Admission comes before the first byte is read. Uploads a robot
/// token may send (episodes to score) hold at most all slots but one, so the admin
/// plane (models, robots, calibrations) always has one. An upload whose average rate
/// since admission falls below the minimum (after a grace period) is cut, so a client
/// that trickles bytes cannot hold a slot either.
#[derive(Debug)]
pub struct Uploads {
    slots: Arc<tokio::sync::Semaphore>,
    robot_slots: Arc<tokio::sync::Semaphore>,
    max: usize,
    disk: Arc<ByteBudget>,
    min_rate: MinRate,
}

/// The slowest an upload may be: after `grace`, its average since admission at least
/// `bytes_per_s`.
#[derive(Debug, Clone, Copy)]
pub struct MinRate {
    /// Bytes per second.
    pub bytes_per_s: u64,
    /// Time an upload has before the rate is checked.
    pub grace: std::time::Duration,
}

/// Who may send an upload: decides which slots it may take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UploadPlane {
    /// An upload a robot token may send (an episode to score): all slots but one.
    Robot,
    /// An admin-only upload (a model, a robot, calibration episodes): any slot.
    Admin,
}

/// Why an upload was not admitted.
#[derive(Debug, Clone, thiserror::Error)]
pub enum UploadRefused {
    /// `max_uploads` are in progress.
    #[error(
        "the server has its maximum of {max} uploads in progress ([service] max_uploads); retry later"
    )]
    Busy {
        /// The limit.
        max: usize,
    },
    /// The temporary disk of uploads is spent.
    #[error("{0} ([service] max_upload_disk_mb); retry later")]
    Disk(#[from] BudgetSpent),
    /// The upload came slower than the minimum rate.
    #[error(
        "the upload is too slow: {received} bytes in {seconds:.0} s, below the minimum of \
         {min_bytes_per_s} bytes/s ([service] min_upload_rate_kib_s)"
    )]
    TooSlow {
        /// Bytes received.
        received: u64,
        /// Seconds since admission.
        seconds: f64,
        /// The minimum rate.
        min_bytes_per_s: u64,
    },
}

/// An admitted upload: its slots and the disk its file holds, both given back on drop.
#[derive(Debug)]
pub struct UploadTicket {
    _slots: (
        tokio::sync::OwnedSemaphorePermit,
        Option<tokio::sync::OwnedSemaphorePermit>,
    ),
    disk: Charge,
    admitted: std::time::Instant,
    min_rate: MinRate,
}

impl UploadTicket {
    /// Charges `bytes` more of the file's growth (past what was declared at admission).
    pub fn written(&mut self, total: u64) -> Result<(), UploadRefused> {
        if total > self.disk.bytes() {
            self.disk.resize(total)?;
        }
        Ok(())
    }

    /// `total` bytes of the body received so far: refused when the average rate since
    /// admission is below the minimum after the grace period.
    pub fn received(&mut self, total: u64) -> Result<(), UploadRefused> {
        let elapsed = self.admitted.elapsed();
        let floor = self.min_rate.bytes_per_s as f64 * elapsed.as_secs_f64();
        if elapsed > self.min_rate.grace && (total as f64) < floor {
            return Err(UploadRefused::TooSlow {
                received: total,
                seconds: elapsed.as_secs_f64(),
                min_bytes_per_s: self.min_rate.bytes_per_s,
            });
        }
        Ok(())
    }

    /// Makes the disk the ticket holds exactly `total` bytes (a file replaced by another).
    pub fn holds(&mut self, total: u64) -> Result<(), UploadRefused> {
        Ok(self.disk.resize(total)?)
    }
}

impl Uploads {
    /// At most `max` uploads at once, `disk_limit` bytes of temporary files, the disk in
    /// use mirrored in `gauge`, each upload at least `min_rate` fast.
    pub fn new(max: usize, disk_limit: u64, gauge: IntGauge, min_rate: MinRate) -> Self {
        Self {
            slots: Arc::new(tokio::sync::Semaphore::new(max)),
            robot_slots: Arc::new(tokio::sync::Semaphore::new(max.saturating_sub(1).max(1))),
            max,
            disk: ByteBudget::new("upload disk budget", disk_limit, gauge),
            min_rate,
        }
    }

    /// Admits an upload of `plane` that declares `declared` bytes (the whole declared size
    /// is charged at once), or says why not.
    pub fn admit(
        &self,
        plane: UploadPlane,
        declared: Option<u64>,
    ) -> Result<UploadTicket, UploadRefused> {
        let busy = |_| UploadRefused::Busy { max: self.max };
        let robot_slot = match plane {
            UploadPlane::Robot => Some(self.robot_slots.clone().try_acquire_owned().map_err(busy)?),
            UploadPlane::Admin => None,
        };
        let slot = self.slots.clone().try_acquire_owned().map_err(busy)?;
        let disk = self.disk.charge(declared.unwrap_or(0))?;
        Ok(UploadTicket {
            _slots: (slot, robot_slot),
            disk,
            admitted: std::time::Instant::now(),
            min_rate: self.min_rate,
        })
    }
}

/// The upload disk budget when `[service] max_upload_disk_mb` is 0: a quarter of the free
/// space of the file system that holds `dir` (the data directory) when the server starts,
/// between 256 MiB and 32 GiB; 32 GiB where the free space cannot be read.
pub fn default_upload_disk(dir: &std::path::Path) -> u64 {
    free_bytes(dir).map_or(32 << 30, |free| (free / 4).clamp(256 << 20, 32 << 30))
}

/// Bytes an unprivileged process may still write on the file system that holds `dir`.
#[cfg(unix)]
fn free_bytes(dir: &std::path::Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let path = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    // SAFETY: `path` is a NUL-terminated string that outlives the call; `stat` is plain
    // data that statvfs fills in.
    let stat = unsafe {
        let mut stat: libc::statvfs = std::mem::zeroed();
        if libc::statvfs(path.as_ptr(), &mut stat) != 0 {
            return None;
        }
        stat
    };
    Some((stat.f_bavail as u64).saturating_mul(stat.f_frsize as u64))
}

#[cfg(not(unix))]
fn free_bytes(_: &std::path::Path) -> Option<u64> {
    None
}

/// The default budget when `[service] memory_budget_mb` is 0: half of the memory this
/// process may use (the cgroup's limit when one is set, else the machine's), at least
/// 256 MiB; 2 GiB where neither can be read.
pub fn default_limit() -> u64 {
    let cgroup = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok());
    let total = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| {
        s.lines()
            .find_map(|l| l.strip_prefix("MemTotal:"))
            .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
            .map(|kb| kb * 1024)
    });
    match (cgroup, total) {
        (Some(c), Some(t)) => c.min(t) / 2,
        (Some(m), None) | (None, Some(m)) => m / 2,
        (None, None) => 2 << 30,
    }
    .max(256 << 20)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charges_are_refused_past_the_limit_and_given_back_on_drop() {
        let gauge = IntGauge::new("t", "t").unwrap_or_else(|e| panic!("{e}"));
        let b = ByteBudget::new("memory budget", 100, gauge.clone());
        let a = b.charge(60).unwrap_or_else(|e| panic!("{e}"));
        let err = b.charge(50).unwrap_err();
        assert_eq!((err.needed, err.used, err.limit), (50, 60, 100));
        assert!(err.to_string().contains("memory budget is spent"), "{err}");
        let mut c = b.empty();
        c.resize(40).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!((b.used(), gauge.get()), (100, 100));
        assert!(c.resize(41).is_err());
        assert_eq!(c.bytes(), 40);
        c.resize(10).unwrap_or_else(|e| panic!("{e}"));
        drop(a);
        assert_eq!((b.used(), gauge.get()), (10, 10));
        drop(c);
        assert_eq!((b.used(), gauge.get()), (0, 0));
        assert!(default_limit() >= 256 << 20);
    }

    #[test]
    fn uploads_are_admitted_up_to_their_count_and_disk() {
        let gauge = IntGauge::new("u", "u").unwrap_or_else(|e| panic!("{e}"));
        let uploads = Uploads::new(2, 1000, gauge.clone(), NO_MIN_RATE);
        let mut a = uploads
            .admit(UploadPlane::Admin, Some(600))
            .unwrap_or_else(|e| panic!("{e}"));
        let err = uploads.admit(UploadPlane::Admin, Some(500)).unwrap_err();
        assert!(matches!(err, UploadRefused::Disk(_)), "{err}");
        let mut b = uploads
            .admit(UploadPlane::Admin, None)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(matches!(
            uploads.admit(UploadPlane::Admin, None),
            Err(UploadRefused::Busy { max: 2 })
        ));
        a.written(600).unwrap_or_else(|e| panic!("{e}"));
        b.written(300).unwrap_or_else(|e| panic!("{e}"));
        let err = b.written(500).unwrap_err();
        assert!(err.to_string().contains("upload disk budget"), "{err}");
        assert_eq!(gauge.get(), 900);
        drop((a, b));
        assert_eq!(gauge.get(), 0);
        assert!(uploads.admit(UploadPlane::Admin, Some(1000)).is_ok());
    }

    #[test]
    fn the_default_upload_disk_is_a_quarter_of_the_free_space_within_bounds() {
        let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
        let free = free_bytes(dir.path()).unwrap_or_else(|| panic!("no free space read"));
        assert!(free > 0);
        assert_eq!(
            default_upload_disk(dir.path()),
            (free / 4).clamp(256 << 20, 32 << 30)
        );
        assert_eq!(default_upload_disk(&dir.path().join("missing")), 32 << 30);
    }

    const NO_MIN_RATE: MinRate = MinRate {
        bytes_per_s: 0,
        grace: std::time::Duration::ZERO,
    };

    #[test]
    fn robot_uploads_leave_one_slot_to_the_admin_plane() {
        let gauge = IntGauge::new("r", "r").unwrap_or_else(|e| panic!("{e}"));
        let uploads = Uploads::new(3, 1000, gauge, NO_MIN_RATE);
        let robot = |u: &Uploads| u.admit(UploadPlane::Robot, None);
        let a = robot(&uploads).unwrap_or_else(|e| panic!("{e}"));
        let _b = robot(&uploads).unwrap_or_else(|e| panic!("{e}"));
        assert!(matches!(
            robot(&uploads),
            Err(UploadRefused::Busy { max: 3 })
        ));
        let admin = uploads
            .admit(UploadPlane::Admin, None)
            .unwrap_or_else(|e| panic!("{e}"));
        assert!(uploads.admit(UploadPlane::Admin, None).is_err());
        drop(admin);
        drop(a);
        assert!(robot(&uploads).is_ok());
        // One slot in all: a robot may take it (there is nothing to keep).
        let one = Uploads::new(
            1,
            1000,
            IntGauge::new("o", "o").unwrap_or_else(|e| panic!("{e}")),
            NO_MIN_RATE,
        );
        assert!(robot(&one).is_ok());
    }

    #[test]
    fn an_upload_below_the_minimum_rate_is_cut_after_its_grace() {
        let gauge = IntGauge::new("s", "s").unwrap_or_else(|e| panic!("{e}"));
        let rate = MinRate {
            bytes_per_s: 1000,
            grace: std::time::Duration::from_millis(50),
        };
        let uploads = Uploads::new(2, 1 << 20, gauge, rate);
        let mut t = uploads
            .admit(UploadPlane::Robot, None)
            .unwrap_or_else(|e| panic!("{e}"));
        // Within the grace any rate passes.
        t.received(1).unwrap_or_else(|e| panic!("{e}"));
        std::thread::sleep(std::time::Duration::from_millis(120));
        // 120 ms at 1000 B/s is 120 bytes: 10 is too slow, 1000 is not.
        let err = t.received(10).unwrap_err();
        assert!(
            matches!(err, UploadRefused::TooSlow { received: 10, .. }),
            "{err}"
        );
        assert!(err.to_string().contains("min_upload_rate_kib_s"), "{err}");
        t.received(1000).unwrap_or_else(|e| panic!("{e}"));
    }
}
