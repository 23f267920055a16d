"""Range sensing a body can carry at a mounted pose, kept apart from any one world or body.

:mod:`sitl.sensing.raycast` casts a beam set mounted on a body (the Pioneer's sonar cones);
:mod:`sitl.sensing.sonar_ring` is the Pioneer 3-DX sonar ring in closed form (discs and walls, every robot at once).
"""
