"""Triangle-mesh generators for scene objects (pure numpy/trimesh, no Mitsuba).

Meshes are accumulated per material in a :class:`MeshGroup` as positions
``(V, 3)`` in metres (world frame, z up), faces ``(F, 3)``, texture
coordinates ``(V, 2)`` in metres divided by the texture's tile size, and
per-vertex linear RGB colours ``(V, 3)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["MeshGroup", "box_mesh", "rotation_z", "trimesh_mesh", "cylinder_mesh",
           "sphere_mesh", "heightfield_mesh", "quad_mesh"]


def rotation_z(angle_rad: float) -> np.ndarray:
    """3x3 rotation about the world z axis by ``angle_rad`` radians."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class MeshGroup:
    """Growing triangle soup of one material."""

    positions: list = field(default_factory=list)
    faces: list = field(default_factory=list)
    uvs: list = field(default_factory=list)
    colors: list = field(default_factory=list)
    count: int = 0

    def add(self, positions: np.ndarray, faces: np.ndarray, uvs: np.ndarray, color=(1.0, 1.0, 1.0)) -> None:
        """Append a mesh; ``color`` is one RGB triple or per-vertex ``(V, 3)``."""
        positions = np.asarray(positions, dtype=np.float64)
        color = np.asarray(color, dtype=np.float64)
        if color.ndim == 1:
            color = np.broadcast_to(color, positions.shape)
        self.positions.append(positions)
        self.faces.append(np.asarray(faces, dtype=np.int64) + self.count)
        self.uvs.append(np.asarray(uvs, dtype=np.float64))
        self.colors.append(color)
        self.count += len(positions)

    def arrays(self):
        """Concatenated ``(positions, faces, uvs, colors)``."""
        return (np.concatenate(self.positions), np.concatenate(self.faces),
                np.concatenate(self.uvs), np.concatenate(self.colors))


# Corner signs of the six faces of a unit box, counter-clockwise seen from outside.
_BOX_FACES = (
    ((1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)),
    ((-1, 1, -1), (-1, -1, -1), (-1, -1, 1), (-1, 1, 1)),
    ((1, 1, -1), (-1, 1, -1), (-1, 1, 1), (1, 1, 1)),
    ((-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)),
    ((-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)),
    ((-1, 1, -1), (1, 1, -1), (1, -1, -1), (-1, -1, -1)),
)


def quad_mesh(corners: np.ndarray, *, tile: float = 1.0):
    """Two triangles of a planar quad ``corners (4, 3)``; UVs in metres / ``tile``."""
    corners = np.asarray(corners, dtype=np.float64)
    e1 = corners[1] - corners[0]
    e2 = corners[3] - corners[0]
    u_len, v_len = np.linalg.norm(e1), np.linalg.norm(e2)
    uvs = np.array([[0, 0], [u_len, 0], [u_len, v_len], [0, v_len]]) / tile
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return corners, faces, uvs


def box_mesh(center, size, *, yaw: float = 0.0, tile: float = 1.0, inward: bool = False):
    """Axis-aligned box (then turned by ``yaw`` radians about z) with metric UVs per face.

    Parameters
    ----------
    center : (3,) array_like
        Box centre in metres.
    size : (3,) array_like
        Extent along x, y, z in metres.
    yaw : float, keyword-only
        Rotation about the vertical axis, radians.
    tile : float, keyword-only
        Texture repeat length in metres.
    inward : bool, keyword-only
        Faces point inside (a room).

    Returns
    -------
    positions (24, 3), faces (12, 3), uvs (24, 2)
    """
    half = np.asarray(size, dtype=np.float64) / 2.0
    rot = rotation_z(yaw)
    positions, faces, uvs = [], [], []
    for k, face in enumerate(_BOX_FACES):
        corners = np.array(face, dtype=np.float64) * half
        corners = corners @ rot.T + np.asarray(center, dtype=np.float64)
        if inward:
            corners = corners[::-1]
        p, f, uv = quad_mesh(corners, tile=tile)
        positions.append(p)
        faces.append(f + 4 * k)
        uvs.append(uv)
    return np.concatenate(positions), np.concatenate(faces), np.concatenate(uvs)


def trimesh_mesh(mesh, *, tile: float = 1.0):
    """Positions, faces and planar-projected UVs (x, y + z in metres / tile) of a trimesh mesh."""
    positions = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    uvs = np.stack([positions[:, 0] + positions[:, 2], positions[:, 1] + positions[:, 2]], axis=1) / tile
    return positions, faces, uvs


def cylinder_mesh(base, *, radius: float, height: float, sections: int = 16, tile: float = 1.0):
    """Vertical cylinder standing on ``base`` (3,), via trimesh."""
    import trimesh

    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    mesh.apply_translation(np.asarray(base, dtype=np.float64) + [0.0, 0.0, height / 2.0])
    return trimesh_mesh(mesh, tile=tile)


def sphere_mesh(center, *, radius: float, subdivisions: int = 2, scale=(1.0, 1.0, 1.0),
                tile: float = 1.0):
    """(Ellipsoidal) icosphere around ``center`` (3,), via trimesh."""
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    mesh.apply_scale(np.asarray(scale, dtype=np.float64))
    mesh.apply_translation(np.asarray(center, dtype=np.float64))
    return trimesh_mesh(mesh, tile=tile)


def heightfield_mesh(size_xy, *, cells: int, heights: np.ndarray, tile: float = 1.0):
    """Ground grid of ``size_xy`` metres centred on the origin with ``heights (cells+1, cells+1)``."""
    sx, sy = size_xy
    xs = np.linspace(-sx / 2, sx / 2, cells + 1)
    ys = np.linspace(-sy / 2, sy / 2, cells + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    positions = np.stack([gx, gy, heights], axis=-1).reshape(-1, 3)
    idx = np.arange((cells + 1) ** 2).reshape(cells + 1, cells + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    uvs = positions[:, :2] / tile
    return positions, faces, uvs
