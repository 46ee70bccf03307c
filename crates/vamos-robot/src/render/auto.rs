//! `render.backend = "auto"` on a host with a hardware GPU: both back-ends take the
//! robot's meshes, the first frames are drawn alternately by each and timed, and from
//! then on the faster one draws every frame. The two back-ends agree (mask IoU > 0.99,
//! depth and flow within the tolerances of `gpu_tests.rs`), so the probe frames are
//! ordinary frames, not extra work.
//!
//! Timing the real robot at the real resolution and poses is what makes the choice
//! right: the GPU's per-frame cost is mostly fixed (submission and read-back), the CPU's
//! grows with the covered pixels and the triangle count, so which one wins depends on
//! the host, the robot and the processing resolution.

use std::time::Instant;

use super::{BodyRenderer, CpuRenderer, RenderError, RenderFrame, RenderOutput, WgpuRenderer};
use crate::geometry::LinkMesh;

/// Timed frames per back-end, after one untimed warm-up frame each (pipeline and buffer
/// creation, first upload).
pub const PROBE_FRAMES: usize = 3;

/// The back-end an [`AutoRenderer`] settled on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Choice {
    /// The CPU rasteriser.
    Cpu,
    /// The wgpu renderer.
    Wgpu,
}

/// The fastest timed frame of one back-end, seconds: the minimum after the warm-up frame
/// (the first entry, ignored), once there are `PROBE_FRAMES` timed frames; `None` before.
fn timed_min(s: &[f64]) -> Option<f64> {
    (s.len() > PROBE_FRAMES).then(|| s[1..].iter().copied().fold(f64::INFINITY, f64::min))
}

/// Picks the back-end with the lower [`timed_min`] once both have one; `None` before.
/// Ties keep the CPU (no driver in the way).
pub fn decide(cpu_s: &[f64], gpu_s: &[f64]) -> Option<Choice> {
    Some(pick(timed_min(cpu_s)?, timed_min(gpu_s)?))
}

/// The faster of two timed minimums; a tie keeps the CPU.
fn pick(cpu_s: f64, gpu_s: f64) -> Choice {
    if gpu_s < cpu_s {
        Choice::Wgpu
    } else {
        Choice::Cpu
    }
}

/// Times both back-ends on the first frames, then renders with the faster.
pub struct AutoRenderer {
    cpu: CpuRenderer,
    gpu: Option<WgpuRenderer>,
    /// Frame times in seconds, warm-up first: `[cpu, wgpu]`.
    times: [Vec<f64>; 2],
    choice: Option<Choice>,
}

impl std::fmt::Debug for AutoRenderer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AutoRenderer")
            .field("gpu", &self.gpu.is_some())
            .field("times", &self.times)
            .field("choice", &self.choice)
            .finish()
    }
}

impl AutoRenderer {
    /// Both back-ends, built for the same configuration; `gpu = None` means the CPU only.
    pub fn new(cpu: CpuRenderer, gpu: Option<WgpuRenderer>) -> Self {
        let choice = gpu.is_none().then_some(Choice::Cpu);
        Self {
            cpu,
            gpu,
            times: [Vec::new(), Vec::new()],
            choice,
        }
    }

    /// The back-end chosen, `None` while the probe frames are still being drawn.
    pub fn choice(&self) -> Option<Choice> {
        self.choice
    }

    /// Frame times measured so far, seconds, warm-up frame first: `(cpu, wgpu)`.
    pub fn probe_times(&self) -> (&[f64], &[f64]) {
        (&self.times[0], &self.times[1])
    }

    fn fall_back_to_cpu(&mut self, e: &RenderError) {
        tracing::warn!(error = %e, "render.backend auto: the wgpu back-end failed; using the CPU rasteriser");
        self.gpu = None;
        self.choice = Some(Choice::Cpu);
    }
}

impl BodyRenderer for AutoRenderer {
    fn prepare(&mut self, meshes: &[LinkMesh]) -> Result<(), RenderError> {
        self.cpu.prepare(meshes)?;
        if let Some(g) = self.gpu.as_mut()
            && let Err(e) = g.prepare(meshes)
        {
            self.fall_back_to_cpu(&e);
        }
        // A new robot is a new workload: time it again.
        if self.gpu.is_some() {
            self.times = [Vec::new(), Vec::new()];
            self.choice = None;
        }
        Ok(())
    }

    fn render(
        &mut self,
        frame: &RenderFrame<'_>,
        out: &mut RenderOutput,
    ) -> Result<(), RenderError> {
        match (self.choice, self.gpu.as_mut()) {
            (Some(Choice::Wgpu), Some(g)) => return g.render(frame, out),
            (Some(_), _) | (None, None) => return self.cpu.render(frame, out),
            (None, Some(_)) => {}
        }
        // Probing: the back-end with fewer frames draws this one (the CPU on a tie).
        let use_gpu = self.times[1].len() < self.times[0].len();
        let t0 = Instant::now();
        let res = match (use_gpu, self.gpu.as_mut()) {
            (true, Some(g)) => g.render(frame, out),
            _ => self.cpu.render(frame, out),
        };
        let elapsed = t0.elapsed().as_secs_f64();
        if let Err(e) = res {
            if !use_gpu {
                return Err(e);
            }
            self.fall_back_to_cpu(&e);
            return self.cpu.render(frame, out);
        }
        self.times[usize::from(use_gpu)].push(elapsed);
        if let (Some(cpu_s), Some(wgpu_s)) = (timed_min(&self.times[0]), timed_min(&self.times[1]))
        {
            let choice = pick(cpu_s, wgpu_s);
            tracing::info!(
                cpu_ms = cpu_s * 1e3,
                wgpu_ms = wgpu_s * 1e3,
                chosen = ?choice,
                "render.backend auto: timed both back-ends on this robot"
            );
            self.choice = Some(choice);
            if choice == Choice::Cpu {
                // Free the GPU's buffers.
                self.gpu = None;
            }
        }
        Ok(())
    }

    fn name(&self) -> &'static str {
        match self.choice {
            Some(Choice::Cpu) => "cpu",
            Some(Choice::Wgpu) => "wgpu",
            None => "auto",
        }
    }
}
