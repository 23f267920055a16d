"""The robot core: the robot's logic, sans-IO, the same in every host (the daemon, the lock-step SITL, the
in-process fleets).  :class:`~runtime.robot.core.RobotCore` takes time, what the robot sensed and what arrived,
and returns the wheel command and what to send; hosts only move bytes, readings and time."""
