//! Finding, provisioning and loading the ONNX Runtime shared library.
//!
//! `ort` is built with `load-dynamic`: nothing is downloaded at build time, the library is
//! opened at run time. [`ensure`] looks for it in this order:
//! 1. `ORT_DYLIB_PATH` (a file; an error if set but missing: the user asked for it);
//! 2. a `lib/` folder beside the running binary (`libonnxruntime.so*`);
//! 3. the vamos cache: `$VAMOS_CACHE_DIR`, else `$XDG_CACHE_HOME/vamos`, else
//!    `~/.cache/vamos`, under `onnxruntime/<ORT_VERSION>/`;
//! 4. the Python `onnxruntime` package (`python3`, `onnxruntime/capi/`), unless disabled.
//!
//! When none is found and provisioning is allowed, it runs
//! `python3 -m pip download onnxruntime==<ORT_VERSION> --no-deps --only-binary=:all:`,
//! extracts `onnxruntime/capi/libonnxruntime.so.<ORT_VERSION>` from the wheel into a
//! temporary folder in the cache and renames it into place (atomic: a concurrent process
//! sees the whole file or none). The environment is initialised once per process.

use std::ffi::OsString;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Mutex, OnceLock};
use std::time::Instant;

/// The ONNX Runtime version vamos provisions and was tested with.
pub const ORT_VERSION: &str = "1.31.1";
/// The oldest ONNX Runtime minor version (1.x) the `ort` API level built in accepts.
pub const ORT_MIN_MINOR: u32 = 24;
/// The variable that names the library file explicitly.
pub const ORT_DYLIB_ENV: &str = "ORT_DYLIB_PATH";
/// The variable that names the vamos cache folder.
pub const CACHE_ENV: &str = "VAMOS_CACHE_DIR";
/// The largest library file accepted from a wheel (the 1.31 CPU library is ~22 MB).
const MAX_LIBRARY_BYTES: u64 = 512 << 20;

/// Errors of finding or loading the ONNX Runtime library.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    /// `ORT_DYLIB_PATH` names a file that does not exist.
    #[error(
        "ORT_DYLIB_PATH={path} does not exist; point it at libonnxruntime.so (ONNX Runtime >= 1.{ORT_MIN_MINOR}) or unset it"
    )]
    EnvPathMissing {
        /// The variable's value.
        path: String,
    },
    /// No library was found and provisioning is disabled.
    #[error(
        "ONNX Runtime {ORT_VERSION} not found (looked in: {searched}); set ORT_DYLIB_PATH to libonnxruntime.so, `pip install onnxruntime=={ORT_VERSION}`, or enable [model] ort_provision"
    )]
    NotFound {
        /// The places searched.
        searched: String,
    },
    /// Downloading or unpacking the wheel failed.
    #[error(
        "could not provision ONNX Runtime {ORT_VERSION} into {cache_dir}: {reason}. Install it yourself (`pip install onnxruntime=={ORT_VERSION}`) or set ORT_DYLIB_PATH to libonnxruntime.so"
    )]
    Provision {
        /// The cache folder.
        cache_dir: String,
        /// What failed.
        reason: String,
    },
    /// No cache folder can be determined (no VAMOS_CACHE_DIR, XDG_CACHE_HOME or HOME).
    #[error("no cache folder for ONNX Runtime: set VAMOS_CACHE_DIR or ORT_DYLIB_PATH")]
    NoCacheDir,
    /// The library exists but could not be loaded (wrong version, wrong architecture...).
    #[error("cannot load ONNX Runtime from {path}: {reason}")]
    Load {
        /// The library file.
        path: String,
        /// The loader's message.
        reason: String,
    },
}

/// Where the library was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RuntimeSource {
    /// `ORT_DYLIB_PATH`.
    EnvVar,
    /// `lib/` beside the binary.
    BesideBinary,
    /// The vamos cache.
    Cache,
    /// The Python `onnxruntime` package.
    PythonPackage,
    /// Downloaded into the cache by this process.
    Provisioned,
}

