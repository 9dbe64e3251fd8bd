"""The launch file for a real rig: `launch` is not installable here, so it is read as XML and everything of this
package it names is checked: executables, parameter files, parameters, remapped topics, launch arguments."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from lip_ros.lip.sensors import IMU_TOPICS, LIP_TOPICS
from lip_ros.nodes.lip.graph import LIP_GRAPH

REPO = Path(__file__).resolve().parents[1]
LAUNCH = REPO / "launch" / "lip_real_rig.launch.xml"
SHARE = "$(find-pkg-share lip_ros)/"


@pytest.fixture(scope="module")
def root() -> ET.Element:
    return ET.parse(LAUNCH).getroot()


def _values(root: ET.Element) -> list[str]:
    return [v for e in root.iter() for v in e.attrib.values()]


def test_every_executable_of_this_package_exists(root):
    scripts = re.findall(r'"(\w+) = [\w.]+:main"', (REPO / "setup.py").read_text(encoding="utf-8"))
    nodes = [n for n in root.iter("node") if n.get("pkg") == "lip_ros"]
    assert nodes and all(n.get("exec") in scripts for n in nodes)


def test_every_file_of_this_package_exists_and_is_installed(root):
    paths = [m for v in _values(root) for m in re.findall(re.escape(SHARE) + r"([\w./]+)", v)]
    assert "params/lip.yaml" in paths and "params/smpl24_skeleton.urdf" in paths
    setup = (REPO / "setup.py").read_text(encoding="utf-8")
    for path in paths:
        assert (REPO / path).is_file(), path
        folder, suffix = path.rsplit("/", 1)[0], Path(path).suffix
        assert f'glob("{folder}/*{suffix}")' in setup, f"{path} is not installed by setup.py"


def test_the_graph_gets_known_parameters_and_its_real_input_topics(root):
    (graph,) = [n for n in root.iter("node") if n.get("exec") == "fusion_node"]
    known = set().union(*(node.parameter_names() for node in LIP_GRAPH))
    assert {p.get("name") for p in graph.iter("param") if p.get("name")} <= known
    assert {r.get("from") for r in graph.iter("remap")} == set(IMU_TOPICS.values())
    (rsp,) = [n for n in root.iter("node") if n.get("exec") == "robot_state_publisher"]
    assert {(r.get("from"), r.get("to")) for r in rsp.iter("remap")} == {("/joint_states", LIP_TOPICS.joint_states)}


def test_every_launch_argument_used_is_declared(root):
    declared = {a.get("name") for a in root.findall("arg")}
    used = {m for v in _values(root) for m in re.findall(r"\$\(var (\w+)\)", v)}
    assert used and used <= declared, used - declared
    assert all(a.get("description") for a in root.findall("arg"))
