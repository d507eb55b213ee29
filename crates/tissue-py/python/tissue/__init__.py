"""tissue: where the inside of a soft organ goes when its surface moves.

The organ's interior is filled with particles (``sample``, stage 1); the
surface particles then follow an observed, deformed surface and the
interior follows them (``Model.deformer`` and ``Deformer.solve``, stage 2).
Points inside the organ (a tumour's vertices, landmarks) ride along
(``Deformer.carry``; a rigid structure by ``Deformer.carry_rigid``, which
also gives its motion as a 4x4 matrix). Arrays are numpy arrays in the surface's units.

    import tissue
    model = tissue.sample(tissue.phantom_breast(), particles=2000)
    deformer = model.deformer(backend="cpu")
    vertices, _ = tissue.phantom_breast_sagged()
    report = deformer.solve(vertices)
    moved = deformer.carry([[0.0, 0.0, 20.0]])

With the two scans' postures, ``Model.deformer_in_posture`` first finds
the organ's unloaded shape and (unless given) its stiffness from the skin,
then solves with the deformed posture's gravity inside:

    posed = model.deformer_in_posture(vertices, (0, 0, -1), (0, -1, 0))
    posed.solve(vertices)
    posed.posture["stiffness_kpa"]

The results go to the files 3D Slicer and ParaView read, as the command
line writes them: ``Deformer.save_particles`` (``particles.vtp``),
``Deformer.save_displacement_field`` (a NRRD grid transform),
``Deformer.carry_file`` (landmarks of a ``.mrk.json`` or ``.csv``, moved)
and ``save_motion`` (a rigid structure's ``.tfm``).

A scanner's point cloud of the organ (no correspondence to the model) is
read by ``load_cloud``; ``rigid_fit`` finds the rigid motion that puts it
on a surface (for a scan in another frame), ``fiducial_fit`` the one that
puts fiducials given in the scan's frame onto the same points in the
model's. ``Deformer.match_observation``
pulls the skin onto another segmentation's surface or onto a scan without
correspondence (the deformer's ``observed`` vertices held at rest);
``from_last=True`` matches a sequence's next frame from the last answer.

Every computation releases the GIL. Errors are ``tissue.TissueError``,
with the messages of the command-line tool.
"""

from ._tissue import (
    Deformer,
    Model,
    TissueError,
    __version__,
    fiducial_fit,
    load_cloud,
    load_model,
    phantom_breast,
    phantom_breast_sagged,
    rigid_fit,
    sample,
    save_motion,
)

__all__ = [
    "Deformer",
    "Model",
    "TissueError",
    "__version__",
    "fiducial_fit",
    "load_cloud",
    "load_model",
    "phantom_breast",
    "phantom_breast_sagged",
    "rigid_fit",
    "sample",
    "save_motion",
]
