// What acts on a particle besides the force between particles, read from
// the `loads` buffer, for a state of `count` particles. Twin of
// `tissue_cpu::kernels::integrate::applied` and
// `tissue_solve::stage2::springs`. The buffer holds, per particle, its body
// force (zero without loads) and, after them where the plan has springs,
// its spring towards an observed plane: s = sqrt(w) n in xyz, s . c in w.
// One (zero) entry: neither.

@group(0) @binding(24) var<storage, read> loads: array<vec4<f32>>;

// Particle i's body force.
fn body_force(i: u32, count: u32) -> vec3<f32> {
    if (arrayLength(&loads) >= count) {
        return loads[i].xyz;
    }
    return vec3<f32>(0.0);
}

// Particle i's spring (zero where the plan has none).
fn spring_of(i: u32, count: u32) -> vec4<f32> {
    if (arrayLength(&loads) == 2u * count) {
        return loads[count + i];
    }
    return vec4<f32>(0.0);
}

// The spring's pull at q: s (s . c − s . q).
fn spring_pull(i: u32, count: u32, q: vec3<f32>) -> vec3<f32> {
    let s = spring_of(i, count);
    return s.xyz * (s.w - dot(s.xyz, q));
}

// The spring's part of K u for a displacement u: s (s . u) / 2.
fn spring_operator(i: u32, count: u32, u: vec3<f32>) -> vec3<f32> {
    let s = spring_of(i, count);
    return 0.5 * s.xyz * dot(s.xyz, u);
}

// The spring's part of the potential at q: (s . q − s . c)^2 / 2.
fn spring_potential(i: u32, count: u32, q: vec3<f32>) -> f32 {
    let s = spring_of(i, count);
    let miss = dot(s.xyz, q) - s.w;
    return 0.5 * miss * miss;
}
