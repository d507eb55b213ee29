//! The GPU grid and neighbour rows against their CPU twins in
//! `tissue_cpu::grid`: the grid exactly (`cell_start`, `particles`, and the
//! layout), the prefix sum exactly, the rows as sets (a pair may differ only
//! where its distance is within `ROW_TOLERANCE` of its limit, relative).

mod common;

use glam::Vec3;
use tissue_cpu::stage1::{grid_build, neighbour_rows};
use tissue_gpu::{GpuError, GridPipelines};
use tissue_testkit::cloud;
use wgpu::util::DeviceExt;

/// A pair's distance may round to either side of its limit on the GPU
/// (fused multiply-adds): allowed within this fraction of the limit.
const ROW_TOLERANCE: f32 = 1e-5;

/// Particles as the GPU holds them: xyz position, w radius.
fn upload(device: &wgpu::Device, positions: &[Vec3], radii: &[f32]) -> wgpu::Buffer {
    let data: Vec<[f32; 4]> = positions
        .iter()
        .zip(radii)
        .map(|(p, &r)| p.extend(r).to_array())
        .collect();
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("test particles"),
        contents: bytemuck::cast_slice(&data),
        usage: wgpu::BufferUsages::STORAGE,
    })
}

fn ok<T>(result: Result<T, GpuError>) -> T {
    result.unwrap_or_else(|e| panic!("{e}"))
}

fn pipelines(device: &wgpu::Device) -> GridPipelines {
    ok(GridPipelines::new(device))
}

/// The GPU grid of `positions` must be the CPU's, word for word.
fn assert_grid_equal(
    what: &str,
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    grids: &GridPipelines,
    positions: &[Vec3],
    cell: f32,
) {
    let radii = vec![0.0; positions.len()];
    let buffer = upload(device, positions, &radii);
    let built = ok(grids.grid_build(device, queue, &buffer, positions.len() as u32, cell));
    let gpu = ok(built.read(device, queue));
    let cpu = grid_build(positions, cell);
    assert_eq!(
        (gpu.origin, gpu.cell, gpu.dims),
        (cpu.origin, cpu.cell, cpu.dims),
        "{what}: layout (origin, cell, dims), GPU vs CPU"
    );
    assert_eq!(gpu.cell_start.len(), cpu.cell_start.len(), "{what}: cells");
    if let Some(c) = (0..cpu.cell_start.len()).find(|&c| gpu.cell_start[c] != cpu.cell_start[c]) {
        panic!(
            "{what}: cell_start[{c}]: GPU {} vs CPU {} (exact)",
            gpu.cell_start[c], cpu.cell_start[c]
        );
    }
    if let Some(k) = (0..cpu.particles.len()).find(|&k| gpu.particles[k] != cpu.particles[k]) {
        panic!(
            "{what}: particles[{k}]: GPU particle {} vs CPU particle {} (exact)",
            gpu.particles[k], cpu.particles[k]
        );
    }
    assert_eq!(
        gpu.particles.len(),
        cpu.particles.len(),
        "{what}: particles"
    );
}

#[test]
fn grid_build_equals_the_cpu_at_awkward_counts() {
    let Some((device, queue)) = common::gpu("grid_build parity") else {
        return;
    };
    let grids = pipelines(&device);
    for (n, scale, cell) in [
        (0, Vec3::ONE, 0.1),
        (1, Vec3::ONE, 0.1),
        (63, Vec3::ONE, 0.1),
        (64, Vec3::ONE, 0.1),
        (65, Vec3::new(1.0, 0.1, 3.0), 0.1),
        (1_000, Vec3::ONE, 0.05),
        (10_007, Vec3::new(2.0, 0.5, 1.0), 0.04),
        // Cells far below the spacing: the layout must grow the cell.
        (10_007, Vec3::ONE, 1e-4),
    ] {
        let (positions, _) = cloud(n, n as u64, scale);
        assert_grid_equal(
            &format!("{n} particles in {scale}, cell {cell}"),
            &device,
            &queue,
            &grids,
            &positions,
            cell,
        );
    }
}

#[test]
fn grid_build_equals_the_cpu_on_the_10k_phantom() {
    let Some((device, queue)) = common::gpu("grid_build phantom parity") else {
        return;
    };
    let model = common::phantom(10_000);
    let r0 = model.radii.iter().sum::<f32>() / model.radii.len() as f32;
    let grids = pipelines(&device);
    for cell in [2.0 * r0, 0.5 * r0] {
        assert_grid_equal(
            &format!("phantom, cell {cell}"),
            &device,
            &queue,
            &grids,
            &model.positions,
            cell,
        );
    }
}