impl RuntimeSource {
    /// Where the library came from, in words (what a first run prints).
    pub fn describe(self) -> &'static str {
        match self {
            Self::EnvVar => "ORT_DYLIB_PATH",
            Self::BesideBinary => "lib/ beside the binary",
            Self::Cache => "the vamos cache",
            Self::PythonPackage => "the Python onnxruntime package",
            Self::Provisioned => "downloaded from PyPI into the vamos cache by this run",
        }
    }
}

/// Which sources [`ensure`] may use besides the environment variable, binary folder and cache.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RuntimeOptions {
    /// Download the wheel into the cache when nothing is found.
    pub provision: bool,
    /// Look in the Python `onnxruntime` package.
    pub use_python_package: bool,
}

impl Default for RuntimeOptions {
    fn default() -> Self {
        Self {
            provision: true,
            use_python_package: true,
        }
    }
}

/// The loaded runtime: the library path, where it came from, and the `ort` environment.
#[derive(Debug)]
pub struct Runtime {
    /// The library file.
    pub path: PathBuf,
    /// Where it was found.
    pub source: RuntimeSource,
    /// Seconds spent finding (and provisioning) and loading it.
    pub setup_secs: f64,
    /// The `ort` environment every session is built in.
    pub environment: ort::environment::Environment,
}

/// The places to look, gathered from the process environment (or given by tests).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SearchPaths {
    /// `ORT_DYLIB_PATH`, when set and non-empty.
    pub env_path: Option<PathBuf>,
    /// The folder of the running binary.
    pub exe_dir: Option<PathBuf>,
    /// The vamos cache folder.
    pub cache_dir: Option<PathBuf>,
}

impl SearchPaths {
    /// The paths of this process.
    pub fn from_process() -> Self {
        let var = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
        Self {
            env_path: var(ORT_DYLIB_ENV).map(PathBuf::from),
            exe_dir: std::env::current_exe()
                .ok()
                .and_then(|p| p.parent().map(Path::to_path_buf)),
            cache_dir: cache_dir_from(var(CACHE_ENV), var("XDG_CACHE_HOME"), var("HOME")),
        }
    }
}

/// The vamos cache folder: `$VAMOS_CACHE_DIR`, else `$XDG_CACHE_HOME/vamos`, else
/// `$HOME/.cache/vamos`.
pub fn cache_dir_from(
    vamos_cache: Option<OsString>,
    xdg_cache_home: Option<OsString>,
    home: Option<OsString>,
) -> Option<PathBuf> {
    vamos_cache
        .map(PathBuf::from)
        .or_else(|| xdg_cache_home.map(|x| PathBuf::from(x).join("vamos")))
        .or_else(|| home.map(|h| PathBuf::from(h).join(".cache").join("vamos")))
}

/// The library's place inside the cache folder.
pub fn cached_library(cache_dir: &Path) -> PathBuf {
    cache_dir
        .join("onnxruntime")
        .join(ORT_VERSION)
        .join(format!("libonnxruntime.so.{ORT_VERSION}"))
}

/// The 1.x minor version in a file name like `libonnxruntime.so.1.31.1` (None: no version).
fn minor_of(name: &str) -> Option<u32> {
    let rest = name.strip_prefix("libonnxruntime.so.")?;
    let mut parts = rest.split('.');
    (parts.next()? == "1").then_some(())?;
    parts.next()?.parse().ok()
}

/// The best `libonnxruntime.so*` in a folder: the newest versioned file with minor >=
/// [`ORT_MIN_MINOR`], else an unversioned `libonnxruntime.so`.
pub fn library_in(dir: &Path) -> Option<PathBuf> {
    let entries = std::fs::read_dir(dir).ok()?;
    let mut best: Option<(u32, PathBuf)> = None;
    let mut plain = None;
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if name == "libonnxruntime.so" {
            plain = Some(e.path());
        } else if let Some(minor) = minor_of(&name)
            && minor >= ORT_MIN_MINOR
            && best.as_ref().is_none_or(|(m, _)| minor > *m)
        {
            best = Some((minor, e.path()));
        }
    }
    best.map(|(_, p)| p).or(plain)
}

