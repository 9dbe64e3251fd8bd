"""lip_process_bag's report of the frames: a frame not accounted for says whether its cloud ever reached the
graph, and if not, where it went as far as the graph's input could tell."""

from __future__ import annotations

from lip_ros.tools.process_bag import ProcessSummary


def test_frames_not_accounted_for_say_whether_the_graph_received_their_clouds():
    assert ProcessSummary(10, {"pose": 10}, 10).lines()[0] == "frames in: 10; pose 10"
    lost = ProcessSummary(10, {"pose": 9}, 9).lines()[0]
    assert lost.endswith("not accounted for 1 (the graph received 9 of the 10 clouds: lost in transport or "
                         "overwritten in its input's queue)")
    told = ProcessSummary(10, {"pose": 7}, 7, (3, 1)).lines()[0]
    assert told.endswith("not accounted for 3 (the graph received 7 of the 10 clouds: its input counted 3 published "
                         "and never taken, 1 lost in transport, 2 overwritten in its queue)")
    ends = ProcessSummary(10, {"pose": 6}, 6, (3, 0)).lines()[0]
    assert ends.endswith("its input counted 3 published and never taken, 0 lost in transport, 3 overwritten in its "
                         "queue; 1 more before the first cloud it took or after the last)")
    more = ProcessSummary(10, {"pose": 9}, 9, (3, 0)).lines()[0]
    assert more.endswith("; 2 more than the bag's clouds it missed (other publishers of the topic?))")
    held = ProcessSummary(10, {"pose": 8, "skipped: malformed cloud": 1}, 10).lines()[0]
    assert held.endswith("not accounted for 1 (every cloud was received)")
    assert ProcessSummary(10, {"pose": 9}).lines()[0].endswith("not accounted for 1")


def test_frames_still_waiting_for_the_optimisation_at_the_end_are_reported():
    """HSC4D: a window still being solved when the graph was stopped is said, not left for the reader to find in
    the count of optimised poses."""
    assert not any("still waiting" in line for line in ProcessSummary(10, {"pose": 10}, 10).lines())
    line = next(line for line in ProcessSummary(10, {"pose": 10}, 10, optimising=7).lines() if "still" in line)
    assert line.startswith("scene-aware optimisation: 7 frames still waiting when the graph was stopped")
