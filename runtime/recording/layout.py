"""The Foxglove layout for a fleet's recording or live view, built with foxglove-sdk's typed layouts.

``python -m runtime.recording.layout [N] > docs/foxglove_layout.json`` writes the shipped layout (robots 1..N,
default 10; topics of robots a fleet does not have stay empty): a 3D panel (the world, each robot's estimate, true
pose, planned path and range readings), a table of the latest task-state event (who did which task), plots of the
bids, prices and coalition values, and the log.  ``tests/test_recording_layout.py`` holds the shipped file to
what this module builds.
"""
from __future__ import annotations

import json
import sys

ROBOT_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
                 "#bcbd22", "#17becf")          # matplotlib's tab10, as the run picture colours robots
PLOTTED = (                                     # (message type, field): the bids, prices and values to plot
    ("Bid", "cost"), ("Price", "price"), ("CoalitionBid", "value"), ("DrBid", "capacity"), ("CmCost", "cost"),
)


def fleet_layout(robots: int = 10):
    import foxglove.layouts as fl

    topics: dict = {"/world": fl.BaseRendererSceneUpdateTopicSettings(visible=True)}
    for rid in range(1, robots + 1):
        colour = ROBOT_COLOURS[(rid - 1) % len(ROBOT_COLOURS)]
        topics[f"/robot_{rid}/pose"] = fl.BaseRendererPoseTopicSettings(visible=True, type="arrow", color=colour)
        topics[f"/robot_{rid}/truth"] = fl.BaseRendererPoseTopicSettings(visible=True, type="axis", axis_scale=0.3)
        topics[f"/robot_{rid}/path"] = fl.BaseRendererPosesTopicSettings(visible=True, type="line", line_width=0.03,
                                                                         gradient=(colour, colour))
        topics[f"/robot_{rid}/ranges"] = fl.BaseRendererPointCloudTopicSettings(visible=True)
    three_d = fl.ThreeDeePanel(title="fleet", config=fl.ThreeDeeConfig(fixed_frame="world", follow_tf="world",
                                                                       topics=topics))
    table = fl.TablePanel(title="tasks: the latest state event",
                          config=fl.TableConfig(topic_path='/allocation{event=="task"}'))
    holders = fl.TablePanel(title="commitments: the latest",
                            config=fl.TableConfig(topic_path='/allocation{event=="committed"}'))
    plot = fl.PlotPanel(title="bids, prices, coalition values", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f'/allocation{{event=="sent"}}{{message=="{m}"}}.fields.{field}',
                             label=f"{m}.{field}") for m, field in PLOTTED],
        show_legend=True))
    log = fl.LogPanel(title="log", config=fl.LogConfig(topic_to_render="/log"))
    side = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(content=table), fl.SplitItem(content=holders), fl.SplitItem(content=plot)])
    return fl.Layout(content=fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=3, content=fl.SplitContainer(direction="row", items=[
            fl.SplitItem(proportion=2, content=three_d), fl.SplitItem(proportion=1, content=side)])),
        fl.SplitItem(proportion=1, content=log)]))


def layout_json(robots: int = 10) -> str:
    return json.dumps(json.loads(fleet_layout(robots).to_json()), indent=1) + "\n"


if __name__ == "__main__":
    sys.stdout.write(layout_json(int(sys.argv[1]) if len(sys.argv) > 1 else 10))
