//! The one error type of the robot module.

/// Errors of loading a robot description, its meshes, and of joint states.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum RobotError {
    /// A file or folder could not be read.
    #[error("cannot read {path}: {message}")]
    Io {
        /// The path.
        path: String,
        /// The operating system's message.
        message: String,
    },
    /// The URDF is not well-formed XML or not a valid URDF document.
    #[error("malformed URDF ({source_name}): {message}")]
    MalformedUrdf {
        /// Where the URDF came from (a path or `<string>`).
        source_name: String,
        /// The parser's message.
        message: String,
    },
    /// The URDF has no links.
    #[error("the URDF has no links")]
    NoLinks,
    /// Two links share a name.
    #[error("duplicate link name {name:?}")]
    DuplicateLink {
        /// The name.
        name: String,
    },
    /// Two joints share a name.
    #[error("duplicate joint name {name:?}")]
    DuplicateJoint {
        /// The name.
        name: String,
    },
    /// A joint names a parent or child link that does not exist.
    #[error("joint {joint:?} refers to absent link {link:?}")]
    MissingLink {
        /// The joint.
        joint: String,
        /// The absent link.
        link: String,
    },
    /// A link is the child of two joints.
    #[error("link {link:?} is the child of two joints ({first:?} and {second:?})")]
    TwoParents {
        /// The link.
        link: String,
        /// The first joint naming it as child.
        first: String,
        /// The second.
        second: String,
    },
    /// Several links have no parent joint (the description is a forest, not a tree).
    #[error("the URDF has several root links: {roots:?}")]
    MultipleRoots {
        /// The parentless links.
        roots: Vec<String>,
    },
    /// Every link has a parent: the joints form a cycle.
    #[error("the joints form a kinematic cycle through link {link:?}")]
    KinematicCycle {
        /// A link on the cycle.
        link: String,
    },
    /// A moving joint has a zero or non-finite axis, or a non-finite origin.
    #[error("joint {joint:?} has an invalid {what}")]
    InvalidJoint {
        /// The joint.
        joint: String,
        /// `axis` or `origin` or `mimic`.
        what: &'static str,
    },
    /// Mimic relations form a cycle.
    #[error("mimic joints form a cycle through {joint:?}")]
    MimicCycle {
        /// A joint on the cycle.
        joint: String,
    },
    /// A named camera link is not in the robot.
    #[error("unknown camera link {name:?}")]
    UnknownCameraLink {
        /// The name.
        name: String,
    },
    /// A mesh file could not be read or parsed.
    #[error("mesh {path} is unreadable: {message}")]
    MeshUnreadable {
        /// The resolved path.
        path: String,
        /// Why.
        message: String,
    },
    /// A mesh file is larger than the configured cap.
    #[error("mesh {path} has {bytes} bytes, more than the cap of {limit_bytes}")]
    MeshFileTooLarge {
        /// The resolved path.
        path: String,
        /// Its size.
        bytes: u64,
        /// `RobotConfig::max_mesh_file_bytes`.
        limit_bytes: u64,
    },
    /// A mesh (or the whole robot) has more triangles than the configured cap.
    #[error("{what} has {triangles} triangles, more than the cap of {limit}")]
    TooManyTriangles {
        /// The mesh path, or `robot`.
        what: String,
        /// Its triangle count.
        triangles: usize,
        /// The cap.
        limit: usize,
    },
    /// A package holds no URDF file, or several equally likely ones.
    #[error("cannot pick the URDF in {path}: {reason}")]
    UrdfNotFound {
        /// The package.
        path: String,
        /// `no .urdf file` or the candidates.
        reason: String,
    },
    /// An archive is corrupt or of an unknown kind.
    #[error("cannot read archive {path}: {message}")]
    Archive {
        /// The archive.
        path: String,
        /// Why.
        message: String,
    },
    /// An archive entry would land outside the extraction root (absolute, `..`, link).
    #[error("archive {path} has an unsafe entry {entry:?}")]
    ArchiveUnsafeEntry {
        /// The archive.
        path: String,
        /// The entry name.
        entry: String,
    },
    /// An archive unpacks to more bytes or entries than the configured caps.
    #[error("archive {path} exceeds the cap of {limit} {what}")]
    ArchiveTooLarge {
        /// The archive.
        path: String,
        /// `bytes` or `entries`.
        what: &'static str,
        /// The cap.
        limit: u64,
    },
    /// A joint position is NaN or infinite.
    #[error("joint {joint:?} has a non-finite position {value}")]
    NonFiniteJoint {
        /// The joint.
        joint: String,
        /// The value.
        value: f64,
    },
    /// A joint vector's length does not match the robot (or names and positions differ).
    #[error("expected {expected} joint positions, got {got}")]
    JointCount {
        /// The expected length.
        expected: usize,
        /// The given length.
        got: usize,
    },
}

impl RobotError {
    pub(crate) fn io(path: &std::path::Path, e: &std::io::Error) -> Self {
        Self::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        }
    }
}
