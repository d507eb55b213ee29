//! Typed storage buffers: [`Storage<T>`] holds `len` elements of one plain
//! type `T` and does the byte arithmetic of creating, writing and reading
//! them in one place, so callers count in elements.
//!
//! What stays a bare `wgpu::Buffer`, and why:
//! - uniform buffers (their slots sit at the device's uniform offset
//!   alignment, not one after another);
//! - staging buffers ([`crate::readback::Readback`]) and the copy-only
//!   backups of a solve or a sampling batch, which no kernel binds;
//! - the timestamp queries' resolve buffer ([`crate::timing`]);
//! - buffers of the public API: the particle buffer a caller hands to
//!   [`crate::GridPipelines`], the fields of [`crate::GpuGrid`] and
//!   [`crate::GpuRows`], and the rows [`crate::sampler::SamplingBuffers`]
//!   takes, which a caller may create or bind in its own kernels.

use std::marker::PhantomData;

use bytemuck::Pod;
use glam::Vec3;

use crate::GpuError;
use crate::readback::Readback;
use crate::support::check_size;

/// A storage buffer of `len` elements of type `T` (a Rust mirror of the
/// WGSL element: `[f32; 4]` for a `vec4<f32>`, [`crate::Rotation`], `u32`,
/// ...). Kernels bind [`Storage::buffer`]; the host writes and reads whole
/// elements. An empty one still holds 16 zero bytes, as a binding may not
/// be empty.
#[derive(Clone, Debug)]
pub(crate) struct Storage<T: Pod> {
    buffer: wgpu::Buffer,
    len: usize,
    _element: PhantomData<T>,
}

/// The bytes of `n` elements of `T`.
fn bytes_of<T: Pod>(n: usize) -> u64 {
    (n as u64).saturating_mul(std::mem::size_of::<T>() as u64)
}

/// The usages of every storage buffer: bound by kernels, written by the
/// queue, copied from and to (readback, backups).
const USAGE: wgpu::BufferUsages = wgpu::BufferUsages::STORAGE
    .union(wgpu::BufferUsages::COPY_DST)
    .union(wgpu::BufferUsages::COPY_SRC);

/// Fails the build for an element type that is not a whole, non-zero
/// number of 4-byte words: copies and queue writes move whole words.
fn assert_words<T: Pod>() {
    const {
        assert!(
            std::mem::size_of::<T>() > 0 && std::mem::size_of::<T>().is_multiple_of(4),
            "a storage element is a whole number of 4-byte words"
        );
    }
}

impl<T: Pod> Storage<T> {
    /// A buffer holding `contents` (16 zero bytes when empty), or the limit
    /// it would break; `what` names it in the error.
    pub(crate) fn init(
        device: &wgpu::Device,
        label: &'static str,
        contents: &[T],
        what: &str,
    ) -> Result<Self, GpuError> {
        use wgpu::util::DeviceExt;
        assert_words::<T>();
        let padded = [0u8; 16];
        let bytes: &[u8] = if contents.is_empty() {
            &padded
        } else {
            bytemuck::cast_slice(contents)
        };
        check_size(device, bytes.len() as u64, what)?;
        let buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytes,
            usage: USAGE,
        });
        Ok(Self {
            buffer,
            len: contents.len(),
            _element: PhantomData,
        })
    }

    /// A buffer of `len` zeroed elements (16 bytes at least, so that it
    /// binds), or the limit it would break; `what` names it in the error.
    pub(crate) fn zeroed(
        device: &wgpu::Device,
        label: &'static str,
        len: usize,
        what: &str,
    ) -> Result<Self, GpuError> {
        assert_words::<T>();
        let size = bytes_of::<T>(len).max(16);
        check_size(device, size, what)?;
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage: USAGE,
            mapped_at_creation: false,
        });
        Ok(Self {
            buffer,
            len,
            _element: PhantomData,
        })
    }

    /// The buffer itself, for bind groups and copies.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    pub(crate) fn buffer(&self) -> &wgpu::Buffer {
        &self.buffer
    }

    /// The buffer itself, given up (for a public field that holds it raw).
    pub(crate) fn into_buffer(self) -> wgpu::Buffer {
        self.buffer
    }

    /// Writes `data` into elements `first..first + data.len()` (taking
    /// effect at the next submit); refused when that runs past the end.
    pub(crate) fn write(
        &self,
        queue: &wgpu::Queue,
        first: usize,
        data: &[T],
    ) -> Result<(), GpuError> {
        let room = self.len.saturating_sub(first);
        if data.len() > room {
            return Err(GpuError::Length {
                what: "elements written to a storage buffer (its room from the first written)",
                expected: room,
                got: data.len(),
            });
        }
        if !data.is_empty() {
            queue.write_buffer(
                &self.buffer,
                bytes_of::<T>(first),
                bytemuck::cast_slice(data),
            );
        }
        Ok(())
    }

    /// Reads every element back through `readback` (stalls until the GPU
    /// is done).
    pub(crate) fn read(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        readback: &Readback,
    ) -> Result<Vec<T>, GpuError> {
        readback.read_as(device, queue, &self.buffer, self.len)
    }

    /// Reads the first `n` elements back through `readback`; refused when
    /// there are fewer.
    pub(crate) fn read_first(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        readback: &Readback,
        n: usize,
    ) -> Result<Vec<T>, GpuError> {
        if n > self.len {
            return Err(GpuError::Length {
                what: "elements read back from a storage buffer (at most its length)",
                expected: self.len,
                got: n,
            });
        }
        readback.read_as(device, queue, &self.buffer, n)
    }
}

