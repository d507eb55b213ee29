//! The surface field on the GPU: its buffers, and the query that checks
//! the shaders' reading of them against [`SurfaceField::query`].

use glam::Vec3;
use tissue_core::SamplingParams;
use tissue_core::field::{Nearest, Side, SurfaceField};
use wgpu::util::DeviceExt;

use super::buffers::{SamplingUniforms, storage, zeroed};
use super::kernels::compile;
use crate::GpuError;
use crate::buffer::{Storage, vec4, xyz};
use crate::readback::Readback;
use crate::state::workgroups;
use crate::support::{Scopes, bind_group, scoped, submit_one};

/// The surface field on the GPU: the same data as [`SurfaceField`], packed
/// into the two buffers `shaders/shared/surface_field.wgsl` reads.
#[derive(Debug)]
pub struct FieldBuffers {
    /// Cell states, CSR starts, candidates, candidate distances (f32 bits):
    /// four sections of u32 words, where `layout` says.
    pub(crate) cells: Storage<u32>,
    /// Per triangle: three corners and seven normals, `vec4` each.
    pub(crate) triangles: Storage<[f32; 4]>,
    /// The field grid's corner (xyz) and cell edge (w).
    pub(crate) origin: [f32; 4],
    /// Cells along x, y, z; w the triangle count.
    pub(crate) dims: [u32; 4],
    /// Where `cells` holds the CSR starts, candidates and candidate distances.
    pub(crate) layout: [u32; 4],
    /// `SurfaceField::margin`.
    pub(super) margin: f32,
}

impl FieldBuffers {
    /// Uploads `field`.
    pub fn new(device: &wgpu::Device, field: &SurfaceField) -> Result<Self, GpuError> {
        let cells = field.cell_state.len();
        let total = 2 * cells + 1 + 2 * field.candidates.len();
        let too_many = |what: &str, asked: usize| GpuError::LimitExceeded {
            limit: "u32 index",
            what: format!("the surface field's {what}"),
            asked: asked as u64,
            allowed: u64::from(u32::MAX),
        };
        let index = |n: usize, what: &str| u32::try_from(n).map_err(|_| too_many(what, n));
        let starts = index(cells, "cells")?;
        let candidates = index(2 * cells + 1, "cells")?;
        let distances = index(2 * cells + 1 + field.candidates.len(), "candidates")?;
        index(total, "candidates")?;
        let triangles = index(field.corners.len(), "triangles")?;
        let mut packed: Vec<u32> = Vec::with_capacity(total);
        packed.extend_from_slice(&field.cell_state);
        packed.extend_from_slice(&field.cell_start);
        packed.extend_from_slice(&field.candidates);
        packed.extend(field.candidate_distance.iter().map(|d| d.to_bits()));
        let geometry: Vec<[f32; 4]> = field
            .corners
            .iter()
            .zip(&field.normals)
            .flat_map(|(corners, normals)| {
                corners
                    .iter()
                    .chain(normals.iter())
                    .map(|&v| vec4(v, 0.0))
                    .collect::<Vec<_>>()
            })
            .collect();
        let what = || format!("{cells} cells, {} triangles", field.corners.len());
        let (cells_buffer, triangles_buffer) = scoped(device, || {
            Ok((
                storage(device, "field_cells", &packed, &what)?,
                storage(device, "field_triangles", &geometry, &what)?,
            ))
        })?;
        Ok(Self {
            cells: cells_buffer,
            triangles: triangles_buffer,
            origin: field.origin.extend(field.cell).to_array(),
            dims: [field.dims[0], field.dims[1], field.dims[2], triangles],
            layout: [starts, candidates, distances, 0],
            margin: field.margin,
        })
    }
}

/// The field query of `shaders/shared/surface_field.wgsl` at `points` (the
/// twin of [`SurfaceField::query`]), through the test kernel
/// `shaders/tests/surface_field.wgsl`: for tests and tools.
pub fn query_field(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    field: &SurfaceField,
    points: &[Vec3],
) -> Result<Vec<Side>, GpuError> {
    let n = points.len();
    if n == 0 {
        return Ok(Vec::new());
    }
    let count = u32::try_from(n).map_err(|_| GpuError::Length {
        what: "query points (below u32::MAX)",
        expected: u32::MAX as usize,
        got: n,
    })?;
    let scope = Scopes::push(device);
    let kernel = compile(device, "tests/surface_field", "field_query_test");
    scope.pop()?;
    let kernel = kernel?;
    let buffers = FieldBuffers::new(device, field)?;
    let mut uniforms =
        SamplingUniforms::new(&buffers, &SamplingParams::default(), 1.0, count, u32::MAX);
    uniforms.groups = 1;
    let what = || format!("{n} query points");
    let points4: Vec<[f32; 4]> = points.iter().map(|&p| vec4(p, 0.0)).collect();
    let [x, y] = workgroups(
        count,
        kernel.workgroup_size,
        device.limits().max_compute_workgroups_per_dimension,
    )?;
    let answers = scoped(device, || {
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("query uniforms"),
            contents: bytemuck::bytes_of(&uniforms),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let points_buffer = storage(device, "points", &points4, &what)?;
        // Four `vec4` per point: the side, distance and triangle, the
        // point, the normal, the barycentric coordinates.
        let answers: Storage<[f32; 4]> = zeroed(device, "answers", n * 4, &what)?;
        let group = bind_group(
            device,
            &kernel,
            ("tests/surface_field", "field query"),
            |name| match name {
                "sampling" => Some(&uniform),
                "points" => Some(points_buffer.buffer()),
                "answers" => Some(answers.buffer()),
                "field_cells" => Some(buffers.cells.buffer()),
                "field_triangles" => Some(buffers.triangles.buffer()),
                _ => None,
            },
            None,
            "names no buffer",
        )?;
        submit_one(device, queue, &kernel, &group, [x, y], "field query");
        Ok(answers)
    })?;
    let raw = answers.read(device, queue, &Readback::default())?;
    Ok(raw
        .chunks_exact(4)
        .map(|a| match a[0][0].to_bits() {
            0 => Side::DeepInside,
            1 => Side::DeepOutside,
            _ => Side::Near(Nearest {
                distance: a[0][1],
                point: xyz(a[1]),
                normal: xyz(a[2]),
                triangle: a[0][2].to_bits(),
                barycentric: [a[3][0], a[3][1], a[3][2]],
            }),
        })
        .collect())
}
