//! Checks that a surface is one closed, consistently oriented, outward shell.
//!
//! Sampling the inside of an organ needs an inside: [`validate`] accepts a
//! mesh only when it bounds a single solid, and turns an inward-facing one
//! around. The checks run in a fixed order and the first failing one is
//! reported, with how often the defect occurs and where one instance sits:
//!
//! 1. empty ([`MeshError::Empty`]),
//! 2. non-finite coordinates ([`MeshError::NonFinite`]),
//! 3. indices out of range ([`MeshError::IndexOutOfRange`]),
//! 4. a size outside [`SIZE_RANGE`] ([`MeshError::Size`]),
//! 5. degenerate triangles ([`MeshError::Degenerate`]),
//! 6. edges shared by more than two triangles ([`MeshError::NonManifold`]),
//! 7. boundary edges ([`MeshError::Open`]),
//! 8. neighbours wound in opposite directions ([`MeshError::InconsistentOrientation`]),
//! 9. more than one edge-connected piece ([`MeshError::SeveralShells`]),
//! 10. no enclosed volume ([`MeshError::ZeroVolume`]).
//!
//! Everything is a linear pass or one sort of the edges, so a mesh with a
//! million triangles validates in a fraction of a second.
//!
//! Not checked: self-intersections and vertices where two sheets touch at a
//! single point (both keep the inside well defined for point sampling).
//!
//! A surface with stray pieces beside the organ (scanner specks, a detached
//! fragment) fails check 9; [`keep_largest_shell`] drops all but the piece
//! enclosing the most volume, for a caller who asks for that explicitly.

use glam::{DVec3, Vec3};

use crate::error::MeshError;
use crate::mesh::SurfaceMesh;

/// A triangle is degenerate when its area is below this times the squared
/// bounding-box diagonal (or when two of its corners are the same vertex).
pub const DEGENERATE_AREA: f64 = 1e-12;

/// The bounding-box diagonals a surface may have, in its own units: an
/// organ is about 0.1 across in metres, 100 in millimetres, 1e5 in
/// micrometres. Beyond these, single-precision squares and cubes of the
/// particle spacing underflow or overflow (a phantom in millimetres scaled
/// by 1e-30 made every particle every other's neighbour, and sampling took
/// a minute to fail).
pub const SIZE_RANGE: (f64, f64) = (1e-6, 1e9);

/// A closed surface encloses no volume when `|volume|` is below this times the
/// cubed bounding-box diagonal.
pub const ZERO_VOLUME: f64 = 1e-10;

/// What [`validate`] found, and did, on a surface that passed every check.
#[derive(Debug, Clone, Copy, PartialEq)]
#[must_use = "`flipped` says whether the mesh was turned inside out"]
pub struct Validation {
    /// The surface faced inward (negative signed volume) and the winding of
    /// every triangle was reversed so that it now faces outward.
    pub flipped: bool,
    /// Enclosed volume after any flip; always positive.
    pub volume: f64,
    /// Surface area.
    pub area: f64,
}

/// What [`keep_largest_shell`] removed.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ShellsDropped {
    /// Shells removed: all but one, or 0 when the mesh was one shell already.
    pub count: usize,
    /// Triangles in the removed shells, together.
    pub triangles: usize,
    /// The largest `|signed volume|` among the removed shells (0 when none
    /// was removed), to set against the kept one: a value close to it means
    /// the file held two organs rather than an organ and some debris.
    pub largest_other_volume: f64,
}

