"""family_cases: the robustness suite's families by number, memoised per size."""
from __future__ import annotations

from functools import lru_cache

from ..errors import RtlabError
from .cases import FAMILY_NAMES, SIZES, Case
from .closest import family_slivers_grazing, family_spawned, family_ties
from .inputs import family_bad_rays, family_dir_lengths, family_grazing, family_random, family_slivers
from .spawn_offsets import family_spawn_offsets
from .shared_edges import (family_box_planes, family_plane, family_sphere, family_splits, family_stairs,
                         family_stairs_scaled)


def family_cases(family: int, size: str = "test") -> list[Case]:
    """The cases of one family (1-15) at size "test" (PoCL-friendly) or "bench" (the full sizes).
    Memoised: the same Scene objects come back, so their device uploads and trees are reused."""
    return _family_cases(int(family), size)


@lru_cache(maxsize=None)
def _family_cases(family: int, size: str) -> list[Case]:
    if size not in SIZES:
        raise RtlabError(f"unknown robustness size '{size}'; choose one of: {', '.join(SIZES)}")
    s = SIZES[size]
    makers = {
        1: lambda: family_sphere(s["sphere_rays"], s["sphere_subdiv"]),
        2: lambda: family_plane(s["plane_rays"], s["plane_quads"]),
        3: lambda: family_splits(s["split_rays"]),
        4: lambda: family_stairs(s["stairs_grid"]),
        5: lambda: family_stairs_scaled(s["scaled_grid"]),
        6: lambda: family_slivers(s["slivers"], s["sliver_rays"]),
        7: lambda: family_grazing(s["grazing_rays"]),
        8: lambda: family_bad_rays(s["bad_ray_sets"]),
        9: lambda: family_random(s["random_rays"], s["random_scenes"]),
        10: lambda: family_box_planes(s["plane_rays_axis"], s["grid_cubes"], s["room_rays"]),
        11: lambda: family_spawn_offsets(s["glass_size"], s["glass_offsets"]),
        12: lambda: family_dir_lengths(s["length_rays"]),
        13: lambda: family_slivers_grazing(s["grazing_sliver_rays"], s["sliver_scenes"]),
        14: lambda: family_ties(s["tie_rays"], s["tie_scenes"]),
        15: lambda: family_spawned(s["spawned_rays"]),
    }
    if family not in makers:
        raise RtlabError(f"unknown robustness family {family}; families: "
                         + ", ".join(f"{k} {v}" for k, v in FAMILY_NAMES.items()))
    return makers[family]()
