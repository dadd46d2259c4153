"""The simulator's URDF of a robot: the source URDF with the model's collision geometry (convex
hulls as OBJ, the feet's boxes: climb_core.geometry_cache), the finger joints kept, and what only
PyBullet needs:

- every link gets a positive mass and inertia (PyBullet drops massless links' dynamics);
- the armature of each joint (``sim.armature``, ``sim.finger_armature``) is added as ``a * I3`` to
  its child link's inertia, as climb_core.robot adds it to the Pinocchio model (PyBullet has no
  joint armature);
- text STL visual meshes are converted to OBJ (PyBullet drops them silently);
- ``package://`` paths are resolved.

The file is written once per key (everything it derives from) under .cache/robots/ and checked by
loading it in a private DIRECT client: its total mass must match Pinocchio's.
"""
from __future__ import annotations

import os
import pathlib
import threading
import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING, Any

import numpy as np

from climb_core.errors import ClimbError
from climb_core.geometry_cache import (apply_collision_geometry, atomic_write, cache_dir, config_key, obj_text,
                                       stamped_urdf, write_mesh)
from climb_core.robot_config import RobotConfig

if TYPE_CHECKING:  # pragma: no cover - typing only
    import pinocchio as pin

__all__ = ["sim_urdf_path", "SimUrdfWriter", "is_ascii_stl"]

#: Bump when the simulator URDF writer changes (invalidates the on-disk cache).
_GENERATOR = "climb_core.robot sim URDF v1"
#: PyBullet and Pinocchio total masses must agree within this fraction.
_MASS_TOLERANCE = 0.01


def sim_urdf_path(robot: Any) -> pathlib.Path:
    """PyBullet-ready URDF of a climb_core RobotModel (finger joints kept), written if needed.

    Load it with ``flags=p.URDF_USE_INERTIA_FROM_FILE`` (PyBullet otherwise recomputes the inertia
    from the collision shapes and loses the armature)."""
    writer = SimUrdfWriter(robot.config)
    return writer.cached() or writer.write(robot.full_collision_model, robot.mass)


def is_ascii_stl(path: pathlib.Path | str) -> bool:
    """True for a text STL (PyBullet drops those silently); binary STL size = 84 + 50 n."""
    path = pathlib.Path(path)
    if path.suffix.lower() != ".stl":
        return False
    size = path.stat().st_size
    with open(path, "rb") as f:
        header = f.read(84)
    if len(header) == 84 and 84 + 50 * int.from_bytes(header[80:84], "little") == size:
        return False
    return header[:5].lower() == b"solid"


def mesh_obj(path: pathlib.Path, scale: np.ndarray) -> str:
    """A mesh file (any format coal / assimp reads) as OBJ text, scale applied."""
    import coal

    bvh = coal.MeshLoader().load(str(path), np.asarray(scale, dtype=float))
    points = np.asarray(bvh.vertices(), dtype=float)
    tris = np.array([[t[0], t[1], t[2]] for t in (bvh.tri_indices(i) for i in range(bvh.num_tris))],
                    dtype=int).reshape(-1, 3)
    return obj_text(points, tris)


