//! Reads from GPU buffers back to the host: one staging buffer kept
//! between reads ([`Readback`]), or a one-off one ([`read_buffer`]). A
//! typed storage buffer reads itself through one
//! ([`crate::buffer::Storage::read`]).

use bytemuck::Pod;

use crate::GpuError;

/// Reads the first `len` elements of `buffer` through a new staging buffer
/// (one-off reads of buffers kept raw; what is read every batch goes
/// through a kept [`Readback`]).
pub(crate) fn read_buffer<T: Pod>(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    buffer: &wgpu::Buffer,
    len: usize,
) -> Result<Vec<T>, GpuError> {
    Readback::default().read_as(device, queue, buffer, len)
}

/// A staging buffer for reads back to the host, kept between reads and
/// grown when a larger one is asked for: a solve reads its step norms back
/// every batch, and would otherwise create a buffer each time.
#[derive(Debug, Default)]
pub(crate) struct Readback {
    staging: std::sync::Mutex<Option<wgpu::Buffer>>,
    /// Tests only: the least size of a staging buffer this one creates, to
    /// make a read inside a solve ask for more memory than the device has.
    #[cfg(test)]
    pub(crate) least: u64,
}

impl Readback {
    /// Reads the first `len` elements of type `T` of `buffer` back (stalls
    /// until the GPU is done).
    pub(crate) fn read_as<T: Pod>(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        buffer: &wgpu::Buffer,
        len: usize,
    ) -> Result<Vec<T>, GpuError> {
        let bytes = self.read(device, queue, buffer, len * std::mem::size_of::<T>())?;
        Ok(bytemuck::pod_collect_to_vec(&bytes))
    }

    /// Copies the first `size` bytes of `buffer` to the staging buffer and
    /// reads them (stalls until the GPU is done).
    fn read(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        buffer: &wgpu::Buffer,
        size: usize,
    ) -> Result<Vec<u8>, GpuError> {
        let size = (size as u64).div_ceil(4) * 4;
        if size == 0 {
            return Ok(Vec::new());
        }
        // A poisoned lock only means another read panicked; the buffer is
        // unmapped or replaced below either way.
        let mut kept = self.staging.lock().unwrap_or_else(|e| e.into_inner());
        #[cfg(test)]
        let allocated = size.max(self.least);
        #[cfg(not(test))]
        let allocated = size;
        let staging = match kept.take() {
            Some(staging) if staging.size() >= size => staging,
            _ => device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("readback"),
                size: allocated,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        };
        let mut encoder = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("readback"),
        });
        encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, size);
        queue.submit([encoder.finish()]);
        let (sender, receiver) = std::sync::mpsc::channel();
        staging.map_async(wgpu::MapMode::Read, ..size, move |result| {
            // The receiver waits below; a failed send only means it gave up.
            let _ = sender.send(result);
        });
        crate::wait(device)?;
        receiver
            .recv()
            .map_err(|e| GpuError::Map(e.to_string()))?
            .map_err(|e| GpuError::Map(e.to_string()))?;
        let bytes = staging
            .get_mapped_range(..size)
            .map_err(|e| GpuError::Map(e.to_string()))?
            .to_vec();
        staging.unmap();
        *kept = Some(staging);
        Ok(bytes)
    }
}
