"""Time the rig's Ouster simulator: one OS1-128 frame with a walking performer in a cluttered scene.

The static range image is cast once per capture (timed separately); each frame
evaluates the performer's pose (forward kinematics) at the sweep time, casts
its rays and applies the sensor model. Run: ``python benchmarks/bench_rig_lidar.py``.
"""

from __future__ import annotations

import time

import numpy as np

from lip_ros.core.body import BodyModel
from lip_ros.core.rotations import rot_x
from lip_ros.core.skeleton import forward_kinematics, load_skeleton
from lip_ros.rig.lidar import Actor, OusterModel
from lip_ros.rig.scene import KeepOut, Scene

HEIGHT = 1.2  # LiDAR above the ground
FRAMES = 200
R_L_M = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def walker(distance: float):
    """A performer at ``distance`` on +x, facing the LiDAR, swinging legs and arms at 1 Hz."""
    skeleton = load_skeleton()
    base = skeleton.pose_local_rotations("a_pose")
    base[0] = R_L_M
    signs = {"left_hip": 1, "right_hip": -1, "left_shoulder": -1, "right_shoulder": 1}
    swing = [(skeleton.index(j), s) for j, s in signs.items()]
    root = np.array([distance, 0.0, skeleton.pelvis_height - HEIGHT])

    def pose(t: float) -> tuple[np.ndarray, np.ndarray]:
        local = base.copy()
        for j, sign in swing:
            local[j] = local[j] @ rot_x(0.4 * sign * np.sin(2.0 * np.pi * t))
        return forward_kinematics(skeleton, local, root + [0.0, 0.3 * np.sin(0.5 * t), 0.0])

    return Actor(BodyModel(skeleton), pose)


def main() -> None:
    scene = Scene.random(0, KeepOut(2.0, 25.0, -6.0, 6.0), -HEIGHT, n_boxes=12, n_cylinders=20, extent=40.0)
    rng = np.random.default_rng(0)
    print(f"scene: {len(scene.boxes)} boxes, {len(scene.cylinders)} cylinders; {FRAMES} frames each")
    for columns in (1024, 2048):
        lidar = OusterModel.os1_128(columns=columns)
        t0 = time.perf_counter()
        static = lidar.static_image(scene)
        print(f"OS1-128 x {columns}: static image {1e3 * (time.perf_counter() - t0):.1f} ms (once per capture)")
        for distance in (4.0, 10.0, 20.0):
            actor = walker(distance)
            times, points = [], 0
            for k in range(FRAMES):
                t0 = time.perf_counter()
                frame = lidar.scan(k * lidar.period_ns, static, [actor], rng)
                times.append(time.perf_counter() - t0)
                points += int((frame.labels == 0).sum())
            ms = 1e3 * np.array(times)
            print(
                f"  performer at {distance:4.1f} m: median {np.median(ms):5.1f} ms, p99 {np.percentile(ms, 99):5.1f} ms"
                f" per frame, {points / FRAMES:6.0f} performer points"
            )


if __name__ == "__main__":
    main()
