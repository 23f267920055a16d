"""Range sensing a body can carry at a mounted pose, kept apart from any one world or body.

:mod:`sitl.sensing.raycast` is the one ray-cast helper: beam sets (:class:`~sitl.sensing.raycast.Beams`) mounted on
bodies, every body's sets cast in one batch (the Pioneer's sonar cones, the RPLIDAR emulator's beams);
:mod:`sitl.sensing.sonar_ring` is the Pioneer 3-DX sonar ring in closed form (discs and walls, every robot at once).
"""
