//! [`Engine`]: where the per-pixel fusion stages run. The one selector of the CLI
//! (`kfuse fuse --engine`, `kfuse view --engine`), the library ([`crate::fuse`]) and the viewer.

use std::fmt;
use std::str::FromStr;

/// Where the per-pixel fusion stages (H1, H2, H7, H3 nearest, H8 mask and fill, H6) run. The
/// output is the same on every engine (bit-identical on lavapipe, see the crate docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Engine {
    /// The CPU pipeline, `geometry::fusion::run`.
    #[default]
    Cpu,
    /// The GPU (wgpu, Vulkan). No adapter is [`crate::GpuError::NoAdapter`] for a batch job
    /// (`kfuse fuse --engine gpu` fails); the viewer, which can still show the frame, fuses
    /// on the CPU instead and says why in its title bar.
    Gpu,
    /// The GPU when an adapter exists, else the CPU with a warning.
    Auto,
}

impl Engine {
    /// Every engine, in the order the CLI lists them.
    pub const ALL: [Engine; 3] = [Engine::Cpu, Engine::Gpu, Engine::Auto];

    /// The CLI spelling: `cpu`, `gpu` or `auto`.
    pub fn name(self) -> &'static str {
        match self {
            Engine::Cpu => "cpu",
            Engine::Gpu => "gpu",
            Engine::Auto => "auto",
        }
    }

    /// Whether a GPU context is to be opened at all.
    pub fn wants_gpu(self) -> bool {
        !matches!(self, Engine::Cpu)
    }

    /// True when the caller may run the CPU pipeline instead after
    /// [`crate::GpuError::NoAdapter`].
    pub fn falls_back_to_cpu(self) -> bool {
        matches!(self, Engine::Auto)
    }
}

impl fmt::Display for Engine {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Engine {
    type Err = String;

    /// `cpu`, `gpu` or `auto` (ASCII case ignored).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Engine::ALL
            .into_iter()
            .find(|e| e.name().eq_ignore_ascii_case(s))
            .ok_or_else(|| format!("'{s}' is not an engine; use cpu, gpu or auto"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_only_auto_falls_back() {
        for e in Engine::ALL {
            assert_eq!(e.name().parse::<Engine>(), Ok(e));
            assert_eq!(e.to_string().to_uppercase().parse::<Engine>(), Ok(e));
        }
        assert!("on".parse::<Engine>().unwrap_err().contains("cpu, gpu or auto"));
        assert_eq!(Engine::ALL.map(Engine::falls_back_to_cpu), [false, false, true]);
        assert_eq!(Engine::ALL.map(Engine::wants_gpu), [false, true, true]);
    }
}
