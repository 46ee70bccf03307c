//! Bearer tokens with three roles (viewer < robot < admin). Tokens are kept as sha256 digests only (in the settings
//! and in memory) and compared in constant time.

use sha2::{Digest, Sha256};
use std::sync::OnceLock;

/// The environment variables of plain tokens, admin then robot.
const TOKEN_VARS: [&str; 2] = ["VAMOS_ADMIN_TOKEN", "VAMOS_ROBOT_TOKEN"];

/// Digests of the plain tokens taken out of the environment by [`take_env_tokens`].
static TAKEN: OnceLock<[Vec<[u8; 32]>; 2]> = OnceLock::new();

/// The environment variable of plain viewer tokens (read-only: the live view, lists).
const VIEWER_VAR: &str = "VAMOS_VIEWER_TOKEN";

/// Digests of the plain viewer tokens taken out of the environment.
static TAKEN_VIEWER: OnceLock<Vec<[u8; 32]>> = OnceLock::new();

fn plain_digests(s: Option<&str>) -> Vec<[u8; 32]> {
    s.unwrap_or("")
        .split(',')
        .map(str::trim)
        .filter(|t| !t.is_empty())
        .map(digest)
        .collect()
}

/// Hashes `VAMOS_ADMIN_TOKEN` and `VAMOS_ROBOT_TOKEN`, overwrites their values in the
/// process's initial environment block (what `/proc/PID/environ` shows) and removes
/// them from the environment, so no plain token outlives the start: neither the running
/// server's memory nor a child process holds it. `vamos serve` calls it first thing.
///
/// # Safety
/// No other thread may read or write the environment while it runs: call it from
/// `main` before any thread is started.
pub unsafe fn take_env_tokens() {
    let taken = TOKEN_VARS.map(|var| plain_digests(std::env::var(var).ok().as_deref()));
    let _ = TAKEN_VIEWER.set(plain_digests(std::env::var(VIEWER_VAR).ok().as_deref()));
    for var in TOKEN_VARS.into_iter().chain([VIEWER_VAR]) {
        #[cfg(unix)]
        if let Ok(name) = std::ffi::CString::new(var) {
            // SAFETY: the caller guarantees no other thread touches the environment;
            // getenv's pointer is the value's bytes in the environment block (the
            // process's own writable memory), `strlen` of them long.
            unsafe {
                let value = libc::getenv(name.as_ptr());
                if !value.is_null() {
                    std::ptr::write_bytes(value, b'x', libc::strlen(value));
                }
            }
        }
        // SAFETY: as above.
        unsafe { std::env::remove_var(var) };
    }
    let _ = TAKEN.set(taken);
}

/// Digests of the plain admin and robot tokens: those [`take_env_tokens`] took, else
/// read from the environment now (a server started in-process by a program).
pub fn env_token_digests() -> [Vec<[u8; 32]>; 2] {
    match TAKEN.get() {
        Some(t) => t.clone(),
        None => TOKEN_VARS.map(|var| plain_digests(std::env::var(var).ok().as_deref())),
    }
}

/// Digests of the plain viewer tokens (`VAMOS_VIEWER_TOKEN`), as [`env_token_digests`].
pub fn env_viewer_digests() -> Vec<[u8; 32]> {
    match TAKEN_VIEWER.get() {
        Some(t) => t.clone(),
        None => plain_digests(std::env::var(VIEWER_VAR).ok().as_deref()),
    }
}

/// What a caller may do.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, schemars::JsonSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Read only: the live view, session and alarm lists, thumbnails.
    Viewer,
    /// Stream sessions and score episodes.
    Robot,
    /// Everything, including changes of state (models, robots, profiles, thresholds).
    Admin,
}

/// Why a request was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AuthError {
    /// No `authorization: Bearer ...` given.
    #[error("missing bearer token")]
    Missing,
    /// The token is not known.
    #[error("invalid token")]
    Invalid,
    /// The token's role may not do this.
    #[error("this needs the {needed:?} role")]
    Forbidden {
        /// The role needed.
        needed: Role,
    },
}

/// A configured token digest is not 64 hex digits.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("token digest {index} of the {role} tokens is not a sha256 hex digest")]
pub struct BadDigest {
    /// `admin` or `robot`.
    pub role: &'static str,
    /// Position in its list.
    pub index: usize,
}

/// The known tokens.
#[derive(Debug, Clone, Default)]
pub struct Tokens {
    admin: Vec<[u8; 32]>,
    robot: Vec<[u8; 32]>,
    viewer: Vec<[u8; 32]>,
}

/// sha256 of a token.
pub fn digest(token: &str) -> [u8; 32] {
    Sha256::digest(token.as_bytes()).into()
}

fn parse_hex(s: &str) -> Option<[u8; 32]> {
    let s = s.trim();
    if s.len() != 64 {
        return None;
    }
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(s.get(2 * i..2 * i + 2)?, 16).ok()?;
    }
    Some(out)
}

/// Equality of two digests in time independent of where they differ (`subtle`).
fn constant_time_eq(a: &[u8; 32], b: &[u8; 32]) -> bool {
    use subtle::ConstantTimeEq;
    bool::from(a.ct_eq(b))
}

impl Tokens {
    /// Tokens from configured digests and plain comma-separated lists (the
    /// `VAMOS_ADMIN_TOKEN` / `VAMOS_ROBOT_TOKEN` variables); plain tokens are hashed at
    /// once and not kept.
    pub fn new(
        admin_sha256: &[String],
        robot_sha256: &[String],
        admin_plain: Option<&str>,
        robot_plain: Option<&str>,
    ) -> Result<Self, BadDigest> {
        let parse = |list: &[String], role| -> Result<Vec<[u8; 32]>, BadDigest> {
            list.iter()
                .enumerate()
                .map(|(index, s)| parse_hex(s).ok_or(BadDigest { role, index }))
                .collect()
        };
        let mut admin = parse(admin_sha256, "admin")?;
        admin.extend(plain_digests(admin_plain));
        let mut robot = parse(robot_sha256, "robot")?;
        robot.extend(plain_digests(robot_plain));
        Ok(Self {
            admin,
            robot,
            viewer: Vec::new(),
        })
    }