#[test]
fn grid_build_equals_the_cpu_with_all_particles_in_one_cell_and_outliers() {
    let Some((device, queue)) = common::gpu("grid_build one cell") else {
        return;
    };
    let grids = pipelines(&device);
    let mut positions = vec![Vec3::splat(0.5); 300];
    assert_grid_equal("300 equal points", &device, &queue, &grids, &positions, 0.2);
    // No cell asked for: the layout's floor, f32::MIN_POSITIVE, not a
    // subnormal that a device flushing subnormals would hold at zero.
    assert_grid_equal(
        "300 equal points, no cell",
        &device,
        &queue,
        &grids,
        &positions,
        0.0,
    );
    positions.push(Vec3::splat(1e4));
    positions.push(Vec3::splat(-1e4));
    positions.push(Vec3::new(-0.0, 0.0, -1e-30));
    assert_grid_equal(
        "one cell and outliers",
        &device,
        &queue,
        &grids,
        &positions,
        0.2,
    );
}

#[test]
fn prefix_scan_is_exact_at_awkward_lengths_and_three_levels() {
    let Some((device, queue)) = common::gpu("prefix scan") else {
        return;
    };
    let grids = pipelines(&device);
    assert_eq!(grids.scan_levels(100_003), 3, "levels at 100,003");
    for len in [1usize, 63, 64, 65, 4_095, 4_097, 100_003] {
        let values: Vec<u32> = (0..len as u32)
            .map(|k| k.wrapping_mul(2_654_435_761) >> 28)
            .collect();
        let got = ok(grids.exclusive_scan(&device, &queue, &values));
        let mut sum = 0u32;
        for (k, (&v, &g)) in values.iter().zip(&got).enumerate() {
            assert_eq!(
                g, sum,
                "length {len}: element {k}: GPU {g} vs CPU {sum} (exact)"
            );
            sum += v;
        }
        assert_eq!(got.len(), len);
    }
}

/// CSR rows: `(offsets, indices)`.
type Rows = (Vec<u32>, Vec<u32>);

/// Row `i` of the GPU must hold the CPU's row as a set; a pair in one row
/// only must lie within `ROW_TOLERANCE` of its limit.
fn assert_rows_equal(
    what: &str,
    positions: &[Vec3],
    radii: &[f32],
    (factor, skin, sorted): (f32, f32, bool),
    cpu: &Rows,
    gpu: &Rows,
) -> usize {
    let n = positions.len();
    assert_eq!(gpu.0.len(), n + 1, "{what}: offsets");
    let row = |rows: &Rows, i: usize| rows.1[rows.0[i] as usize..rows.0[i + 1] as usize].to_vec();
    let mut borderline = 0;
    for i in 0..n {
        let (mut want, mut got) = (row(cpu, i), row(gpu, i));
        if sorted {
            assert!(
                got.windows(2).all(|w| w[0] < w[1]),
                "{what}: particle {i}: GPU row not ascending: {got:?}"
            );
        }
        want.sort_unstable();
        got.sort_unstable();
        if want == got {
            continue;
        }
        for j in want
            .iter()
            .filter(|j| got.binary_search(j).is_err())
            .chain(got.iter().filter(|j| want.binary_search(j).is_err()))
        {
            let j = *j as usize;
            let distance = (positions[i] - positions[j]).length();
            let limit = factor * (radii[i] + radii[j]) + skin;
            assert!(
                j != i && (distance - limit).abs() <= ROW_TOLERANCE * limit,
                "{what}: particle {i}: neighbour {j} in one row only at distance {distance}, \
                 limit {limit} (tolerance {ROW_TOLERANCE} relative); CPU row {want:?}, GPU row {got:?}"
            );
            borderline += 1;
        }
    }
    borderline
}

fn rows_on_both(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    grids: &GridPipelines,
    positions: &[Vec3],
    radii: &[f32],
    (factor, skin, sorted): (f32, f32, bool),
) -> (Rows, Rows) {
    let buffer = upload(device, positions, radii);
    let rows = ok(grids.neighbour_rows(
        device,
        queue,
        &buffer,
        positions.len() as u32,
        factor,
        skin,
        sorted,
    ));
    let gpu = ok(rows.read(device, queue));
    assert_eq!(rows.entries as usize, gpu.1.len());
    (neighbour_rows(positions, radii, factor, skin, sorted), gpu)
}

