//! What the unit tests that run kernels share: a device, and a model.

#![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

use crate::GpuError;

/// A device from the environment (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`),
/// or `None` after saying the test is skipped, as the integration tests
/// do (under `CI=true` a missing adapter fails).
pub(crate) fn gpu(test: &str) -> Option<(wgpu::Device, wgpu::Queue)> {
    match crate::device_from_env() {
        Ok((_, device, queue)) => Some((device, queue)),
        Err(GpuError::NoAdapter(why)) => {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "{test}: no GPU adapter under CI=true ({why})"
            );
            eprintln!("SKIPPED: no GPU adapter ({test}: {why})");
            None
        }
        Err(e) => panic!("{test}: the adapter would not open a device: {e}"),
    }
}

/// The bundled breast phantom sampled with `particles` particles.
pub(crate) fn phantom(particles: usize) -> tissue_core::ParticleModel {
    tissue_cpu::sample(
        &tissue_core::phantom::default_breast(),
        &tissue_core::SamplingParams::with_particles(particles),
        &mut |_| {},
    )
    .unwrap()
    .model
}
