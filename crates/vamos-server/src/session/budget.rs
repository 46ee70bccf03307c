//! Byte budgets: one count of the bytes that clients can make the server hold, against
//! a limit. The memory budget counts buffered images, joint states and images being
//! decoded; the upload budget counts the temporary disk of uploads. Work that would take
//! a count past its limit is refused with [`BudgetSpent`], a clear error, instead of
//! being allocated or written. A [`Charge`] gives its bytes back when dropped, so buffers
//! emptied on any path (scored, dropped, closed, failed) release what they held.

use prometheus::IntGauge;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

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

/// Uploads in progress: at most `max_uploads` at once, their temporary files within the
/// upload disk budget. Admission comes before the first byte is read.
#[derive(Debug)]
pub struct Uploads {
    slots: Arc<tokio::sync::Semaphore>,
    max: usize,
    disk: Arc<ByteBudget>,
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
}

/// An admitted upload: its slot and the disk its file holds, both given back on drop.
#[derive(Debug)]
pub struct UploadTicket {
    _slot: tokio::sync::OwnedSemaphorePermit,
    disk: Charge,
}

impl UploadTicket {
    /// Charges `bytes` more of the file's growth (past what was declared at admission).
    pub fn written(&mut self, total: u64) -> Result<(), UploadRefused> {
        if total > self.disk.bytes() {
            self.disk.resize(total)?;
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
    /// use mirrored in `gauge`.
    pub fn new(max: usize, disk_limit: u64, gauge: IntGauge) -> Self {
        Self {
            slots: Arc::new(tokio::sync::Semaphore::new(max)),
            max,
            disk: ByteBudget::new("upload disk budget", disk_limit, gauge),
        }
    }

    /// Admits an upload that declares `declared` bytes (the whole declared size is
    /// charged at once), or says why not.
    pub fn admit(&self, declared: Option<u64>) -> Result<UploadTicket, UploadRefused> {
        let slot = self
            .slots
            .clone()
            .try_acquire_owned()
            .map_err(|_| UploadRefused::Busy { max: self.max })?;
        let disk = self.disk.charge(declared.unwrap_or(0))?;
        Ok(UploadTicket { _slot: slot, disk })
    }
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
        let uploads = Uploads::new(2, 1000, gauge.clone());
        let mut a = uploads.admit(Some(600)).unwrap_or_else(|e| panic!("{e}"));
        let err = uploads.admit(Some(500)).unwrap_err();
        assert!(matches!(err, UploadRefused::Disk(_)), "{err}");
        let mut b = uploads.admit(None).unwrap_or_else(|e| panic!("{e}"));
        assert!(matches!(
            uploads.admit(None),
            Err(UploadRefused::Busy { max: 2 })
        ));
        a.written(600).unwrap_or_else(|e| panic!("{e}"));
        b.written(300).unwrap_or_else(|e| panic!("{e}"));
        let err = b.written(500).unwrap_err();
        assert!(err.to_string().contains("upload disk budget"), "{err}");
        assert_eq!(gauge.get(), 900);
        drop((a, b));
        assert_eq!(gauge.get(), 0);
        assert!(uploads.admit(Some(1000)).is_ok());
    }
}