#[test]
fn neighbour_rows_equal_the_cpu_as_sets_at_awkward_counts() {
    let Some((device, queue)) = common::gpu("neighbour_rows parity") else {
        return;
    };
    let grids = pipelines(&device);
    for (n, scale) in [
        (0, Vec3::ONE),
        (1, Vec3::ONE),
        (2, Vec3::splat(0.01)),
        (63, Vec3::ONE),
        (65, Vec3::new(1.0, 0.1, 3.0)),
        (1_000, Vec3::ONE),
        (10_007, Vec3::new(2.0, 0.5, 1.0)),
    ] {
        let (positions, radii) = cloud(n, 31 * n as u64, scale);
        for rule in [(0.9, 0.01, true), (1.0, 0.0, false)] {
            let (cpu, gpu) = rows_on_both(&device, &queue, &grids, &positions, &radii, rule);
            let what = format!("{n} particles in {scale}, (factor, skin, sorted) {rule:?}");
            let borderline = assert_rows_equal(&what, &positions, &radii, rule, &cpu, &gpu);
            eprintln!("{what}: {} entries, {borderline} at the limit", cpu.1.len());
        }
    }
}

#[test]
fn neighbour_rows_equal_the_cpu_on_the_10k_phantom() {
    let Some((device, queue)) = common::gpu("neighbour_rows phantom parity") else {
        return;
    };
    let model = common::phantom(10_000);
    let r0 = model.radii.iter().sum::<f32>() / model.radii.len() as f32;
    let grids = pipelines(&device);
    // The sampler's Verlet rows and the connections of eq. (9).
    for rule in [(1.0, 1.2 * r0, false), (1.2, 0.0, true)] {
        let (cpu, gpu) = rows_on_both(
            &device,
            &queue,
            &grids,
            &model.positions,
            &model.radii,
            rule,
        );
        let what = format!("phantom 10k, (factor, skin, sorted) {rule:?}");
        let borderline = assert_rows_equal(&what, &model.positions, &model.radii, rule, &cpu, &gpu);
        eprintln!("{what}: {} entries, {borderline} at the limit", cpu.1.len());
    }
}

#[test]
fn dispatches_beyond_65535_workgroups_run_in_two_dimensions() {
    let Some((device, queue)) = common::gpu("two-dimensional dispatch") else {
        return;
    };
    let grids = pipelines(&device);
    let per_dimension = device.limits().max_compute_workgroups_per_dimension;
    // One workgroup (64 threads) per 64 elements: this needs a second row of workgroups.
    let len = per_dimension as usize * 64 + 4_097;
    let values: Vec<u32> = (0..len as u32).map(|k| k % 3).collect();
    let got = ok(grids.exclusive_scan(&device, &queue, &values));
    let mut sum = 0u32;
    for (k, &v) in values.iter().enumerate() {
        assert_eq!(
            got[k], sum,
            "element {k} of {len}: GPU {} vs CPU {sum}",
            got[k]
        );
        sum += v;
    }
    // 8 cells per particle: 600k particles give a cell prefix sum over 4.8M.
    let (positions, _) = cloud(600_000, 5, Vec3::ONE);
    assert_grid_equal(
        "600k particles, 4.8M cells",
        &device,
        &queue,
        &grids,
        &positions,
        1e-4,
    );
}

#[test]
fn a_non_finite_position_is_an_error_not_a_grid() {
    let Some((device, queue)) = common::gpu("non-finite positions") else {
        return;
    };
    let grids = pipelines(&device);
    let (mut positions, mut radii) = cloud(100, 3, Vec3::ONE);
    positions[17].y = f32::NAN;
    let buffer = upload(&device, &positions, &radii);
    let grid = ok(grids.grid_build(&device, &queue, &buffer, 100, 0.1));
    assert!(
        grid.read(&device, &queue).is_err(),
        "a NaN position gave a grid"
    );
    let rows = grids.neighbour_rows(&device, &queue, &buffer, 100, 1.0, 0.0, true);
    assert!(rows.is_err(), "a NaN position gave rows");
    positions[17].y = 0.5;
    radii[3] = f32::INFINITY;
    let buffer = upload(&device, &positions, &radii);
    let rows = grids.neighbour_rows(&device, &queue, &buffer, 100, 1.0, 0.0, true);
    assert!(rows.is_err(), "an infinite radius gave rows");
    // Host-side checks: a short buffer and a non-finite cell.
    assert!(matches!(
        grids.grid_build(&device, &queue, &buffer, 101, 0.1),
        Err(GpuError::Length { .. })
    ));
    assert!(
        grids
            .grid_build(&device, &queue, &buffer, 100, f32::NAN)
            .is_err()
    );
}

#[test]
fn buffers_above_the_binding_limit_are_refused() {
    let Some((device, queue)) = common::gpu("binding limit") else {
        return;
    };
    let grids = pipelines(&device);
    let limit = device.limits().max_storage_buffer_binding_size;
    // Enough particles for the positions to bind, but not their cell starts
    // (8 cells of 4 bytes per particle: twice the positions' 16 bytes).
    let count = (limit / 16) as u32;
    let buffer = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("large particles"),
        size: u64::from(count) * 16,
        usage: wgpu::BufferUsages::STORAGE,
        mapped_at_creation: false,
    });
    assert!(matches!(
        grids.grid_build(&device, &queue, &buffer, count, 1.0),
        Err(GpuError::LimitExceeded { .. })
    ));
    assert!(matches!(
        grids.neighbour_rows(&device, &queue, &buffer, count, 1.0, 0.0, false),
        Err(GpuError::LimitExceeded { .. })
    ));
}

