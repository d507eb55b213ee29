// Stage 1, eqs. (2)-(6): the IMF pair forces over a particle's neighbour row,
// the surface's force (eq. (3), paper force) or the wall's reaction from the
// last move (projection), and the balloon's compression. Twin of
// `tissue_cpu::sampling::imf_force`; inputs in its order: state (`current`:
// xyz position, w radius; `contact`), rows, field, parameters.

#import shared/sampling
#import shared/surface_field

@group(0) @binding(1) var<storage, read> current: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> contact: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> offsets: array<u32>;
@group(0) @binding(4) var<storage, read> neighbours: array<u32>;
// xyz the force F_i, w the compression |F_compress,i|.
@group(0) @binding(5) var<storage, read_write> forces: array<vec4<f32>>;
// Non-zero once this batch stopped for a neighbour-row rebuild.
@group(0) @binding(6) var<storage, read> halt: array<u32>;

// Entry k of the neighbour rows: in `neighbours` below `row_split`, in
// `offsets` after the row starts from there (rows too long for one binding).
fn row_entry(k: u32) -> u32 {
    if (k < sampling.row_split) {
        return neighbours[k];
    }
    return offsets[sampling.count + 1u + k - sampling.row_split];
}

// Eqs. (4)-(5), `imf_pair`: signed magnitude along j -> i, positive repels.
fn imf_pair(distance: f32, radius_sum: f32, alpha: f32) -> f32 {
    let h = 1.0 / (alpha * distance / radius_sum + (1.0 - alpha));
    let h3 = h * h * h;
    return h3 * h3 - h3;
}

@compute @workgroup_size(WORKGROUP_SIZE)
fn imf_force(
    @builtin(workgroup_id) workgroup: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) local: u32,
) {
    let i = particle_index(workgroup, groups, local);
    if (i >= sampling.count || halt[0] != 0u) {
        return;
    }
    let p = current[i].xyz;
    let r = current[i].w;
    let cutoff = sampling.cutoff;
    var force = vec3<f32>(0.0);
    var magnitudes = 0.0;
    for (var k = offsets[i]; k < offsets[i + 1u]; k++) {
        let other = current[row_entry(k)];
        let offset = p - other.xyz;
        let radius_sum = r + other.w;
        let d2 = dot(offset, offset);
        if (d2 >= (cutoff * radius_sum) * (cutoff * radius_sum) || d2 == 0.0) {
            continue;
        }
        let d = sqrt(d2);
        let f = imf_pair(d, radius_sum, sampling.alpha);
        force += offset * (f / d);
        magnitudes += abs(f);
    }
    // eq. (6): |F_compress| = sum |F_j| - |sum F_j|; when counted, the
    // surface's force is one more term on both sides.
    var wall = vec3<f32>(0.0);
    var moves = true;
    if (sampling.surface_mode == 0u) {
        // Projection: the reaction counts in the compression; the move is the projection's.
        wall = -contact[i].w * contact[i].xyz;
        moves = false;
    } else {
        // eq. (3): -n while outside, weighted by mu in eq. (2).
        let q = field_query(field_grid(), p);
        if (q.side == SIDE_NEAR && q.nearest.distance > 0.0) {
            wall = -sampling.mu * q.nearest.normal;
        } else if (q.side == SIDE_DEEP_OUTSIDE) {
            wall = -sampling.mu * nearest_of_all(field_grid(), p).normal;
        }
    }
    var compression = magnitudes - length(force);
    if (sampling.wall_in_compression != 0u) {
        compression = magnitudes + length(wall) - length(force + wall);
    }
    forces[i] = vec4<f32>(select(force, force + wall, moves), max(compression, 0.0));
}
