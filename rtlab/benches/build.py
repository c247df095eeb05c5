"""The paper's Table 2: each scene's SAH kd-tree (#triangles, #nodes, #non-empty leaves, triangle refs
per non-empty leaf, size) beside the paper's row, with depth, SAH cost and build time (``rtlab build``
shows one scene, ``rtlab bench paper`` all of them)."""
from __future__ import annotations

from ..accel.kdtree import KdTree, kd_stats
from .paper_figures import PAPER_TABLE2
from .tables import Table

PAPER_COLUMNS = ("#triangles", "#nodes", "#neleaves", "#links", "size")     # the paper's Table 2 columns
EXTRA_COLUMNS = ("depth", "SAH cost", "build s")


def table2_cells(name: str, tree: KdTree, n_triangles: int) -> list[tuple[str, str, str]]:
    """(column, ours, the paper's) for the paper's columns, then the extra ones (the paper has none)."""
    s = kd_stats(tree, n_triangles)
    paper = PAPER_TABLE2.get(name.lower())
    ours = (f"{s['triangles']:,}", f"{s['nodes']:,}", f"{s['nonempty_leaves']:,}", f"{s['refs_per_nonempty_leaf']:.2f}",
            f"{s['size_bytes'] / 2**20:.1f} MB")
    theirs = (["-"] * 5 if paper is None else
              [f"{v:,}" if isinstance(v, int) else str(v) for v in paper])
    extra = (str(s["depth"]), f"{s['sah_cost']:.2f}", f"{s['build_seconds']:.2f}")
    return list(zip(PAPER_COLUMNS, ours, theirs)) + [(c, v, "-") for c, v in zip(EXTRA_COLUMNS, extra)]


def table2(entries: list[tuple[str, KdTree, int]]) -> Table:
    """One row a scene (name, tree, triangles): 'ours (paper's)' in the paper's columns."""
    rows = []
    for name, tree, n_triangles in entries:
        cells = table2_cells(name, tree, n_triangles)
        rows.append((name, *[f"{ours} ({theirs})" for _, ours, theirs in cells[:len(PAPER_COLUMNS)]],
                     *[ours for _, ours, _ in cells[len(PAPER_COLUMNS):]]))
    return Table(("scene", *[f"{c} (paper)" for c in PAPER_COLUMNS], *EXTRA_COLUMNS), rows,
                 "Table 2: kd-tree statistics")
