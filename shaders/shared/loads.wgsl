// What acts on a particle besides the force between particles, read from
// the `loads` buffer, for a state of `count` particles. Twin of
// `tissue_cpu::kernels::integrate::applied` and
// `tissue_solve::stage2::springs`. The buffer holds, per particle, its body
// force (zero without loads) and, after them where the plan has springs,
// its spring towards the observation in two entries: its point c in xyz
// and its stiffness a in w, then its axis u in xyz and the stiffness b
// added along it in w (the potential (q − c)^T P (q − c) / 2 with
// P = a I + b u u^T). One (zero) entry: neither.

@group(0) @binding(24) var<storage, read> loads: array<vec4<f32>>;

// Particle i's body force.
fn body_force(i: u32, count: u32) -> vec3<f32> {
    if (arrayLength(&loads) >= count) {
        return loads[i].xyz;
    }
    return vec3<f32>(0.0);
}

// `tissue_solve::stage2::Spring`: (c, a) and (u, b).
struct Spring {
    anchor: vec4<f32>,
    axis: vec4<f32>,
}

// Particle i's spring (zero where the plan has none).
fn spring_of(i: u32, count: u32) -> Spring {
    if (arrayLength(&loads) == 3u * count) {
        return Spring(loads[count + 2u * i], loads[count + 2u * i + 1u]);
    }
    return Spring(vec4<f32>(0.0), vec4<f32>(0.0));
}

// P v.
fn spring_times(s: Spring, v: vec3<f32>) -> vec3<f32> {
    return s.anchor.w * v + (s.axis.w * dot(s.axis.xyz, v)) * s.axis.xyz;
}

// The spring's pull at q: P (c − q).
fn spring_pull(i: u32, count: u32, q: vec3<f32>) -> vec3<f32> {
    let s = spring_of(i, count);
    return spring_times(s, s.anchor.xyz - q);
}

// The spring's part of K u for a displacement u: P u / 2.
fn spring_operator(i: u32, count: u32, u: vec3<f32>) -> vec3<f32> {
    return 0.5 * spring_times(spring_of(i, count), u);
}

// The spring's part of the potential at q: (q − c)^T P (q − c) / 2.
fn spring_potential(i: u32, count: u32, q: vec3<f32>) -> f32 {
    let s = spring_of(i, count);
    let miss = q - s.anchor.xyz;
    return 0.5 * dot(miss, spring_times(s, miss));
}