class SimUrdfWriter:
    """Writes <cache>/<name>_<key>_sim.urdf, key = hash of everything the file derives from."""

    def __init__(self, config: RobotConfig):
        self.config = config
        self.cache = cache_dir()
        key = config_key(config, _GENERATOR)
        # The key is in the name: a config edited elsewhere (or a test's variant) never overwrites
        # the file another process is using; the stamp line double-checks it.
        self.out = self.cache / f"{config.name}_{key}_sim.urdf"
        self.stamp = f"<!-- {_GENERATOR}; key={key} -->"

    def cached(self) -> pathlib.Path | None:
        """The cached URDF if it is up to date (and every mesh it names exists), else None."""
        return stamped_urdf(self.out, self.stamp)

    def write(self, geom: "pin.GeometryModel", expected_mass: float) -> pathlib.Path:
        text = self._generate(geom)
        _verify_in_pybullet(text, expected_mass, self.config.name, self.cache)
        atomic_write(self.out, text)
        return self.out

    def _mesh(self, text: str, stem: str) -> pathlib.Path:
        return write_mesh(self.config, text, stem, self.cache)

    def _resolve(self, filename: str) -> pathlib.Path:
        if filename.startswith("package://"):
            rel = filename[len("package://"):].lstrip("/")
            for d in self.config.package_dirs:
                if (d / rel).is_file():
                    return (d / rel).resolve()
            raise ClimbError(f"{self.config.name}: cannot resolve {filename} in {self.config.package_dirs}")
        if filename.startswith("file://"):
            filename = filename[len("file://"):]
        p = pathlib.Path(filename)
        return (p if p.is_absolute() else self.config.urdf_path.parent / p).resolve()

    def _generate(self, geom: "pin.GeometryModel") -> str:
        cfg = self.config
        tree = ET.parse(cfg.urdf_path)
        root = tree.getroot()
        joints_by_child = {el.find("child").get("link"): el for el in root.findall("joint")}
        locked = set(cfg.locked_joints)
        for link in root.findall("link"):
            self._fix_inertial(link, joints_by_child.get(link.get("name")), locked)
        apply_collision_geometry(root, cfg, geom, self._mesh)
        for link in root.findall("link"):
            name = link.get("name")
            for k, vis in enumerate(link.findall("visual")):
                mesh = vis.find("geometry/mesh")
                if mesh is None:
                    continue
                src = self._resolve(mesh.get("filename"))
                if is_ascii_stl(src):  # PyBullet silently drops text STL: convert
                    scale = np.array([float(x) for x in mesh.get("scale", "1 1 1").split()])
                    mesh.set("filename", str(self._mesh(mesh_obj(src, scale), f"{name}_visual_{k}")))
                    mesh.attrib.pop("scale", None)
                else:
                    mesh.set("filename", str(src))
        for any_mesh in root.iter("mesh"):
            fn = any_mesh.get("filename")
            if fn.startswith("package://"):
                any_mesh.set("filename", str(self._resolve(fn)))
        ET.indent(tree)
        body = ET.tostring(root, encoding="unicode")
        return f'<?xml version="1.0"?>\n{self.stamp}\n{body}\n'

    def _fix_inertial(self, link: ET.Element, parent_joint: ET.Element | None, locked: set[str]) -> None:
        sim = self.config.sim
        inertial = link.find("inertial")
        mass_el = None if inertial is None else inertial.find("mass")
        if inertial is None or mass_el is None or float(mass_el.get("value", 0.0)) <= 0.0:
            if inertial is not None:
                link.remove(inertial)
            inertial = ET.Element("inertial")
            link.insert(0, inertial)
            ET.SubElement(inertial, "origin", {"xyz": "0 0 0", "rpy": "0 0 0"})
            ET.SubElement(inertial, "mass", {"value": f"{sim.tiny_mass:.9g}"})
            i = f"{sim.tiny_inertia:.9g}"
            ET.SubElement(inertial, "inertia", {"ixx": i, "ixy": "0", "ixz": "0", "iyy": i, "iyz": "0", "izz": i})
        if parent_joint is None or parent_joint.get("type") not in ("revolute", "continuous", "prismatic"):
            return
        a = sim.finger_armature if parent_joint.get("name") in locked else sim.armature
        if a <= 0:
            return
        inertia = inertial.find("inertia")
        for key in ("ixx", "iyy", "izz"):
            inertia.set(key, f"{float(inertia.get(key, 0.0)) + a:.9g}")


def _verify_in_pybullet(text: str, expected_mass: float, name: str, cache: pathlib.Path) -> None:
    """Load the generated URDF in a private DIRECT client; its total mass must match Pinocchio's."""
    import pybullet as p

    tmp = cache / f".{name}_verify.{os.getpid()}.{threading.get_ident()}.urdf"
    atomic_write(tmp, text)
    client = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(tmp), useFixedBase=False, physicsClientId=client)
        mass = sum(p.getDynamicsInfo(body, link, physicsClientId=client)[0]
                   for link in range(-1, p.getNumJoints(body, physicsClientId=client)))
    except p.error as exc:
        raise ClimbError(f"{name}: PyBullet cannot load the generated URDF: {exc}") from exc
    finally:
        p.disconnect(client)
        tmp.unlink(missing_ok=True)
    if abs(mass - expected_mass) > _MASS_TOLERANCE * expected_mass:
        raise ClimbError(f"{name}: PyBullet mass {mass:.3f} kg != Pinocchio mass {expected_mass:.3f} kg")
