"""The package's layout rules, read from the source (AST): who may import what.

- ``lip_ros.core`` is the shared base: it imports neither branch, nor the rig, nodes or tools.
- The branches ``lip_ros.lip`` and ``lip_ros.hsc4d`` never import each other.
- ROS (rclpy and the message packages) only in ``lip_ros.nodes``, ``lip_ros.tools`` and the rclpy backend of
  ``lip_msgs_py``; the ROS-free packages never import the nodes or tools either.
- Heavy libraries only in the modules that wrap them: torch in the LIP networks, their training, the
  torch kinematics, the torch thread count and the HSC4D scene-aware optimisation; kiss-icp and gtsam each in
  one module of the HSC4D branch; embreex in the rig's mesh ray casting; numba in its options' module and the
  four compiled loops (capsule ray casting, forward kinematics' joint chain, the LIP surface fit's normal
  equations, the LIP segmentation's clustering).
- Every installed executable starts in ``lip_ros.nodes`` or ``lip_ros.tools``.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("lip_ros", "lip_msgs_py")

#: Python packages of ROS itself (a full ROS install has them; here the PyPI wheels).
ROS_MODULES = ("rclpy", "rcl_interfaces", "builtin_interfaces", "std_msgs", "std_srvs", "sensor_msgs",
               "geometry_msgs", "nav_msgs", "diagnostic_msgs", "visualization_msgs", "rosgraph_msgs", "tf2_msgs")
#: Where ROS may be imported.
ROS_ALLOWED = ("lip_ros.nodes", "lip_ros.tools", "lip_msgs_py.backend")
#: The ROS-free packages.
ROS_FREE = ("lip_ros.core", "lip_ros.lip", "lip_ros.hsc4d", "lip_ros.rig")
#: Heavy library -> the modules (or packages) allowed to import it, and how many modules may.
HEAVY = {
    "torch": (("lip_ros.core.torch_kinematics", "lip_ros.core.torch_runtime", "lip_ros.lip.nets",
               "lip_ros.lip.train", "lip_ros.hsc4d.scene_optimisation"), None),
    "kiss_icp": (("lip_ros.hsc4d",), 1),
    "gtsam": (("lip_ros.hsc4d",), 1),
    "embreex": (("lip_ros.rig.mesh_raycast",), 1),
    "numba": (("lip_ros.core.compiled", "lip_ros.core.capsule_rays", "lip_ros.core.kinematics_kernel",
               "lip_ros.lip.surface_kernel", "lip_ros.lip.segmentation.clusters"), 5),
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Every module a file imports, at the top or inside functions (``from a import b``: ``a`` and ``a.b``)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}: relative import"  # the code imports absolutely
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


@pytest.fixture(scope="module")
def import_graph() -> dict[str, set[str]]:
    """Module name -> the modules it imports, for every module of the package."""
    files = [p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py")]
    assert len(files) > 50
    return {_module_name(p): _imports(p) for p in files}


def _within(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def _violations(graph: dict[str, set[str]], sources: tuple[str, ...], targets: tuple[str, ...]) -> list[str]:
    return sorted(f"{m} imports {i}" for m, imps in graph.items() if _within(m, sources)
                  for i in imps if _within(i, targets))


def test_the_rules_see_the_imports(import_graph):
    """The graph holds what the rules below look for (so that an empty result means something)."""
    assert "lip_ros.core.skeleton" in import_graph["lip_ros.lip.calibration"]
    assert "rclpy" in import_graph["lip_ros.nodes.base"]
    assert "torch" in import_graph["lip_ros.lip.nets.models"]
    assert "lip_ros.lip" in import_graph and "lip_ros.hsc4d" in import_graph
    assert _violations(import_graph, ("lip_ros.nodes",), ("rclpy",))  # the check finds what is there


def test_core_imports_no_branch_rig_node_or_tool(import_graph):
    assert _violations(import_graph, ("lip_ros.core",), ("lip_ros.lip", "lip_ros.hsc4d", "lip_ros.rig",
                                                          "lip_ros.nodes", "lip_ros.tools")) == []


def test_the_branches_never_import_each_other(import_graph):
    assert _violations(import_graph, ("lip_ros.lip",), ("lip_ros.hsc4d",)) == []
    assert _violations(import_graph, ("lip_ros.hsc4d",), ("lip_ros.lip",)) == []


def test_ros_only_in_nodes_tools_and_the_rclpy_backend(import_graph):
    outside = {m: imps for m, imps in import_graph.items() if not _within(m, ROS_ALLOWED)}
    assert _violations(outside, PACKAGES, ROS_MODULES) == []
    assert _violations(import_graph, ROS_FREE, ("lip_ros.nodes", "lip_ros.tools")) == []


@pytest.mark.parametrize("library", sorted(HEAVY))
def test_heavy_libraries_only_where_they_are_wrapped(import_graph, library):
    allowed, most = HEAVY[library]
    users = sorted(m for m, imps in import_graph.items() if any(_within(i, (library,)) for i in imps))
    assert [m for m in users if not _within(m, allowed)] == []
    if most is not None:
        assert len(users) <= most, users


def test_every_executable_starts_in_nodes_or_tools():
    setup = (REPO / "setup.py").read_text(encoding="utf-8")
    entry_points = re.findall(r'"(\w+) = ([\w.]+):main"', setup)
    assert len(entry_points) >= 10
    assert [(exe, mod) for exe, mod in entry_points if not _within(mod, ("lip_ros.nodes", "lip_ros.tools"))] == []


def test_every_module_says_what_it_is(import_graph):
    files = [p for pkg in PACKAGES for p in (REPO / pkg).rglob("*.py")]
    assert [str(p.relative_to(REPO)) for p in files if not ast.get_docstring(ast.parse(p.read_text()))] == []
