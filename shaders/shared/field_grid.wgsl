// Where the surface field's grid lies and how its `field_cells` buffer is
// laid out: what every query of `shared/surface_field` takes.

struct FieldGrid {
    // xyz the corner of cell (0, 0, 0), w the cell edge.
    origin: vec4<f32>,
    // Cells along x, y, z; w the number of triangles.
    dims: vec4<u32>,
    // Where `field_cells` holds the CSR starts (x), candidates (y) and
    // candidate distances (z); the cell states begin at 0.
    sections: vec4<u32>,
}
