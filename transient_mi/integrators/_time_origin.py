"""Where a camera path's time of flight starts: the point where light reaches the sensor.

Mitsuba 3 starts a projective camera's rays on its near-clip plane (``near_clip``, default 0.01 m in
front of the sensor, along the optical axis), so ``ray.o`` itself is not where light is detected:
taken literally it would shorten every path by ``near_clip / cos(theta)`` (33 ps on axis). The time
origin per sensor:

* ``perspective``: the centre of projection (the pinhole, the sensor's position); every ray
  passes through it. It is where ``ray.o`` traced back along ``-ray.d`` crosses the sensor plane
  (``z = 0`` in camera space), taken exactly rather than recomputed with rounding.
* other projective cameras (``thinlens``, ``orthographic``, any ``mi.ProjectiveCamera``): ``ray.o``
  traced back along ``-ray.d`` to the sensor plane: the ray's point on the lens (thin lens), its
  point on the image plane through the sensor's position (orthographic).
* every other sensor (``radiancemeter``, ``irradiancemeter``, ...): ``ray.o`` (Mitsuba offsets it by
  ~1e-4 m from the sensor's point to avoid self-intersection: < 0.3 ps).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi


class TimeOrigin:
    """``origin(ray)``: per-lane point (mi.Point3f, metres) from which a camera path is timed."""

    def __init__(self, sensor):
        T = sensor.world_transform()
        if sensor.class_name() == "PerspectiveCamera":
            self.kind = "centre"
            self.centre = mi.Point3f(T.translation())
        elif isinstance(sensor, mi.ProjectiveCamera):
            self.kind = "plane"
            self.centre = mi.Point3f(T.translation())
            self.axis = mi.Vector3f(T @ mi.Vector3f(0, 0, 1))  # optical axis (world)
        else:
            self.kind = "ray"

    def __call__(self, ray):
        if self.kind == "centre":
            return self.centre
        if self.kind == "plane":
            t = dr.dot(ray.o - self.centre, self.axis) / dr.dot(ray.d, self.axis)
            return dr.fma(ray.d, -t, ray.o)
        return mi.Point3f(ray.o)
