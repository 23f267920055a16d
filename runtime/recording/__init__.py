"""Recording: MCAP files and a live Foxglove WebSocket view, fed by the robot core's events.

:mod:`runtime.recording.recorder` owns the channels (Foxglove's well-known schemas where one fits, JSON schemas for
the rest) and their sinks: an MCAP file of bounded size and, optionally, a Foxglove WebSocket server.
:mod:`runtime.recording.feed` turns what a :class:`~runtime.robot.core.RobotCore` did in one cycle into messages on
those channels; :mod:`runtime.recording.read` reads a recording back (the ``mcap`` reader), also a truncated one.
The libraries are the ``[record]`` extra (``foxglove-sdk`` writes, ``mcap`` and ``mcap-protobuf-support`` read);
see docs/recording.md.
"""
