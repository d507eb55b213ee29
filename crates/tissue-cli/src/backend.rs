//! `--backend auto|gpu|cpu`: the library's choice of device
//! ([`tissue::backend`]), made once per command and printed with its reason.

use anyhow::Result;
use clap::ValueEnum;

pub use tissue::backend::{BoundPoints, Device, Solver};

/// Where the work runs (the command line's spelling of [`tissue::backend::Backend`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Backend {
    /// A hardware GPU when there is one, otherwise the CPU (a software
    /// adapter such as lavapipe is slower than the CPU path).
    Auto,
    /// The GPU adapter `WGPU_BACKEND` / `WGPU_ADAPTER_NAME` name, or the
    /// default one; an error when there is none.
    Gpu,
    /// The CPU path.
    Cpu,
}

impl From<Backend> for tissue::backend::Backend {
    fn from(backend: Backend) -> Self {
        match backend {
            Backend::Auto => Self::Auto,
            Backend::Gpu => Self::Gpu,
            Backend::Cpu => Self::Cpu,
        }
    }
}

/// The `--backend` option shared by `deform`, `track` and `demo`.
#[derive(Debug, clap::Args)]
pub struct BackendArgs {
    /// Where both stages run: `gpu` through wgpu (honours WGPU_BACKEND and
    /// WGPU_ADAPTER_NAME), `cpu`, or `auto` (a hardware GPU when there is
    /// one, else the CPU; the choice and its reason are printed).
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
}

/// Chooses the device for `backend` and, unless `quiet`, prints
/// `backend: <choice> (<why>)`.
pub fn pick(backend: Backend, quiet: bool) -> Result<Device> {
    let picked = Device::pick(backend.into())?;
    if !quiet {
        println!("backend: {picked}");
    }
    Ok(picked.device)
}