/// Resolution without side effects: the first library found, in the documented order.
/// `python_capi` is asked only when the earlier places hold nothing (it starts Python).
pub fn resolve(
    paths: &SearchPaths,
    python_capi: impl FnOnce() -> Option<PathBuf>,
) -> Result<Option<(PathBuf, RuntimeSource)>, RuntimeError> {
    if let Some(p) = &paths.env_path {
        if p.is_file() {
            return Ok(Some((p.clone(), RuntimeSource::EnvVar)));
        }
        return Err(RuntimeError::EnvPathMissing {
            path: p.display().to_string(),
        });
    }
    if let Some(found) = paths
        .exe_dir
        .as_ref()
        .and_then(|d| library_in(&d.join("lib")))
    {
        return Ok(Some((found, RuntimeSource::BesideBinary)));
    }
    if let Some(cache) = &paths.cache_dir {
        let p = cached_library(cache);
        if p.is_file() {
            return Ok(Some((p, RuntimeSource::Cache)));
        }
    }
    if let Some(found) = python_capi().and_then(|d| library_in(&d)) {
        return Ok(Some((found, RuntimeSource::PythonPackage)));
    }
    Ok(None)
}

/// The `capi/` folder of `python3`'s `onnxruntime` package, if it has one.
pub fn python_capi_dir() -> Option<PathBuf> {
    let out = Command::new(python())
        .args([
            "-c",
            "import onnxruntime, os; print(os.path.dirname(onnxruntime.__file__))",
        ])
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let dir = String::from_utf8(out.stdout).ok()?;
    let capi = PathBuf::from(dir.trim()).join("capi");
    capi.is_dir().then_some(capi)
}

fn python() -> OsString {
    std::env::var_os("VAMOS_PYTHON")
        .filter(|v| !v.is_empty())
        .unwrap_or_else(|| "python3".into())
}

/// Downloads the `onnxruntime` wheel with pip and installs its library into the cache.
/// Returns the library path.
pub fn provision(cache_dir: &Path) -> Result<PathBuf, RuntimeError> {
    let fail = |reason: String| RuntimeError::Provision {
        cache_dir: cache_dir.display().to_string(),
        reason,
    };
    let target = cached_library(cache_dir);
    let version_dir = target
        .parent()
        .ok_or_else(|| fail("cache path has no parent".into()))?
        .to_path_buf();
    let root = cache_dir.join("onnxruntime");
    std::fs::create_dir_all(&root)
        .map_err(|e| fail(format!("cannot create {}: {e}", root.display())))?;
    let tmp = root.join(format!(".tmp-{}-{}", std::process::id(), unique()));
    std::fs::create_dir_all(&tmp)
        .map_err(|e| fail(format!("cannot create {}: {e}", tmp.display())))?;
    let result = provision_into(&tmp, &version_dir, &target);
    let _ = std::fs::remove_dir_all(&tmp);
    result.map_err(fail)
}

fn unique() -> u128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos())
}