/// Keeps the edge-connected shell of `mesh` that encloses the most volume
/// and drops the others, with the vertices only they used.
///
/// Shells are ranked by `|signed volume|` (winding either way counts; a
/// volume that is not a number ranks last), then by triangle count, then by
/// lowest first triangle. Triangles keep their order and corners; kept
/// vertices keep their order and are renumbered from 0.
///
/// A mesh of one shell (or none) comes back unchanged, with
/// [`ShellsDropped::count`] 0; so does one whose triangles name missing
/// vertices, for [`validate`] to report. Nothing else is checked: run
/// [`validate`] on the result.
///
/// # Examples
///
/// ```
/// use tissue_core::{SurfaceMesh, Vec3, validate::{keep_largest_shell, validate}};
///
/// // A unit tetrahedron, then one twice its size beside it.
/// let small = [Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z];
/// let big = small.map(|v| 2.0 * v + Vec3::splat(5.0));
/// let faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
/// let mesh = SurfaceMesh::new(
///     [small, big].concat(),
///     faces.iter().chain(&faces.map(|t| t.map(|i| i + 4))).copied().collect(),
/// );
/// assert!(validate(&mut mesh.clone()).is_err()); // two shells
///
/// let (mut kept, dropped) = keep_largest_shell(&mesh);
/// assert_eq!(kept.vertices, big);
/// assert_eq!(kept.triangles, faces);
/// assert_eq!((dropped.count, dropped.triangles), (1, 4));
/// assert!((dropped.largest_other_volume - 1.0 / 6.0).abs() < 1e-9);
/// assert!((validate(&mut kept)?.volume - 8.0 / 6.0).abs() < 1e-6);
/// # Ok::<(), tissue_core::MeshError>(())
/// ```
pub fn keep_largest_shell(mesh: &SurfaceMesh) -> (SurfaceMesh, ShellsDropped) {
    let unchanged = || (mesh.clone(), ShellsDropped::default());
    if check_indices(mesh).is_err() {
        return unchanged();
    }
    let shells = Shells::new(mesh.triangles.len(), &sorted_half_edges(mesh));
    if shells.count() <= 1 {
        return unchanged();
    }

    let centre = bounding_centre(mesh);
    let mut volume = vec![0.0; shells.count()];
    let mut triangles = vec![0usize; shells.count()];
    for (t, &shell) in shells.of_triangle.iter().enumerate() {
        volume[shell] += six_cone_volume(mesh, t, centre) / 6.0;
        triangles[shell] += 1;
    }
    let size = |shell: usize| {
        let v = volume[shell];
        if v.is_nan() {
            f64::NEG_INFINITY
        } else {
            v.abs()
        }
    };
    // Shells are numbered by first triangle, so keeping the earlier on a tie
    // breaks it by lowest first triangle.
    let kept = (1..shells.count()).fold(0, |best, shell| {
        let larger = size(shell)
            .total_cmp(&size(best))
            .then(triangles[shell].cmp(&triangles[best]))
            .is_gt();
        if larger { shell } else { best }
    });

    let mut kept_triangles: Vec<[u32; 3]> = mesh
        .triangles
        .iter()
        .zip(&shells.of_triangle)
        .filter(|&(_, &shell)| shell == kept)
        .map(|(&t, _)| t)
        .collect();
    let mut used = vec![false; mesh.vertices.len()];
    for &i in kept_triangles.iter().flatten() {
        used[i as usize] = true;
    }
    let mut vertices = Vec::new();
    let renumbered: Vec<u32> = used
        .iter()
        .zip(&mesh.vertices)
        .map(|(&used, &v)| {
            if !used {
                return u32::MAX;
            }
            vertices.push(v);
            vertices.len() as u32 - 1
        })
        .collect();
    for t in &mut kept_triangles {
        *t = t.map(|i| renumbered[i as usize]);
    }

    let dropped = ShellsDropped {
        count: shells.count() - 1,
        triangles: mesh.triangles.len() - triangles[kept],
        largest_other_volume: (0..shells.count())
            .filter(|&shell| shell != kept)
            .map(|shell| volume[shell].abs())
            .fold(0.0, f64::max),
    };
    (SurfaceMesh::new(vertices, kept_triangles), dropped)
}

/// Checks that `mesh` is a single closed, consistently oriented surface
/// enclosing a volume, and makes it face outward.
///
/// The checks and their order are listed in the [module docs](self); the
/// first one that fails is returned and `mesh` is left untouched. When the
/// surface passes but faces inward, every triangle's winding is reversed in
/// place, a `log::warn!` is emitted and [`Validation::flipped`] is `true`.
///
/// Vertices are compared by index: weld duplicated positions first
/// ([`crate::io::surface::weld`]), or a mesh read from STL looks like a
/// soup of separate triangles.
///
/// # Errors
///
/// The [`MeshError`] of the first failing check.
///
/// # Examples
///
/// ```
/// use tissue_core::{SurfaceMesh, Vec3, validate::validate};
///
/// // A tetrahedron with every triangle wound clockwise seen from outside.
/// let mut mesh = SurfaceMesh::new(
///     vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
///     vec![[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
/// );
/// let validation = validate(&mut mesh)?;
/// assert!(validation.flipped);
/// assert!((validation.volume - 1.0 / 6.0).abs() < 1e-9);
/// assert!(mesh.signed_volume() > 0.0);
/// # Ok::<(), tissue_core::MeshError>(())
/// ```
pub fn validate(mesh: &mut SurfaceMesh) -> Result<Validation, MeshError> {
    check_not_empty(mesh)?;
    check_finite(mesh)?;
    check_indices(mesh)?;
    let diagonal = bounding_diagonal(mesh);
    if !(SIZE_RANGE.0..=SIZE_RANGE.1).contains(&diagonal) {
        return Err(MeshError::Size {
            diagonal,
            range: SIZE_RANGE,
        });
    }
    check_degenerate(mesh, diagonal)?;
    check_edges(mesh)?;

    let signed = signed_volume(mesh);
    if signed.abs() <= ZERO_VOLUME * diagonal.powi(3) {
        return Err(MeshError::ZeroVolume { volume: signed });
    }
    let flipped = signed < 0.0;
    if flipped {
        for triangle in &mut mesh.triangles {
            triangle.swap(1, 2);
        }
        log::warn!(
            "the surface faced inward (signed volume {signed}); reversed the winding of all {} triangles",
            mesh.triangles.len()
        );
    }
    Ok(Validation {
        flipped,
        volume: signed.abs(),
        area: mesh.area(),
    })
}

