"""On-disk cache of a robot's collision geometry: the source URDF with every collision mesh
replaced by its convex hull (OBJ) and each foot's collision elements by the foot box.

Computing the hulls of G1's meshes with qhull costs ~1.5 s; loading them from the cached OBJ
files ~0.3 s, which every node pays at start-up. The cache is keyed by everything it derives from
(the URDF, the robot config, the coal / Pinocchio / example-robot-data versions), so an edit
anywhere writes a new file beside the old one instead of changing a file another process reads.
The simulator's URDF (sim_bridge.sim_urdf) applies the same collision geometry with
:func:`apply_collision_geometry` and adds what only the simulator needs.
"""
from __future__ import annotations

import hashlib
import importlib.metadata
import os
import pathlib
import threading
import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from climb_core.contact import FEET
from climb_core.errors import ClimbError
from climb_core.robot_config import RobotConfig, foot_box_geometry
from climb_core.ros_env import project_root

if TYPE_CHECKING:  # pragma: no cover - typing only
    import pinocchio as pin

__all__ = ["cache_dir", "atomic_write", "obj_text", "config_key", "write_mesh", "stamped_urdf",
           "apply_collision_geometry", "CollisionUrdfCache"]

#: Bump when the collision URDF written here changes (invalidates the on-disk cache).
_GENERATOR = "climb_core.geometry_cache collision URDF v1"


def cache_dir() -> pathlib.Path:
    """<project>/.cache/robots (or ~/.cache/climb/robots outside a checkout), created if needed."""
    try:
        base = project_root() / ".cache" / "robots"
    except FileNotFoundError:
        base = pathlib.Path.home() / ".cache" / "climb" / "robots"
    base.mkdir(parents=True, exist_ok=True)
    return base


def atomic_write(path: pathlib.Path, content: str | bytes) -> None:
    """Write through a private temporary file and rename: a reader never sees half a file."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")
    mode = "wb" if isinstance(content, bytes) else "w"
    with open(tmp, mode) as f:
        f.write(content)
    os.replace(tmp, path)


def obj_text(points: np.ndarray, triangles: np.ndarray) -> str:
    """Wavefront OBJ text of a triangle mesh (0-based triangle indices)."""
    lines = [f"v {p[0]:.9g} {p[1]:.9g} {p[2]:.9g}" for p in points]
    lines += [f"f {t[0] + 1} {t[1] + 1} {t[2] + 1}" for t in triangles]
    return "\n".join(lines) + "\n"


def _convex_obj(convex: Any) -> str:
    points = np.asarray(convex.points(), dtype=float)
    tris = np.array([[t[0], t[1], t[2]] for t in (convex.polygons(i) for i in range(convex.num_polygons))],
                    dtype=int).reshape(-1, 3)
    return obj_text(points, tris)


def config_key(config: RobotConfig, generator: str) -> str:
    """16 hex digits of a hash of ``generator`` and everything a derived robot file depends on."""
    h = hashlib.sha256()
    h.update(generator.encode())
    h.update(str(config.urdf_path).encode())
    h.update(config.urdf_path.read_bytes())
    if config.config_path is not None:
        h.update(config.config_path.read_bytes())
    else:
        h.update(repr(config).encode())
    for dist in ("coal", "pin", "example-robot-data"):
        try:
            h.update(importlib.metadata.version(dist).encode())
        except importlib.metadata.PackageNotFoundError:
            pass
    return h.hexdigest()[:16]


def write_mesh(config: RobotConfig, text: str, stem: str, directory: pathlib.Path | None = None) -> pathlib.Path:
    """<cache>/<robot>_meshes/<stem>_<digest>.obj (content-addressed: written once, never changed)."""
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    mesh_dir = (directory or cache_dir()) / f"{config.name}_meshes"
    mesh_dir.mkdir(parents=True, exist_ok=True)
    path = mesh_dir / f"{stem}_{digest}.obj"
    if not path.is_file():
        atomic_write(path, text)
    return path


def stamped_urdf(path: pathlib.Path, stamp: str) -> pathlib.Path | None:
    """``path`` when it is a URDF written with ``stamp`` on its second line whose every mesh file
    exists (an up-to-date cache entry), else None."""
    if not path.is_file():
        return None
    lines = path.read_text().split("\n", 2)
    if len(lines) < 2 or lines[1].strip() != stamp:
        return None
    for mesh in ET.fromstring(lines[2] if len(lines) > 2 else "<robot/>").iter("mesh"):
        if not pathlib.Path(mesh.get("filename", "")).is_file():
            return None
    return path


def apply_collision_geometry(root: ET.Element, config: RobotConfig, geom: "pin.GeometryModel",
                             mesh_writer: Callable[[str, str], pathlib.Path]) -> None:
    """In a parsed URDF: each collision mesh becomes its hull in ``geom`` (object ``<link>_<k>``,
    written as OBJ by ``mesh_writer(text, stem)``); the feet's collision elements become one box
    whose bottom face is the sole polygon (``sim.foot_box``)."""
    hulls = {obj.name: obj.geometry for obj in geom.geometryObjects}
    foot_links = {config.limbs[limb].surface.frame: limb for limb in FEET} if config.sim.foot_box else {}
    for link in root.findall("link"):
        name = link.get("name")
        for k, col in enumerate(link.findall("collision")):
            if name in foot_links:
                link.remove(col)
                continue
            mesh = col.find("geometry/mesh")
            if mesh is None:
                continue
            hull = hulls.get(f"{name}_{k}")
            if hull is None:
                raise ClimbError(f"{config.name}: no collision hull for {name} element {k}")
            mesh.set("filename", str(mesh_writer(_convex_obj(hull), f"{name}_{k}")))
            mesh.attrib.pop("scale", None)
        if name in foot_links:
            size, centre = foot_box_geometry(config, foot_links[name])
            col = ET.SubElement(link, "collision", {"name": f"{name}_foot_box"})
            ET.SubElement(col, "origin", {"xyz": " ".join(f"{x:.9g}" for x in centre), "rpy": "0 0 0"})
            geo = ET.SubElement(col, "geometry")
            ET.SubElement(geo, "box", {"size": " ".join(f"{x:.9g}" for x in size)})


class CollisionUrdfCache:
    """<cache>/<name>_<key>_collision.urdf: the robot's collision geometry, hulls as OBJ files."""

    def __init__(self, config: RobotConfig):
        self.config = config
        self.cache = cache_dir()
        key = config_key(config, _GENERATOR)
        self.out = self.cache / f"{config.name}_{key}_collision.urdf"
        self.stamp = f"<!-- {_GENERATOR}; key={key} -->"

    def cached(self) -> pathlib.Path | None:
        """The cached URDF if it is up to date and every mesh it names exists, else None."""
        return stamped_urdf(self.out, self.stamp)

    def write(self, geom: "pin.GeometryModel") -> pathlib.Path:
        """Write the collision URDF of ``geom`` (hulls already built); visuals are dropped."""
        tree = ET.parse(self.config.urdf_path)
        root = tree.getroot()
        for link in root.findall("link"):
            for visual in link.findall("visual"):
                link.remove(visual)
        apply_collision_geometry(root, self.config, geom,
                                 lambda text, stem: write_mesh(self.config, text, stem, self.cache))
        ET.indent(tree)
        body = ET.tostring(root, encoding="unicode")
        atomic_write(self.out, f'<?xml version="1.0"?>\n{self.stamp}\n{body}\n')
        return self.out