/// A point as the GPU holds it: a `vec4<f32>`, xyz the point, w `w`.
pub(crate) fn vec4(point: Vec3, w: f32) -> [f32; 4] {
    point.extend(w).to_array()
}

/// The point of a `vec4<f32>` (its xyz).
pub(crate) fn xyz(v: [f32; 4]) -> Vec3 {
    Vec3::new(v[0], v[1], v[2])
}

/// Buffers of points, one `vec4<f32>` each with w unused (0): the
/// conversions from and to [`Vec3`].
impl Storage<[f32; 4]> {
    /// A buffer holding `points` (w 0), as [`Storage::init`].
    pub(crate) fn points(
        device: &wgpu::Device,
        label: &'static str,
        points: &[Vec3],
        what: &str,
    ) -> Result<Self, GpuError> {
        let data: Vec<[f32; 4]> = points.iter().map(|&p| vec4(p, 0.0)).collect();
        Self::init(device, label, &data, what)
    }

    /// Writes `points` (w 0) from element `first` on, as [`Storage::write`].
    pub(crate) fn write_points(
        &self,
        queue: &wgpu::Queue,
        first: usize,
        points: &[Vec3],
    ) -> Result<(), GpuError> {
        let data: Vec<[f32; 4]> = points.iter().map(|&p| vec4(p, 0.0)).collect();
        self.write(queue, first, &data)
    }

    /// Reads every point back (w dropped), as [`Storage::read`].
    pub(crate) fn read_points(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        readback: &Readback,
    ) -> Result<Vec<Vec3>, GpuError> {
        Ok(self
            .read(device, queue, readback)?
            .into_iter()
            .map(xyz)
            .collect())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
    use super::*;
    use crate::testing::gpu;

    #[test]
    fn elements_are_written_and_read_where_they_belong() {
        let Some((device, queue)) = gpu("storage elements") else {
            return;
        };
        let readback = Readback::default();
        let buffer = Storage::init(&device, "test", &[1u32, 2, 3, 4, 5], "a test buffer").unwrap();
        buffer.write(&queue, 3, &[40, 50]).unwrap();
        let read = |n| buffer.read_first(&device, &queue, &readback, n);
        assert_eq!(
            buffer.read(&device, &queue, &readback).unwrap(),
            [1, 2, 3, 40, 50]
        );
        assert_eq!(read(2).unwrap(), [1, 2]);
        // Past the end: refused, and nothing is written.
        assert!(matches!(
            buffer.write(&queue, 4, &[0, 0]),
            Err(GpuError::Length {
                expected: 1,
                got: 2,
                ..
            })
        ));
        assert!(matches!(
            buffer.write(&queue, 6, &[0]),
            Err(GpuError::Length {
                expected: 0,
                got: 1,
                ..
            })
        ));
        assert!(matches!(
            read(6),
            Err(GpuError::Length {
                expected: 5,
                got: 6,
                ..
            })
        ));
        assert_eq!(read(5).unwrap(), [1, 2, 3, 40, 50]);
    }

    #[test]
    fn empty_buffers_bind_and_zeroed_ones_read_zero() {
        let Some((device, queue)) = gpu("empty and zeroed storage") else {
            return;
        };
        let readback = Readback::default();
        let empty = Storage::<f32>::init(&device, "empty", &[], "an empty buffer").unwrap();
        assert_eq!(empty.buffer().size(), 16);
        assert!(empty.read(&device, &queue, &readback).unwrap().is_empty());
        let none = Storage::<u32>::zeroed(&device, "none", 0, "no elements").unwrap();
        assert_eq!(none.buffer().size(), 16);
        let zeroed = Storage::<[f32; 4]>::zeroed(&device, "zeroed", 3, "three points").unwrap();
        assert_eq!(zeroed.buffer().size(), 48);
        assert_eq!(
            zeroed.read_points(&device, &queue, &readback).unwrap(),
            [Vec3::ZERO; 3]
        );
        let p = Vec3::new(1.0, -2.0, 0.5);
        zeroed.write_points(&queue, 1, &[p]).unwrap();
        assert_eq!(
            zeroed.read(&device, &queue, &readback).unwrap(),
            [[0.0; 4], [1.0, -2.0, 0.5, 0.0], [0.0; 4]]
        );
    }

    #[test]
    fn a_buffer_beyond_the_device_limits_is_refused_by_name() {
        let Some((device, _)) = gpu("storage limits") else {
            return;
        };
        let too_many = device.limits().max_storage_buffer_binding_size / 16 + 1;
        match Storage::<[f32; 4]>::zeroed(&device, "huge", too_many as usize, "the huge buffer") {
            Err(GpuError::LimitExceeded { what, .. }) => assert_eq!(what, "the huge buffer"),
            other => panic!("expected GpuError::LimitExceeded, got {other:?}"),
        }
    }

    #[test]
    fn element_bytes_saturate_instead_of_wrapping() {
        assert_eq!(bytes_of::<[f32; 4]>(3), 48);
        assert_eq!(bytes_of::<u32>(0), 0);
        assert_eq!(bytes_of::<[f32; 4]>(usize::MAX), u64::MAX);
    }

    #[test]
    fn points_keep_xyz_and_carry_w() {
        let p = Vec3::new(1.0, -2.0, 3.5);
        assert_eq!(vec4(p, 0.25), [1.0, -2.0, 3.5, 0.25]);
        assert_eq!(xyz(vec4(p, 9.0)), p);
    }
}