fn check_not_empty(mesh: &SurfaceMesh) -> Result<(), MeshError> {
    if mesh.vertices.is_empty() || mesh.triangles.is_empty() {
        return Err(MeshError::Empty {
            vertices: mesh.vertices.len(),
            triangles: mesh.triangles.len(),
        });
    }
    Ok(())
}

fn check_finite(mesh: &SurfaceMesh) -> Result<(), MeshError> {
    let mut bad = mesh
        .vertices
        .iter()
        .enumerate()
        .filter(|(_, v)| !v.is_finite());
    if let Some((example, value)) = bad.next() {
        return Err(MeshError::NonFinite {
            count: 1 + bad.count(),
            example,
            value: value.to_array(),
        });
    }
    Ok(())
}

/// Every triangle refers to existing vertices.
pub(crate) fn check_indices(mesh: &SurfaceMesh) -> Result<(), MeshError> {
    let vertices = mesh.vertices.len();
    let out_of_range = |t: &[u32; 3]| t.iter().copied().find(|&i| i as usize >= vertices);
    let mut bad = mesh
        .triangles
        .iter()
        .enumerate()
        .filter_map(|(t, triangle)| Some((t, out_of_range(triangle)?)));
    if let Some((example, vertex)) = bad.next() {
        return Err(MeshError::IndexOutOfRange {
            count: 1 + bad.count(),
            example,
            vertex,
            vertices,
        });
    }
    Ok(())
}

fn check_degenerate(mesh: &SurfaceMesh, diagonal: f64) -> Result<(), MeshError> {
    // Compare twice the area squared, |(b - a) x (c - a)|^2, to avoid a sqrt per triangle.
    let limit = (2.0 * DEGENERATE_AREA * diagonal * diagonal).powi(2);
    let is_degenerate = |t: usize| {
        let [a, b, c] = mesh.triangles[t];
        if a == b || b == c || c == a {
            return true;
        }
        let [a, b, c] = mesh.corners(t).map(Vec3::as_dvec3);
        (b - a).cross(c - a).length_squared() <= limit
    };
    let mut bad = (0..mesh.triangles.len()).filter(|&t| is_degenerate(t));
    if let Some(example) = bad.next() {
        return Err(MeshError::Degenerate {
            count: 1 + bad.count(),
            example,
            at: centroid(mesh, example),
        });
    }
    Ok(())
}

/// One side of a triangle, keyed by its undirected edge so that equal edges
/// sort next to each other.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct HalfEdge {
    /// `(min << 32) | max` of the two vertex indices.
    key: u64,
    /// The triangle index times two, plus one when the triangle walks the
    /// edge from its larger to its smaller vertex.
    triangle_and_direction: u64,
}

impl HalfEdge {
    fn new(from: u32, to: u32, triangle: usize) -> Self {
        let (lo, hi) = if from < to { (from, to) } else { (to, from) };
        Self {
            key: (u64::from(lo) << 32) | u64::from(hi),
            triangle_and_direction: ((triangle as u64) << 1) | u64::from(from > to),
        }
    }

    fn ends(self) -> (usize, usize) {
        ((self.key >> 32) as usize, (self.key & 0xffff_ffff) as usize)
    }

    fn triangle(self) -> usize {
        (self.triangle_and_direction >> 1) as usize
    }

    fn reversed(self) -> bool {
        self.triangle_and_direction & 1 == 1
    }
}

/// Count of offending edges and the first one (in sorted order).
#[derive(Default)]
struct EdgeTally {
    count: usize,
    example: Option<(usize, usize)>,
}

impl EdgeTally {
    fn add(&mut self, edge: HalfEdge) {
        self.count += 1;
        self.example.get_or_insert(edge.ends());
    }
}

