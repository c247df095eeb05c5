"""What every command group of the command line shares: the consoles, option parsing (lists, block
shapes, backends), the command line a table was made with, and tables printed as rich tables."""
from __future__ import annotations

import shlex
from pathlib import Path
from typing import Optional

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table as RichTable

from ..errors import RtlabError

console = Console()
err_console = Console(stderr=True, soft_wrap=True)   # an error stays one line


def names(text: str) -> list[str]:
    """'a,b,,c' -> ['a', 'b', 'c']: a comma-separated option's items."""
    return [t.strip() for t in text.split(",") if t.strip()]


def int_list(text: str, option: str) -> list[int]:
    """'1,2,3' -> [1, 2, 3]; anything else is a one-line error naming the option."""
    try:
        return [int(t) for t in names(text)]
    except ValueError:
        raise RtlabError(f"{option} must be whole numbers separated by commas, got '{text}'") from None


def block_shape(text: str, option: str = "--block", example: str = "32x4") -> tuple[int, int]:
    """'32x4' -> (32, 4): a block, window or image shape WxH; anything else is a one-line error
    naming the option."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() and int(p) > 0 for p in parts):
        raise RtlabError(f"{option} must look like {example} (two positive whole numbers), got '{text}'")
    return int(parts[0]), int(parts[1])


def block_shapes(text: str, option: str = "--blocks") -> list[tuple[int, int]]:
    return [block_shape(b, option) for b in names(text)]


def backend_list(backends: str, device: Optional[str]):
    """The backends of a comma-separated --backends; --device names an OpenCL device (CUDA takes its
    own from $RTLAB_CUDA_DEVICE)."""
    from ..backends import get_backend
    return [get_backend(b, device if b == "opencl" else None) for b in names(backends)]


def command_line(ctx: typer.Context) -> str:
    """The command that made a table, for the markdown beside it: the command's path and the options
    given on it and its groups (not their defaults). From the parsed context, not sys.argv, which is
    not the command under main(argv) or a test's runner."""
    words: list[str] = []
    for level in reversed(list(_contexts(ctx))):
        words += level.info_name.split() if level.parent is not None else ["rtlab"]
        for param in level.command.params:
            source = level.get_parameter_source(param.name)
            if source is None or source.name == "DEFAULT":
                continue
            value = level.params.get(param.name)
            values = [str(v) for v in value] if isinstance(value, (tuple, list)) else [str(value)]
            if not param.opts[0].startswith("-"):
                words += values
            elif getattr(param, "is_flag", False):
                words.append(param.opts[0] if value else (param.secondary_opts or param.opts)[0])
            else:
                words += [param.opts[0], *values]
    return shlex.join(words)


def _contexts(ctx: typer.Context):
    while ctx is not None:
        yield ctx
        ctx = ctx.parent


def print_tables(tables, width: int | None = None) -> None:
    """Bench tables (rtlab.benches.tables.Table) as rich tables; ``width`` for tables too wide to fold
    legibly in 80 columns. Into a file or a pipe (a log) each table keeps its natural width: rich
    would fold it into 80 columns of cut-off cells."""
    if not console.is_terminal:
        out = Console(width=1000)
    else:
        out = Console(width=max(console.width, width)) if width else console
    for t in tables:
        if t.note:
            out.print(escape(t.note), highlight=False)
        rich = RichTable(title=t.title or None)
        for col in t.columns:
            rich.add_column(escape(col), justify="right")
        for cells in t.rows:
            rich.add_row(*(escape(c) for c in cells))
        out.print(rich)


def output_folder(path: Path, option: str = "--out", given: Optional[Path] = None) -> Path:
    """Make ``option``'s folder (for the file ``given``) before any work: a path through a file, or a
    file, is a one-line error saying that the output path is the problem (not a bare "File exists")."""
    blocker = next((p for p in reversed([path, *path.parents]) if p.exists() and not p.is_dir()), None)
    if blocker is not None:
        raise RtlabError(f"{option} {given or path}: cannot make the folder {path}: {blocker} is a file")
    path.mkdir(parents=True, exist_ok=True)
    return path


def image_file(path: Path, option: str = "--out") -> Path:
    """Check ``option``'s image file before any work, and make its folder: a folder, or a name whose
    extension Pillow cannot write (no extension, .txt), is a one-line error; found only at save
    time it would cost the render and its figures."""
    from PIL import Image
    if path.is_dir():
        raise RtlabError(f"{option} {path} is a folder; give an image file, e.g. {path / 'render.png'}")
    formats = Image.registered_extensions()
    if formats.get(path.suffix.lower()) not in Image.SAVE:
        raise RtlabError(f"{option} {path}: cannot write an image of type {path.suffix or '(no extension)'!r}; "
                         f"give a .png (or .jpg, .bmp, .tif) file")
    output_folder(path.parent, option, path)
    return path


def append_markdown(md: Optional[Path], text: str) -> None:
    """Append a table's markdown to --md (a block for a fragment of docs/results/)."""
    if md:
        with open(md, "a") as f:
            f.write(text + "\n")


def load_scene(name: str, size: Optional[int] = None):
    from ..scene import load_scene as load
    with console.status(f"loading scene {name}..."):
        return load(name, size=size)


def kd_tree(scene):
    """The scene's kd-tree, built (or loaded from the cache) under a status line: (tree, from_cache)."""
    from ..accel.cache import load_or_build_kdtree
    from ..accel.kdtree import COMPILING_MESSAGE, KdBuildParams
    with console.status(f"kd-tree for {scene.name} ({scene.n_triangles:,} triangles)...") as status:
        def progress(message: str):
            if message == COMPILING_MESSAGE:
                console.print(f"{message}...")     # the one noticeable wait of a fresh install: keep it
            status.update(message)
        return load_or_build_kdtree(scene.vertices, scene.faces, KdBuildParams(), progress=progress)


def traversal_structure(scene, backend, variant) -> None:
    """Build (or load from the caches) what ``variant`` traverses on ``backend`` under a status line:
    the kd-tree (kd_tree), or a BVH, saying so when numba compiles its builder on a first run."""
    from ..device.device_scene import KD_FAMILIES, accel_family, device_scene
    if accel_family(variant.traversal) in KD_FAMILIES:
        kd_tree(scene)
        return
    from ..accel.bvh import COMPILING_MESSAGE, builder_needs_compiling
    with console.status(f"BVH for {scene.name} ({scene.n_triangles:,} triangles)..."):
        if builder_needs_compiling():
            console.print(f"{COMPILING_MESSAGE}...")   # the one noticeable wait of a fresh install
        device_scene(scene, backend).features(variant)


def use_kernels(kernels: Optional[Path], variant=None, step: Optional[str] = None,
                entries: tuple[str, ...] = ("render_primary",)) -> None:
    """Switch to the kernel sources of --kernels (if given) and say which tree runs and what in it is
    still a template stub (rtlab render --traversal ropes --check must not pass off the reference):
    with ``variant``, the stubs that the ``entries`` kernels of program ``step`` (default: the primary
    render's) call."""
    from ..course.kernel_sources import kernel_sources_summary
    from ..paths import use_kernel_dir
    if kernels is not None:
        use_kernel_dir(kernels)
    console.print(escape(kernel_sources_summary(variant, step, entries)), highlight=False)