fn provision_into(tmp: &Path, version_dir: &Path, target: &Path) -> Result<PathBuf, String> {
    let python = python();
    tracing::warn!(
        version = ORT_VERSION,
        cache = %version_dir.display(),
        "ONNX Runtime not found: downloading the onnxruntime wheel from PyPI with pip"
    );
    let wheel_dir = tmp.join("wheel");
    let out = Command::new(&python)
        .args(["-m", "pip", "download"])
        .arg(format!("onnxruntime=={ORT_VERSION}"))
        .args([
            "--no-deps",
            "--only-binary=:all:",
            "--disable-pip-version-check",
            "-q",
            "-d",
        ])
        .arg(&wheel_dir)
        .output()
        .map_err(|e| {
            format!(
                "cannot run `{} -m pip` ({e}); install Python 3 with pip",
                python.to_string_lossy()
            )
        })?;
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        return Err(format!(
            "`pip download onnxruntime=={ORT_VERSION}` failed ({}): {}",
            out.status,
            stderr.trim().lines().last().unwrap_or("no output")
        ));
    }
    let wheel = std::fs::read_dir(&wheel_dir)
        .map_err(|e| format!("cannot list {}: {e}", wheel_dir.display()))?
        .flatten()
        .map(|e| e.path())
        .find(|p| p.extension().is_some_and(|x| x == "whl"))
        .ok_or_else(|| "pip downloaded no wheel".to_string())?;
    let file = std::fs::File::open(&wheel).map_err(|e| format!("cannot open the wheel: {e}"))?;
    let mut zip = zip::ZipArchive::new(file).map_err(|e| format!("the wheel is not a zip: {e}"))?;
    let member = format!("onnxruntime/capi/libonnxruntime.so.{ORT_VERSION}");
    let mut entry = zip
        .by_name(&member)
        .map_err(|e| format!("the wheel has no {member}: {e}"))?;
    if entry.size() > MAX_LIBRARY_BYTES {
        return Err(format!("{member} is {} bytes, refusing", entry.size()));
    }
    let staged_dir = tmp.join("staged");
    std::fs::create_dir_all(&staged_dir).map_err(|e| e.to_string())?;
    let staged = staged_dir.join(
        target
            .file_name()
            .ok_or_else(|| "target has no file name".to_string())?,
    );
    let mut bytes = Vec::new();
    (&mut entry)
        .take(MAX_LIBRARY_BYTES + 1)
        .read_to_end(&mut bytes)
        .map_err(|e| format!("cannot unpack {member}: {e}"))?;
    std::fs::write(&staged, &bytes)
        .map_err(|e| format!("cannot write {}: {e}", staged.display()))?;
    // The whole version folder appears at once; if another process won the race, use its.
    match std::fs::rename(&staged_dir, version_dir) {
        Ok(()) => {}
        Err(_) if target.is_file() => {}
        Err(e) => {
            return Err(format!(
                "cannot move the library into {}: {e}",
                version_dir.display()
            ));
        }
    }
    Ok(target.to_path_buf())
}

static RUNTIME: OnceLock<Runtime> = OnceLock::new();
static INIT_LOCK: Mutex<()> = Mutex::new(());

/// The process's ONNX Runtime, if [`ensure`] has loaded it.
pub fn loaded() -> Option<&'static Runtime> {
    RUNTIME.get()
}

/// The process's ONNX Runtime: found (and provisioned) and loaded on the first call,
/// returned as is afterwards. A failure is not cached: a later call tries again.
pub fn ensure(options: RuntimeOptions) -> Result<&'static Runtime, RuntimeError> {
    if let Some(r) = RUNTIME.get() {
        return Ok(r);
    }
    let _guard = INIT_LOCK.lock().unwrap_or_else(|p| p.into_inner());
    if let Some(r) = RUNTIME.get() {
        return Ok(r);
    }
    let start = Instant::now();
    let paths = SearchPaths::from_process();
    let found = resolve(&paths, || {
        if options.use_python_package {
            python_capi_dir()
        } else {
            None
        }
    })?;
    let (path, source) = match found {
        Some(f) => f,
        None => {
            let cache = paths.cache_dir.as_ref().ok_or(RuntimeError::NoCacheDir)?;
            if !options.provision {
                return Err(RuntimeError::NotFound {
                    searched: searched(&paths, options),
                });
            }
            (provision(cache)?, RuntimeSource::Provisioned)
        }
    };
    let environment = load(&path)?;
    let runtime = Runtime {
        path,
        source,
        setup_secs: start.elapsed().as_secs_f64(),
        environment,
    };
    tracing::info!(
        path = %runtime.path.display(),
        source = ?runtime.source,
        secs = runtime.setup_secs,
        "ONNX Runtime loaded"
    );
    Ok(RUNTIME.get_or_init(|| runtime))
}

fn searched(paths: &SearchPaths, options: RuntimeOptions) -> String {
    let mut s = vec![format!("{ORT_DYLIB_ENV} (unset)")];
    if let Some(d) = &paths.exe_dir {
        s.push(d.join("lib").display().to_string());
    }
    if let Some(c) = &paths.cache_dir {
        s.push(cached_library(c).display().to_string());
    }
    if options.use_python_package {
        s.push("python3's onnxruntime package".into());
    }
    s.join(", ")
}