/// The three half-edges of every triangle, sorted so that the sides of one
/// undirected edge are adjacent.
fn sorted_half_edges(mesh: &SurfaceMesh) -> Vec<HalfEdge> {
    let mut half_edges: Vec<HalfEdge> = mesh
        .triangles
        .iter()
        .enumerate()
        .flat_map(|(t, &[a, b, c])| {
            [
                HalfEdge::new(a, b, t),
                HalfEdge::new(b, c, t),
                HalfEdge::new(c, a, t),
            ]
        })
        .collect();
    half_edges.sort_unstable();
    half_edges
}

/// Manifoldness, closedness, orientation and connectivity, from one sort of
/// all half-edges: a closed oriented manifold has every undirected edge
/// exactly twice, walked in opposite directions.
fn check_edges(mesh: &SurfaceMesh) -> Result<(), MeshError> {
    let half_edges = sorted_half_edges(mesh);
    let mut non_manifold = EdgeTally::default();
    let mut open = EdgeTally::default();
    let mut inconsistent = EdgeTally::default();
    for run in half_edges.chunk_by(|x, y| x.key == y.key) {
        match *run {
            [edge] => open.add(edge),
            [first, second] => {
                if first.reversed() == second.reversed() {
                    inconsistent.add(first);
                }
            }
            _ => non_manifold.add(run[0]),
        }
    }

    let point = |i: usize| mesh.vertices[i].to_array();
    if let Some((at, to)) = non_manifold.example {
        return Err(MeshError::NonManifold {
            count: non_manifold.count,
            at: point(at),
            to: point(to),
        });
    }
    if let Some((at, to)) = open.example {
        return Err(MeshError::Open {
            count: open.count,
            at: point(at),
            to: point(to),
        });
    }
    if let Some((at, to)) = inconsistent.example {
        return Err(MeshError::InconsistentOrientation {
            count: inconsistent.count,
            at: point(at),
            to: point(to),
        });
    }
    let shells = Shells::new(mesh.triangles.len(), &half_edges);
    if let Some(&example) = shells.first_triangle.get(1) {
        return Err(MeshError::SeveralShells {
            count: shells.count(),
            example,
            at: centroid(mesh, example),
        });
    }
    Ok(())
}

/// The edge-connected pieces of a surface: triangles that share an edge
/// (with each other or through a third) are in one shell, however many
/// triangles meet at the edge.
struct Shells {
    /// The shell of each triangle; shells are numbered in order of their
    /// first triangle, so triangle 0 is in shell 0.
    of_triangle: Vec<usize>,
    /// The first (lowest-numbered) triangle of each shell.
    first_triangle: Vec<usize>,
}

impl Shells {
    /// The shells of `triangles` triangles whose half-edges, from
    /// [`sorted_half_edges`], are `half_edges`.
    fn new(triangles: usize, half_edges: &[HalfEdge]) -> Self {
        let mut sets = UnionFind::new(triangles);
        for run in half_edges.chunk_by(|x, y| x.key == y.key) {
            for pair in run.windows(2) {
                sets.union(pair[0].triangle(), pair[1].triangle());
            }
        }
        let mut shell_of_root = vec![usize::MAX; triangles];
        let mut first_triangle = Vec::new();
        let of_triangle = (0..triangles)
            .map(|t| {
                let shell = &mut shell_of_root[sets.find(t)];
                if *shell == usize::MAX {
                    *shell = first_triangle.len();
                    first_triangle.push(t);
                }
                *shell
            })
            .collect();
        Self {
            of_triangle,
            first_triangle,
        }
    }

    fn count(&self) -> usize {
        self.first_triangle.len()
    }
}

/// Disjoint sets over triangle indices (union by size, path halving).
struct UnionFind {
    parent: Vec<usize>,
    size: Vec<usize>,
}

impl UnionFind {
    fn new(n: usize) -> Self {
        Self {
            parent: (0..n).collect(),
            size: vec![1; n],
        }
    }

    fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] != x {
            self.parent[x] = self.parent[self.parent[x]];
            x = self.parent[x];
        }
        x
    }

    fn union(&mut self, a: usize, b: usize) {
        let (a, b) = (self.find(a), self.find(b));
        if a == b {
            return;
        }
        let (big, small) = if self.size[a] >= self.size[b] {
            (a, b)
        } else {
            (b, a)
        };
        self.parent[small] = big;
        self.size[big] += self.size[small];
    }
}

fn bounding_diagonal(mesh: &SurfaceMesh) -> f64 {
    mesh.bounds()
        .map_or(0.0, |(lo, hi)| (hi.as_dvec3() - lo.as_dvec3()).length())
}

