//! `RobotConfig`: caps and tessellation settings for loading robot descriptions
//! (the `[robot]` settings section).

use serde::{Deserialize, Serialize};

/// Limits and tessellation for loading a robot. Defaults fit real arms (pybullet's panda
/// has 105k visual triangles, ~9 MB of meshes) with a wide margin, while refusing
/// accidental or hostile inputs (a 1 GB scan, a zip bomb) before they take the memory.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RobotConfig {
    /// Largest mesh file read, bytes (default 64 MiB). Larger files are left out with a
    /// warning.
    pub max_mesh_file_bytes: u64,
    /// Most triangles in one mesh file (default 2,000,000). Larger meshes are left out with
    /// a warning.
    pub max_mesh_triangles: usize,
    /// Most visual triangles of the whole robot (default 5,000,000); more is an error.
    pub max_robot_triangles: usize,
    /// Largest total size unpacked from a robot package archive, bytes (default 512 MiB).
    pub max_archive_bytes: u64,
    /// Most entries in a robot package archive (default 10,000).
    pub max_archive_entries: usize,
    /// Segments around a URDF cylinder (and capsule); default 32.
    pub cylinder_segments: u32,
    /// Latitude bands of a URDF sphere (longitude segments are twice as many); default 12.
    pub sphere_rings: u32,
}

impl Default for RobotConfig {
    fn default() -> Self {
        Self {
            max_mesh_file_bytes: 64 << 20,
            max_mesh_triangles: 2_000_000,
            max_robot_triangles: 5_000_000,
            max_archive_bytes: 512 << 20,
            max_archive_entries: 10_000,
            cylinder_segments: 32,
            sphere_rings: 12,
        }
    }
}
