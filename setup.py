"""ament_python package lip_ros (colcon build on a ROS 2 Jazzy install, or pip)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "lip_ros"

# Installed by pip from PyPI (`pip install -e ".[pypi]"`); on a full ROS 2 install
# rclpy and the message packages come from the distribution (package.xml) instead.
PYPI = [
    "ros-jazzy-rclpy==7.1.6",
    "ros-jazzy-common-interfaces==5.3.6",
    "ros-jazzy-rmw-fastrtps-cpp==8.4.3",
    "ros-jazzy-ament-index-python==1.8.1",
    "torch==2.13.0",
]
CORE = [
    "numpy>=1.26,<3",
    "scipy>=1.11,<2",
    "PyYAML>=6,<7",
    "rosbags>=0.11.9,<0.12",
    "mcap>=1.2,<2",
    "zstandard>=0.22,<1",  # also an mcap dependency; lip_ros.bagstream decompresses chunks with it
    "fpsample>=1.0,<2",
    "isal>=1.7,<2",  # lip_ros.bagstream checks MCAP chunk CRCs with its crc32
    "matplotlib>=3.8,<4",
    "embreex>=4.4,<5",  # ray casting of the HSC4D rig's scenes (lip_ros.rig.mesh_raycast)
    "kiss-icp==1.3.0",  # the HSC4D LiDAR odometry's registration core (lip_ros.hsc4d.lidar_odometry)
    "gtsam==4.3.0",  # the HSC4D trajectory's pose graph (lip_ros.hsc4d.pose_graph)
    "numba>=0.60,<1",  # the compiled hot loops (lip_ros.core.compiled lists them)
]
TEST = [
    "pytest>=8,<10",
    "pytest-xdist>=3.6,<4",  # make test runs the suite on 2 workers
    "ruff==0.17.5",  # make test lints with it (pyproject.toml [tool.ruff])
    "colcon-core==0.21.3",
    "colcon-ros==0.5.0",
    "ros-jazzy-ament-package==0.16.4",
]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/params", sorted(glob("params/*.yaml") + glob("params/*.urdf") + glob("params/*.xml"))),
        ("share/" + PACKAGE + "/params/weights", sorted(glob("params/weights/*.pt") + glob("params/weights/*.json")
                                                          + glob("params/weights/*.sha256"))),
        ("share/" + PACKAGE + "/launch", sorted(glob("launch/*.launch.xml"))),
    ],
    install_requires=["setuptools"],
    extras_require={"core": CORE, "pypi": CORE + PYPI, "test": TEST},
    zip_safe=True,
    maintainer="lip_ros developers",
    maintainer_email="lip_ros@example.com",
    description="Human motion capture in large spaces from LiDAR and body-worn IMUs (LIP, HSC4D) for ROS 2 Jazzy",
    license="Apache-2.0",
    python_requires=">=3.10",
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "fusion_node = lip_ros.nodes.fusion_node:main",
            "segmentation_node = lip_ros.nodes.lip.segmentation:main",
            "calibration_node = lip_ros.nodes.lip.calibration:main",
            "pose_node = lip_ros.nodes.lip.pose:main",
            "hsc4d_trajectory_node = lip_ros.nodes.hsc4d.trajectory:main",
            "hsc4d_body_node = lip_ros.nodes.hsc4d.body:main",
            "lip_rig = lip_ros.tools.rig:main",
            "lip_train = lip_ros.tools.lip_train:main",
            "lip_eval = lip_ros.tools.lip_eval:main",
            "hsc4d_eval = lip_ros.tools.hsc4d_eval:main",
            "lip_bag_play = lip_ros.tools.bag_play:main",
            "lip_bag_record = lip_ros.tools.bag_record:main",
            "lip_process_bag = lip_ros.tools.process_bag:main",
        ],
    },
)