fn centroid(mesh: &SurfaceMesh, t: usize) -> [f32; 3] {
    let [a, b, c] = mesh.corners(t);
    ((a + b + c) / 3.0).to_array()
}

/// Signed volume about the bounding-box centre (rather than the origin), so
/// that a mesh far from the origin does not lose digits to cancellation.
fn signed_volume(mesh: &SurfaceMesh) -> f64 {
    let centre = bounding_centre(mesh);
    (0..mesh.triangles.len())
        .map(|t| six_cone_volume(mesh, t, centre))
        .sum::<f64>()
        / 6.0
}

fn bounding_centre(mesh: &SurfaceMesh) -> DVec3 {
    mesh.bounds().map_or(DVec3::ZERO, |(lo, hi)| {
        0.5 * (lo.as_dvec3() + hi.as_dvec3())
    })
}

/// Six times the signed volume of the tetrahedron from `centre` to
/// triangle `t`; summed over a closed surface, six times its volume.
fn six_cone_volume(mesh: &SurfaceMesh, t: usize, centre: DVec3) -> f64 {
    let [a, b, c] = mesh.corners(t).map(|v| v.as_dvec3() - centre);
    a.dot(b.cross(c))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]

    use super::*;

    fn tetrahedron() -> SurfaceMesh {
        SurfaceMesh::new(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        )
    }

    #[test]
    fn sizes_outside_the_range_are_refused_naming_the_size() {
        for (scale, accepted) in [
            (1e-30, false),
            (1e-7, false),
            (1e-5, true),
            (1e8, true),
            (1e10, false),
        ] {
            let mut mesh = tetrahedron();
            for v in &mut mesh.vertices {
                *v *= scale;
            }
            match validate(&mut mesh) {
                Ok(_) => assert!(accepted, "scale {scale} accepted"),
                Err(MeshError::Size { diagonal, .. }) => {
                    assert!(!accepted, "scale {scale} refused");
                    assert!((diagonal / (f64::from(scale) * 3f64.sqrt()) - 1.0).abs() < 1e-3);
                }
                Err(other) => panic!("scale {scale}: {other}"),
            }
        }
    }

    #[test]
    fn outward_tetrahedron_passes_unchanged() {
        let mut mesh = tetrahedron();
        let validation = validate(&mut mesh).unwrap();
        assert!(!validation.flipped);
        assert!((validation.volume - 1.0 / 6.0).abs() < 1e-12);
        assert_eq!(mesh, tetrahedron());
    }

    #[test]
    fn signed_volume_about_centre_matches_origin_formula() {
        let mut mesh = tetrahedron();
        for v in &mut mesh.vertices {
            *v += Vec3::new(1000.0, -2000.0, 500.0);
        }
        assert!((signed_volume(&mesh) - 1.0 / 6.0).abs() < 1e-9);
    }

    #[test]
    fn half_edge_packs_direction_and_triangle() {
        let forward = HalfEdge::new(3, 7, 5);
        let backward = HalfEdge::new(7, 3, 6);
        assert_eq!(forward.key, backward.key);
        assert_eq!(forward.ends(), (3, 7));
        assert_eq!((forward.triangle(), forward.reversed()), (5, false));
        assert_eq!((backward.triangle(), backward.reversed()), (6, true));
    }

    #[test]
    fn shells_are_numbered_by_first_triangle_and_joined_through_any_edge() {
        // Triangles 0 and 2 share edge 0-1; 1 and 3 share edge 5-6; 5 and 6
        // join 0's shell through edge 1-2, which three triangles share; 4
        // touches 6 only at vertex 10, so it stands alone.
        let mesh = SurfaceMesh::new(
            vec![Vec3::ZERO; 12],
            vec![
                [0, 1, 2],
                [4, 5, 6],
                [1, 0, 3],
                [6, 5, 7],
                [8, 9, 10],
                [2, 1, 11],
                [1, 2, 10],
            ],
        );
        let shells = Shells::new(mesh.triangles.len(), &sorted_half_edges(&mesh));
        assert_eq!(shells.of_triangle, [0, 1, 0, 1, 2, 0, 0]);
        assert_eq!(shells.first_triangle, [0, 1, 4]);
    }

    #[test]
    fn union_find_counts_components() {
        let mut sets = UnionFind::new(5);
        sets.union(0, 1);
        sets.union(3, 4);
        sets.union(1, 0);
        let roots = (0..5).filter(|&x| sets.find(x) == x).count();
        assert_eq!(roots, 3);
        assert_eq!(sets.find(0), sets.find(1));
        assert_ne!(sets.find(2), sets.find(3));
    }
}