/// Rows longer than one storage binding (lavapipe's 128 MiB holds stage 1's
/// rows up to about 600,000 particles) continue after the row starts in the
/// offsets buffer. A device whose bindings hold 1.5 MiB splits the 10k
/// phantom's Verlet rows (about 2.2 MB), sorted and not, and they are still
/// the CPU's rows.
#[test]
fn neighbour_rows_longer_than_one_binding_are_the_cpus_rows() {
    let Some((device, queue)) = common::gpu_with_binding("rows over one binding", 3 << 19) else {
        return;
    };
    let model = common::phantom(10_000);
    let r0 = model.radii.iter().sum::<f32>() / model.radii.len() as f32;
    let grids = pipelines(&device);
    for rule in [(1.0, 1.2 * r0, false), (1.0, 1.2 * r0, true)] {
        let buffer = upload(&device, &model.positions, &model.radii);
        let rows = ok(grids.neighbour_rows(
            &device,
            &queue,
            &buffer,
            model.len() as u32,
            rule.0,
            rule.1,
            rule.2,
        ));
        assert!(
            rows.entries > rows.split,
            "{} entries fit one binding of {}: the split is not tested",
            rows.entries,
            rows.split
        );
        let gpu = ok(rows.read(&device, &queue));
        let cpu = neighbour_rows(&model.positions, &model.radii, rule.0, rule.1, rule.2);
        let what = format!("phantom 10k split at {}, {rule:?}", rows.split);
        let borderline = assert_rows_equal(&what, &model.positions, &model.radii, rule, &cpu, &gpu);
        eprintln!("{what}: {} entries, {borderline} at the limit", cpu.1.len());
    }
}

/// Rows longer than two bindings (the row starts and the rest of the
/// entries share the second) are refused by name, not a GPU fault.
#[test]
fn neighbour_rows_longer_than_two_bindings_are_refused() {
    let Some((device, queue)) = common::gpu_with_binding("rows over two bindings", 1 << 16) else {
        return;
    };
    let grids = pipelines(&device);
    // 1,000 particles close together: about 1,000 entries a row.
    let (positions, radii) = cloud(1_000, 7, Vec3::splat(0.01));
    let buffer = upload(&device, &positions, &radii);
    match grids.neighbour_rows(&device, &queue, &buffer, 1_000, 1.0, 0.0, false) {
        Err(GpuError::LimitExceeded { what, .. }) => {
            assert!(what.contains("entries past one binding"), "{what}");
        }
        other => panic!("expected LimitExceeded, got {other:?}"),
    }
}

/// Positive normal floats below 2^126 (where `reciprocal` divides by
/// itself): random significands at every exponent, the significands next
/// to a power of two, and the cells the layout grows through.
fn reciprocal_inputs() -> Vec<f32> {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(0x0ce1_1ed6);
    let mut out = Vec::new();
    for exponent in 1u32..=252 {
        for significand in [0u32, 1, 2, 3, 0x7f_fffe, 0x7f_ffff, 0x40_0000, 0x55_5555] {
            out.push(f32::from_bits(exponent << 23 | significand));
        }
        for _ in 0..400 {
            out.push(f32::from_bits(
                exponent << 23 | rng.random_range(0..0x80_0000),
            ));
        }
    }
    let mut cell = 1e-4f32;
    while cell < 1e4 {
        out.push(cell);
        cell *= 1.25;
    }
    out.extend([0.1, 0.3, 0.7, 1.0 / 3.0, 2.5, 4.0, 1e-30, 1e30]);
    out
}

#[test]
fn the_cells_reciprocal_rounds_as_the_cpus_division() {
    let Some((device, queue)) = common::gpu("reciprocal") else {
        return;
    };
    let inputs = reciprocal_inputs();
    let bytes = common::run_list_kernel(
        &device,
        &queue,
        ("tests/reciprocal", "reciprocal_test"),
        &inputs,
        std::mem::size_of_val(inputs.as_slice()) as u64,
    );
    let got: Vec<f32> = bytemuck::pod_collect_to_vec(&bytes);
    assert!(inputs.len() > 100_000, "{} inputs", inputs.len());
    for (&x, &r) in inputs.iter().zip(&got) {
        let want = 1.0 / x;
        assert_eq!(
            r.to_bits(),
            want.to_bits(),
            "reciprocal({x:e} = {:#010x}): GPU {r:e}, CPU {want:e}",
            x.to_bits()
        );
    }
}
