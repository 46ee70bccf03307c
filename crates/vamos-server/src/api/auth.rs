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
    /// Robot tokens, each with the robots it is issued for (`None`: any robot id).
    robot: Vec<([u8; 32], Option<Vec<String>>)>,
    viewer: Vec<[u8; 32]>,
}

/// Who is calling: a role and, for a robot token, what it may act for and see.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Caller {
    /// The token's role.
    pub role: Role,
    /// A robot token's identity in this server's run (its place among the robot tokens;
    /// kept with what it opens, never shown); `None` for the other roles.
    pub robot_token: Option<usize>,
    /// The robots a robot token is issued for (`None`: any robot id).
    pub robots: Option<Vec<String>>,
}

impl Caller {
    /// Every caller when no token is configured.
    pub fn anyone() -> Self {
        Self::of(Role::Admin)
    }

    /// A caller of `role` that is no robot token.
    fn of(role: Role) -> Self {
        Self {
            role,
            robot_token: None,
            robots: None,
        }
    }

    /// Whether the caller may open a session or score an episode as robot `robot_id`.
    pub fn may_act_for(&self, robot_id: &str) -> bool {
        self.robots
            .as_ref()
            .is_none_or(|r| r.iter().any(|x| x == robot_id))
    }

    /// Whether the caller may see (read, resume, mark the alarms of) what was opened by
    /// robot token `opener` (`None`: another role) as robot `robot_id`. Admins and
    /// viewers see everything; a robot token what its robots' sessions hold when it is
    /// issued for robots, else only what it opened itself.
    pub fn sees(&self, opener: Option<usize>, robot_id: &str) -> bool {
        match (self.role, &self.robots) {
            (Role::Admin | Role::Viewer, _) => true,
            (Role::Robot, Some(robots)) => robots.iter().any(|r| r == robot_id),
            (Role::Robot, None) => opener.is_some() && opener == self.robot_token,
        }
    }
}

/// A configured robot token: `HEX` (any robot) or `HEX:robot-a,robot-b`.
fn parse_robot(s: &str) -> Option<([u8; 32], Option<Vec<String>>)> {
    match s.split_once(':') {
        None => Some((parse_hex(s)?, None)),
        Some((hex, robots)) => {
            let robots: Vec<String> = robots
                .split(',')
                .map(str::trim)
                .filter(|r| !r.is_empty())
                .map(String::from)
                .collect();
            (!robots.is_empty()).then_some(())?;
            Some((parse_hex(hex)?, Some(robots)))
        }
    }
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
        let mut robot = robot_sha256
            .iter()
            .enumerate()
            .map(|(index, s)| {
                parse_robot(s).ok_or(BadDigest {
                    role: "robot",
                    index,
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        robot.extend(plain_digests(robot_plain).into_iter().map(|d| (d, None)));
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
        self.robot.extend(robot.into_iter().map(|d| (d, None)));
        self
    }

    /// Whether any token is configured (otherwise every caller is admin).
    pub fn enabled(&self) -> bool {
        !(self.admin.is_empty() && self.robot.is_empty() && self.viewer.is_empty())
    }

    /// The role of an `authorization` header value (`Bearer TOKEN`); every caller is
    /// admin when no token is configured.
    pub fn role_of(&self, header: Option<&str>) -> Result<Role, AuthError> {
        self.caller_of(header).map(|c| c.role)
    }

    /// The caller of an `authorization` header value (`Bearer TOKEN`): its role and, for
    /// a robot token, its identity and robots; every caller is admin when no token is
    /// configured.
    pub fn caller_of(&self, header: Option<&str>) -> Result<Caller, AuthError> {
        if !self.enabled() {
            return Ok(Caller::anyone());
        }
        let header = header.ok_or(AuthError::Missing)?;
        let token = header
            .strip_prefix("Bearer ")
            .or_else(|| header.strip_prefix("bearer "))
            .ok_or(AuthError::Missing)?
            .trim();
        let d = digest(token);
        // Every digest is compared, so the time does not tell which list matched.
        let mut caller = None;
        for known in &self.viewer {
            if constant_time_eq(known, &d) {
                caller = Some(Caller::of(Role::Viewer));
            }
        }
        for (index, (known, robots)) in self.robot.iter().enumerate() {
            if constant_time_eq(known, &d) {
                caller = Some(Caller {
                    role: Role::Robot,
                    robot_token: Some(index),
                    robots: robots.clone(),
                });
            }
        }
        for known in &self.admin {
            if constant_time_eq(known, &d) {
                caller = Some(Caller::of(Role::Admin));
            }
        }
        caller.ok_or(AuthError::Invalid)
    }

    /// Checks that the caller has at least `needed`.
    pub fn require(&self, header: Option<&str>, needed: Role) -> Result<Role, AuthError> {
        self.require_caller(header, needed).map(|c| c.role)
    }

    /// Checks that the caller has at least `needed`, and says who it is.
    pub fn require_caller(&self, header: Option<&str>, needed: Role) -> Result<Caller, AuthError> {
        let caller = self.caller_of(header)?;
        if caller.role >= needed {
            Ok(caller)
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
    fn robot_tokens_act_for_their_robots_and_see_only_their_own() {
        let scoped = format!("{}:arm-1, arm-2", hex(digest("r-scoped")));
        let t = Tokens::new(&[], &[scoped, hex(digest("r-any"))], None, Some("r-env")).unwrap();
        let c = |tok: &str| t.caller_of(Some(&format!("Bearer {tok}"))).unwrap();
        let (scoped, any, env) = (c("r-scoped"), c("r-any"), c("r-env"));
        assert_eq!(
            scoped.robots,
            Some(vec!["arm-1".to_string(), "arm-2".to_string()])
        );
        assert!(scoped.may_act_for("arm-2") && !scoped.may_act_for("arm-3"));
        assert!(any.may_act_for("arm-3") && env.may_act_for("x"));
        // A scoped token sees its robots' sessions, whoever opened them.
        assert!(scoped.sees(any.robot_token, "arm-1"));
        assert!(!scoped.sees(scoped.robot_token, "arm-3"));
        // An unscoped one only what it opened itself.
        assert!(any.sees(any.robot_token, "arm-3"));
        assert!(!any.sees(env.robot_token, "arm-3"));
        assert!(!any.sees(None, "arm-3"));
        assert!(Caller::anyone().sees(Some(7), "x"));
        let err = Tokens::new(&[], &[format!("{}:", hex(digest("x")))], None, None).unwrap_err();
        assert_eq!(
            err,
            BadDigest {
                role: "robot",
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
