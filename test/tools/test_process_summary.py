"""lip_process_bag's report of the frames: a frame not accounted for says whether its cloud ever reached the
graph."""

from __future__ import annotations

from lip_ros.tools.process_bag import ProcessSummary


def test_frames_not_accounted_for_say_whether_the_graph_received_their_clouds():
    assert ProcessSummary(10, {"pose": 10}, 10).lines()[0] == "frames in: 10; pose 10"
    lost = ProcessSummary(10, {"pose": 9}, 9).lines()[0]
    assert lost.endswith("not accounted for 1 (lost in transport: the graph received 9 of the 10 clouds)")
    held = ProcessSummary(10, {"pose": 8, "skipped: malformed cloud": 1}, 10).lines()[0]
    assert held.endswith("not accounted for 1 (every cloud was received)")
    assert ProcessSummary(10, {"pose": 9}).lines()[0].endswith("not accounted for 1")


def test_frames_still_waiting_for_the_optimisation_at_the_end_are_reported():
    """HSC4D: a window still being solved when the graph was stopped is said, not left for the reader to find in
    the count of optimised poses."""
    assert not any("still waiting" in line for line in ProcessSummary(10, {"pose": 10}, 10).lines())
    line = next(line for line in ProcessSummary(10, {"pose": 10}, 10, optimising=7).lines() if "still" in line)
    assert line.startswith("scene-aware optimisation: 7 frames still waiting when the graph was stopped")
