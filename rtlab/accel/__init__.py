"""Acceleration structures built on the host: the SAH kd-tree (and the BVH)."""
