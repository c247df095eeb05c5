"""The float64 reference tracer and error metrics: ground truth for every check."""
from .bvh import ReferenceBVH, build_reference_bvh, cached_reference_bvh
from .metrics import HitComparison, compare_hits, image_rmse_psnr, pixels_differing
from .tracer import RefHits, brute_force_trace, intersect_ray_triangles_f64, reference_trace
from .watertight import usable_triangle_mask

__all__ = [
    "RefHits",
    "ReferenceBVH",
    "reference_trace",
    "brute_force_trace",
    "intersect_ray_triangles_f64",
    "build_reference_bvh",
    "cached_reference_bvh",
    "usable_triangle_mask",
    "HitComparison",
    "compare_hits",
    "image_rmse_psnr",
    "pixels_differing",
]