    /// Adds viewer tokens: configured digests (hex) and plain digests (e.g.
    /// [`env_viewer_digests`]).
    pub fn with_viewers(
        mut self,
        viewer_sha256: &[String],
        plain: Vec<[u8; 32]>,
    ) -> Result<Self, BadDigest> {
        for (index, s) in viewer_sha256.iter().enumerate() {
            self.viewer.push(parse_hex(s).ok_or(BadDigest {
                role: "viewer",
                index,
            })?);
        }
        self.viewer.extend(plain);
        Ok(self)
    }

    /// Adds token digests: admin, then robot (e.g. [`env_token_digests`]).
    pub fn with_digests(mut self, [admin, robot]: [Vec<[u8; 32]>; 2]) -> Self {
        self.admin.extend(admin);
        self.robot.extend(robot);
        self
    }

    /// Whether any token is configured (otherwise every caller is admin).
    pub fn enabled(&self) -> bool {
        !(self.admin.is_empty() && self.robot.is_empty() && self.viewer.is_empty())
    }

    /// The role of an `authorization` header value (`Bearer TOKEN`); every caller is
    /// admin when no token is configured.
    pub fn role_of(&self, header: Option<&str>) -> Result<Role, AuthError> {
        if !self.enabled() {
            return Ok(Role::Admin);
        }
        let header = header.ok_or(AuthError::Missing)?;
        let token = header
            .strip_prefix("Bearer ")
            .or_else(|| header.strip_prefix("bearer "))
            .ok_or(AuthError::Missing)?
            .trim();
        let d = digest(token);
        // Every digest is compared, so the time does not tell which list matched.
        let mut role = None;
        for known in &self.viewer {
            if constant_time_eq(known, &d) {
                role = Some(Role::Viewer);
            }
        }
        for known in &self.robot {
            if constant_time_eq(known, &d) {
                role = Some(Role::Robot);
            }
        }
        for known in &self.admin {
            if constant_time_eq(known, &d) {
                role = Some(Role::Admin);
            }
        }
        role.ok_or(AuthError::Invalid)
    }

    /// Checks that the caller has at least `needed`.
    pub fn require(&self, header: Option<&str>, needed: Role) -> Result<Role, AuthError> {
        let role = self.role_of(header)?;
        if role >= needed {
            Ok(role)
        } else {
            Err(AuthError::Forbidden { needed })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(d: [u8; 32]) -> String {
        d.iter().map(|b| format!("{b:02x}")).collect()
    }

    #[test]
    fn roles_follow_the_lists_and_admin_covers_robot() {
        let t = Tokens::new(&[hex(digest("adm"))], &[], None, Some("r1, r2")).unwrap();
        assert!(t.enabled());
        assert_eq!(t.role_of(Some("Bearer adm")), Ok(Role::Admin));
        assert_eq!(t.role_of(Some("Bearer r2")), Ok(Role::Robot));
        assert_eq!(t.role_of(Some("Bearer nope")), Err(AuthError::Invalid));
        assert_eq!(t.role_of(Some("adm")), Err(AuthError::Missing));
        assert_eq!(t.role_of(None), Err(AuthError::Missing));
        assert_eq!(t.require(Some("Bearer adm"), Role::Robot), Ok(Role::Admin));
        assert_eq!(
            t.require(Some("Bearer r1"), Role::Admin),
            Err(AuthError::Forbidden {
                needed: Role::Admin
            })
        );
    }

    #[test]
    fn no_tokens_means_everyone_is_admin_and_bad_digests_are_refused() {
        let t = Tokens::new(&[], &[], None, Some(" , ")).unwrap();
        assert!(!t.enabled());
        assert_eq!(t.role_of(None), Ok(Role::Admin));
        let err = Tokens::new(&[], &["abc".into()], None, None).unwrap_err();
        assert_eq!(
            err,
            BadDigest {
                role: "robot",
                index: 0
            }
        );
    }

    #[test]
    fn viewers_are_below_robots_and_alone_enable_tokens() {
        let t = Tokens::new(&[], &[], None, None)
            .unwrap()
            .with_viewers(&[hex(digest("v1"))], vec![digest("v2")])
            .unwrap();
        assert!(t.enabled());
        assert_eq!(t.role_of(Some("Bearer v1")), Ok(Role::Viewer));
        assert_eq!(t.require(Some("Bearer v2"), Role::Viewer), Ok(Role::Viewer));
        assert_eq!(
            t.require(Some("Bearer v2"), Role::Robot),
            Err(AuthError::Forbidden {
                needed: Role::Robot
            })
        );
        assert_eq!(t.role_of(None), Err(AuthError::Missing));
        let t = Tokens::new(&[], &[], Some("adm"), None)
            .unwrap()
            .with_viewers(&[], vec![])
            .unwrap();
        assert_eq!(t.require(Some("Bearer adm"), Role::Viewer), Ok(Role::Admin));
        let err = t.with_viewers(&["zz".into()], vec![]).unwrap_err();
        assert_eq!(
            err,
            BadDigest {
                role: "viewer",
                index: 0
            }
        );
    }

    #[test]
    fn digest_is_sha256() {
        // sha256("abc"), FIPS 180-2 appendix B.1.
        assert_eq!(
            hex(digest("abc")),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }
}