fn load(path: &Path) -> Result<ort::environment::Environment, RuntimeError> {
    let err = |reason: String| RuntimeError::Load {
        path: path.display().to_string(),
        reason,
    };
    // ort panics on a path that does not exist; every caller has checked, check again.
    if !path.is_file() {
        return Err(err("no such file".into()));
    }
    ort::init_from(path)
        .map_err(|e| err(e.to_string()))?
        .with_name("vamos")
        .build()
        .map_err(|e| err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn touch(p: &Path) {
        std::fs::create_dir_all(p.parent().unwrap()).unwrap();
        std::fs::write(p, b"x").unwrap();
    }

    #[test]
    fn cache_dir_precedence() {
        let s = |v: &str| Some(OsString::from(v));
        assert_eq!(
            cache_dir_from(s("/a"), s("/x"), s("/h")),
            Some(PathBuf::from("/a"))
        );
        assert_eq!(
            cache_dir_from(None, s("/x"), s("/h")),
            Some(PathBuf::from("/x/vamos"))
        );
        assert_eq!(
            cache_dir_from(None, None, s("/h")),
            Some(PathBuf::from("/h/.cache/vamos"))
        );
        assert_eq!(cache_dir_from(None, None, None), None);
    }

    #[test]
    fn resolution_order_with_fake_folders() {
        let root = tempfile::tempdir().unwrap();
        let r = root.path();
        let exe = r.join("bin");
        let cache = r.join("cache");
        let py = r.join("py/capi");
        let env_lib = r.join("custom/libort.so");
        let mut paths = SearchPaths {
            env_path: None,
            exe_dir: Some(exe.clone()),
            cache_dir: Some(cache.clone()),
        };
        let no_python = || None;
        assert_eq!(resolve(&paths, no_python).unwrap(), None);

        // Python package: the newest supported versioned file wins; too-old ones are skipped.
        touch(&py.join("libonnxruntime.so.1.20.0"));
        assert_eq!(resolve(&paths, || Some(py.clone())).unwrap(), None);
        touch(&py.join("libonnxruntime.so.1.31.1"));
        touch(&py.join("libonnxruntime.so.1.24.2"));
        touch(&py.join("libonnxruntime_providers_shared.so"));
        assert_eq!(
            resolve(&paths, || Some(py.clone())).unwrap(),
            Some((
                py.join("libonnxruntime.so.1.31.1"),
                RuntimeSource::PythonPackage
            ))
        );
        // The cache beats Python, and Python is then not even asked.
        let cached = cached_library(&cache);
        touch(&cached);
        assert_eq!(
            resolve(&paths, || panic!("python asked")).unwrap(),
            Some((cached.clone(), RuntimeSource::Cache))
        );
        // lib/ beside the binary beats the cache.
        touch(&exe.join("lib/libonnxruntime.so"));
        assert_eq!(
            resolve(&paths, no_python).unwrap(),
            Some((
                exe.join("lib/libonnxruntime.so"),
                RuntimeSource::BesideBinary
            ))
        );
        // ORT_DYLIB_PATH beats everything, and a missing one is an error, not a fallback.
        paths.env_path = Some(env_lib.clone());
        let e = resolve(&paths, no_python).unwrap_err();
        assert!(matches!(e, RuntimeError::EnvPathMissing { .. }), "{e}");
        assert!(e.to_string().contains("custom/libort.so"));
        touch(&env_lib);
        assert_eq!(
            resolve(&paths, no_python).unwrap(),
            Some((env_lib, RuntimeSource::EnvVar))
        );
    }

    #[test]
    fn cached_library_layout() {
        assert_eq!(
            cached_library(Path::new("/c")),
            PathBuf::from(format!(
                "/c/onnxruntime/{ORT_VERSION}/libonnxruntime.so.{ORT_VERSION}"
            ))
        );
        assert_eq!(minor_of("libonnxruntime.so.1.31.1"), Some(31));
        assert_eq!(minor_of("libonnxruntime.so.2.1.0"), None);
        assert_eq!(minor_of("libonnxruntime.so"), None);
    }
}
