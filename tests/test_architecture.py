"""The shape of the code, checked: no import cycles (modules, and packages as layers), modules of a
readable size, constants the host and the kernels share read from one place, the port layer the
only place that tells CUDA from OpenCL, kernel pairs that declare the same kernels, and the
README's layout naming the tree as it is."""
from __future__ import annotations

import ast
import os
import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

from rtlab.paths import PACKAGE_DIR, PROJECT_DIR, REFERENCE_KERNEL_DIR

SHARED = REFERENCE_KERNEL_DIR / "shared"
MODULE_LINES = 400
PORT_LAYER = {"rt_port.h", "rt_memory.h", "rt_lanes.h"}


# ---- imports -----------------------------------------------------------------------------------

def _modules() -> dict[str, tuple[Path, bool]]:
    """module name -> (file, is a package's __init__)"""
    out = {}
    for path in PACKAGE_DIR.rglob("*.py"):
        parts = list(path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts)
        is_init = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_init else parts)] = (path, is_init)
    return out


def _imports(modules, lazy: bool) -> dict[str, set[str]]:
    """module -> the rtlab modules it imports: at import time only (module level, class bodies), or
    with ``lazy`` also those imported inside functions. The root package, which every import of a
    submodule runs first, is left out."""
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for name, (path, is_init) in modules.items():
        package = name.split(".") if is_init else name.split(".")[:-1]
        nodes: list[ast.AST] = []

        def visit(node):
            for child in ast.iter_child_nodes(node):
                if lazy or not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                    nodes.append(child)
                    visit(child)

        visit(ast.parse(path.read_text()))
        for node in nodes:
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else []))
                targets = [base] + [f"{base}.{a.name}" for a in node.names]
            else:
                continue
            for target in targets:
                parts = target.split(".")
                found = next((".".join(parts[:i]) for i in range(len(parts), 0, -1) if ".".join(parts[:i]) in modules),
                             None)
                if found is None or found == name or found == "rtlab":
                    continue
                graph[name].add(found)
                for i in range(2, len(found.split("."))):         # a.b.c runs a.b's __init__ first
                    parent = ".".join(found.split(".")[:i])
                    if parent in modules and not name.startswith(parent + "."):
                        graph[name].add(parent)
    return graph


def _rtlab_imports_outside_the_package():
    """(file, line, module, names) of every rtlab import, at any depth, in the tests, benchmarks,
    scripts and notebooks: the code that a rename inside the package leaves behind."""
    for folder in ("tests", "experiments", "scripts", "notebooks", "labs"):
        for path in sorted((PROJECT_DIR / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").startswith("rtlab"):
                    yield path, node.lineno, node.module, [a.name for a in node.names]
                elif isinstance(node, ast.Import):
                    for a in node.names:
                        if a.name.startswith("rtlab"):
                            yield path, node.lineno, a.name, []


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one node (Tarjan)."""
    index, low, on_stack, stack, out = {}, {}, set(), [], []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in list(graph):
        if v not in index:
            visit(v)
    return out


def _layer(module: str) -> str:
    """rtlab.device.device_scene -> rtlab.device: the package a module belongs to (a top-level module is its own)."""
    return ".".join(module.split(".")[:2])


def test_no_module_imports_itself_back_at_import_time():
    graph = _imports(_modules(), lazy=False)
    assert not _cycles(graph), f"import cycles at import time: {_cycles(graph)}"


def test_imports_outside_the_package_name_what_exists():
    """An editable install or a stale checkout can hide a module that moved (the old file is found
    elsewhere on the path); here every name is looked up in this tree's package."""
    import importlib
    missing = []
    for path, line, module, names in _rtlab_imports_outside_the_package():
        where = f"{path.relative_to(PROJECT_DIR)}:{line}"
        try:
            mod = importlib.import_module(module)
        except ImportError as e:
            missing.append(f"{where}: {module} ({e})")
            continue
        assert Path(mod.__file__).resolve().is_relative_to(PACKAGE_DIR.resolve()), f"{module} from {mod.__file__}"
        for name in names:
            if not hasattr(mod, name):
                try:
                    importlib.import_module(f"{module}.{name}")
                except ImportError:
                    missing.append(f"{where}: {module} has no {name}")
    assert not missing, "\n".join(missing)


def test_packages_form_layers_even_counting_imports_inside_functions():
    """Packages (device, accel, backends, ...) import each other in one direction only: with the
    imports inside functions counted too, no package reaches back to one that reaches it."""
    graph = _imports(_modules(), lazy=True)
    layers: dict[str, set[str]] = {}
    for module, targets in graph.items():
        layers.setdefault(_layer(module), set()).update(_layer(t) for t in targets if _layer(t) != _layer(module))
    assert not _cycles(layers), f"packages importing each other: {_cycles(layers)}"
    # the layers this project means to have, bottom to top
    assert not layers["rtlab.backends"] & {"rtlab.device", "rtlab.accel", "rtlab.benches", "rtlab.course", "rtlab.cli"}
    assert not layers["rtlab.reference"] & {"rtlab.device", "rtlab.backends", "rtlab.accel"}, \
        "the float64 reference must not use the code it checks"
    assert not layers["rtlab.scene"] - {"rtlab.errors", "rtlab.paths", "rtlab.kernel_constants"}


def test_the_import_graph_sees_a_cycle():
    """The check above can fail: two modules importing each other are found."""
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


# ---- module size -------------------------------------------------------------------------------

def test_modules_stay_readable():
    """No module of rtlab over MODULE_LINES lines, unless its docstring says why it is one file
    ("Why one file:")."""
    long = []
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        n = len(path.read_text().splitlines())
        doc = ast.get_docstring(ast.parse(path.read_text())) or ""
        if n > MODULE_LINES and "Why one file:" not in doc:
            long.append(f"{path.relative_to(PACKAGE_DIR.parent)} ({n} lines)")
    assert not long, "split by kind, or say at the top why it is one file: " + ", ".join(long)


# ---- constants shared with the kernels ---------------------------------------------------------

def _header_defines() -> dict[str, str]:
    """#define NAME value of the shared headers, read here with a plain regex (independent of
    rtlab.kernel_constants' parser)."""
    out = {}
    for header in SHARED.glob("*.h"):
        for name, value in re.findall(r"^#define (\w+) +\(?(-?\d+)\)?(?=\s|$)", header.read_text(), re.M):
            out.setdefault(name, value)
    return out


@pytest.mark.parametrize("table, prefix", [("TRAVERSALS", "RT_TRAVERSAL_"), ("INTERSECTIONS", "RT_ISECT_"),
                                           ("NODE_MEMORY", "RT_MEM_"), ("CONST_MEMORY", "RT_MEM_"),
                                           ("RAY_MEMORY", "RT_MEM_"), ("RAY_ORDERS", "RT_ORDER_")])
def test_variant_codes_are_the_headers(table, prefix):
    from rtlab.device import kernels
    defines = _header_defines()
    names = getattr(kernels, table)
    for name, code in names.items():
        define = prefix + name.upper().replace("-", "_")
        assert define in defines, f"{table}[{name!r}]: no #define {define} in kernels/shared"
        assert code == int(defines[define]), f"{table}[{name!r}] = {code}, but {define} is {defines[define]}"
    if prefix != "RT_MEM_":        # every traversal, test and order the kernels know has a name
        codes = {d for d in defines if d.startswith(prefix)}
        assert codes == {prefix + n.upper().replace("-", "_") for n in names}


def test_layout_constants_are_the_headers():
    from rtlab.accel import bvh, bvh4, bvh8, bvh_wide, kdtree, ropes, tri_data
    from rtlab.device import kernels, whitted
    from rtlab.reference import whitted as reference_whitted
    from rtlab.scene.materials import MIN_WEIGHT
    d = {k: int(v) for k, v in _header_defines().items()}
    assert (bvh.LEAF_BITS, bvh.NODE_FLOAT4S) == (d["BVH_LEAF_BITS"], d["BVH_NODE_STRIDE"])
    assert (bvh8.NODE_ROWS, bvh8.TRI_ROWS, bvh4.NODE_ROWS, bvh4.LEAF_BITS) == (
        d["BVH8_NODE_ROWS"], d["BVH8_TRI_ROWS"], d["BVH4_NODE_ROWS"], d["BVH4_LEAF_BITS"])
    assert bvh8.NODE_DTYPE.itemsize == 16 * d["BVH8_NODE_ROWS"] == 80
    assert (bvh_wide.LEAF_BITS, bvh_wide.EMPTY) == (d["WBVH_LEAF_BITS"], d["WBVH_EMPTY"])
    assert (bvh_wide.NODE_VECTORS, bvh_wide.BLOCK_VECTORS) == (d["WBVH_NODE_VECTORS"], d["WBVH_BLOCK_VECTORS"])
    assert kernels.PACKET_LANES == d["RT_LANES"] == 8
    assert kdtree.LEAF_TAG == d["KD_LEAF"] and ropes.RECORD_FLOAT4S == d["KD_ROPES_LEAF_STRIDE"]
    assert (tri_data.WALD_ROWS, tri_data.PLUCKER_ROWS) == (d["RT_WALD_ROWS"], d["RT_PLUCKER_ROWS"])
    assert whitted.NO_RAY == reference_whitted.NO_RAY == d["RT_NO_RAY"]
    text = (SHARED / "rt_whitted.h").read_text()
    num, den = re.search(r"#define RT_MIN_WEIGHT \((\d+\.\d*)f / (\d+\.\d*)f\)", text).groups()
    assert MIN_WEIGHT == float(num) / float(den)


def test_constant_parser_reads_expressions_and_defaults():
    from rtlab.kernel_constants import parse_defines
    text = """#ifndef RT_X_H
#define RT_X_H
#define A 3              /* a comment */
#define B (2 * A + 1)
#define C (1.0f / 4.0f)
#ifndef D
#define D 7
#endif
#if A == 3
#define E 1               /* a variant's, not a constant */
#endif
#define F(x) ((x) + 1)
#define G __ldg
#endif
"""
    assert parse_defines(text) == {"A": 3, "B": 7, "C": 0.25, "D": 7}


KERNEL_OF_VARIANT = """
#include "rt_port.h"
RT_KERNEL void variant_codes(RT_GLOBAL int *out)
{
    out[0] = RT_TRAVERSAL == %s;
    out[1] = RT_ISECT == %s;
    out[2] = RT_NODE_MEM == %s;
    out[3] = RT_RAY_ORDER == %s;
}
"""


@pytest.mark.parametrize("traversal, isect, memory, order", [("stack", "moller", "global", "rows"),
                                                             ("bvh-packet", "watertight", "texture", "morton"),
                                                             ("ropes", "plucker", "global", "rows"),
                                                             ("restart", "wald", "texture", "rows")])
def test_a_variant_compiles_as_its_own_name(backend, tmp_path, traversal, isect, memory, order):
    """build_defines sets what the kernel tests by name: a variant's traversal, test, placement and
    order arrive as the #define of the same name (a swapped code would fail here)."""
    from rtlab.device.kernels import SceneFeatures, Variant, build_defines
    variant = Variant(traversal=traversal, intersection=isect, node_memory=memory, ray_order=order)
    names = ["RT_TRAVERSAL_" + traversal.upper().replace("-", "_"), "RT_ISECT_" + isect.upper(),
             "RT_MEM_" + memory.upper(), "RT_ORDER_" + order.upper()]
    src = tmp_path / ("codes" + backend.extension)
    src.write_text(KERNEL_OF_VARIANT % tuple(names))
    out = backend.empty(16)
    backend.compile(src, build_defines(variant, SceneFeatures())).launch("variant_codes", (1,), (1,), [out])
    assert backend.to_host(out, np.int32, 4).tolist() == [1, 1, 1, 1]


# ---- the kernels' sources ----------------------------------------------------------------------

KERNEL_DEFINITION = re.compile(r"^(?:RT_KERNEL|__kernel|extern \"C\" __global__)\s+void\s+(\w+)\s*\(", re.M)
QUOTED_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"', re.M)


def _defined_kernels(path: Path) -> list[str]:
    """Entry kernels whose definition is in this file itself."""
    return KERNEL_DEFINITION.findall(path.read_text())


def _kernel_names(path: Path, seen: set | None = None) -> list[str]:
    """Entry kernels a program holds: its own and those of the headers it includes (found beside it,
    then in kernels/shared, as the compilers search)."""
    seen = set() if seen is None else seen
    names = _defined_kernels(path)
    for name in QUOTED_INCLUDE.findall(path.read_text()):
        header = next((d / name for d in (path.parent, SHARED) if (d / name).is_file()), None)
        if header is not None and header not in seen:
            seen.add(header)
            names += _kernel_names(header, seen)
    return sorted(names)


def _pairs():
    steps = sorted(p.stem for p in (REFERENCE_KERNEL_DIR / "cuda").glob("*.cu"))
    harness = PACKAGE_DIR / "course" / "harness"
    return ([(REFERENCE_KERNEL_DIR / "cuda" / f"{s}.cu", REFERENCE_KERNEL_DIR / "opencl" / f"{s}.cl") for s in steps]
            + [(harness / "camera_rays.cu", harness / "camera_rays.cl")])


@pytest.mark.parametrize("cu, cl", _pairs(), ids=lambda p: p.stem)
def test_each_pair_declares_the_same_kernels(cu, cl):
    assert _kernel_names(cu), f"no kernel found in {cu.name}"
    assert _kernel_names(cu) == _kernel_names(cl), f"{cu.name} and {cl.name} declare different kernels"


def test_each_entry_kernel_is_written_once():
    """Entry kernels are written once for both languages (kernels/shared/rt_entry_*.h, the grader's
    harness headers): a .cu or .cl file defines none, and no kernel name is defined twice. A device
    function a language file defines is a lab's student region (01_memory.cu's place_ray_shared)."""
    from rtlab.course.kernel_sources import region_owners
    headers = sorted(SHARED.glob("*.h")) + sorted((PACKAGE_DIR / "course" / "harness").glob("*.h"))
    programs = [p for pair in _pairs() for p in pair]
    in_programs = {p.name: _defined_kernels(p) for p in programs if _defined_kernels(p)}
    assert not in_programs, f"entry kernels defined in a language's own file (write them in kernels/shared): {in_programs}"
    where: dict[str, list[str]] = {}
    for h in headers:
        for name in _defined_kernels(h):
            where.setdefault(name, []).append(h.name)
    twice = {k: v for k, v in where.items() if len(v) > 1}
    assert not twice, f"entry kernels defined more than once: {twice}"
    held = {name for p in programs for name in _kernel_names(p)}
    assert held <= set(where) and held, f"kernels of no shared header: {held - set(where)}"
    regions = {(path, f) for path, f in region_owners()}
    loose = [f"{p.name}:{name}" for p in programs for name, _ in _functions(p.read_text())
             if (f"kernels/{p.parent.name}/{p.name}", name) not in regions]
    assert not loose, f"device functions in a language's own file (write them once in kernels/shared): {loose}"


def test_only_the_port_layer_tells_the_languages_apart():
    """__CUDACC__ (and OpenCL's extension macros) appear only in rt_port.h, rt_memory.h and rt_lanes.h."""
    split = re.compile(r"__CUDACC__|__CUDA_ARCH__|__OPENCL_VERSION__|cl_khr_\w+")
    outside = [f"{h.name}:{n}" for h in sorted(SHARED.glob("*.h")) if h.name not in PORT_LAYER
               for n, line in enumerate(h.read_text().splitlines(), 1) if split.search(line)]
    assert not outside, f"language split outside the port layer: {outside}"


def test_thread_indices_come_from_the_port_layer():
    """Kernels find their thread, block and pixel through rt_port.h's rt_global_id, rt_local_id, ...
    (and rt_primary.h's launch_pixel, block_pixel's order): CUDA's and OpenCL's own names only there."""
    native = re.compile(r"\b(?:blockIdx|threadIdx|blockDim|gridDim|get_global_id|get_local_id|get_group_id|"
                        r"get_local_size|get_global_size)\b")
    files = sorted(SHARED.glob("*.h")) + sorted(REFERENCE_KERNEL_DIR.glob("*/*.c[lu]"))
    files += sorted((PACKAGE_DIR / "course" / "harness").glob("*"))
    outside = [f"{f.name}:{n}" for f in files if f.name != "rt_port.h"
               for n, line in enumerate(f.read_text().splitlines(), 1) if native.search(line)]
    assert not outside, f"thread indices outside rt_port.h: {outside}"


def _functions(text: str):
    """(name, parameter text) of every RT_FN definition."""
    for m in re.finditer(r"^RT_FN\s+[\w\s\*]+?\b(\w+)\s*\(([^)]*)\)\s*\{", text, re.M):
        yield m.group(1), " ".join(m.group(2).split())


def test_scene_params_come_first():
    late = [f"{h.name}:{name}" for h in sorted(SHARED.glob("*.h")) for name, params in _functions(h.read_text())
            if "RT_SCENE_PARAMS" in params and not params.startswith("RT_SCENE_PARAMS")]
    assert not late, f"functions taking RT_SCENE_PARAMS after other parameters: {late}"


LOADERS = {"load_node": "nodes", "load_node_data": "node_data", "load_object": "objects", "load_tri_vertex": "tris",
           "load_tri_data": "tri_data", "load_tri_normal": "normals", "load_tri_material": "tri_materials"}


def test_loaders_are_given_their_buffer():
    """Every scene read names the buffer it reads (load_node(nodes, i), as Warp's bvh_load_node)."""
    wrong = []
    for path in sorted(SHARED.glob("*.h")) + sorted(REFERENCE_KERNEL_DIR.glob("*/*.c[lu]")):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            for loader, buffer in LOADERS.items():
                for m in re.finditer(rf"\b{loader}\(\s*(\w+)\s*,", line):
                    if m.group(1) != buffer:
                        wrong.append(f"{path.name}:{n}: {loader}({m.group(1)}, ...)")
                if re.search(rf"\b{loader}\(\s*[^,()]*\)", line):
                    wrong.append(f"{path.name}:{n}: {loader} without its buffer")
    assert not wrong, wrong


SCENE_BUFFERS = tuple(LOADERS.values())
_RAW_READ = re.compile(r"\b(" + "|".join(SCENE_BUFFERS) + r")\s*\[|\*\s*\(\s*(" + "|".join(SCENE_BUFFERS) + r")\s*\+")


def _code_only(text: str) -> str:
    """The source with comments blanked (line numbers kept)."""
    text = re.sub(r"/\*.*?\*/", lambda m: re.sub(r"[^\n]", " ", m.group(0)), text, flags=re.S)
    return re.sub(r"//[^\n]*", "", text)


def _raw_scene_reads(path: Path) -> list[str]:
    text = _code_only(path.read_text())
    return [f"{path.name}:{n}: {line.strip()}" for n, line in enumerate(text.splitlines(), 1) if _RAW_READ.search(line)]


def test_scene_buffers_are_read_through_their_loaders_only():
    """Outside rt_memory.h (where the loaders are defined, one per memory placement) no kernel code
    indexes a scene buffer itself: every read goes through load_node(nodes, i) and the like, so a
    placement, the work counters of the grader and the texture paths see every read. The rule finds
    an indexed read and pointer arithmetic."""
    assert _RAW_READ.search("float4 v = tris[3 * i];") and _RAW_READ.search("int o = *(objects + k);")
    assert not _RAW_READ.search("float4 v = load_tri_vertex(tris, 3 * i);")
    files = [p for p in sorted(SHARED.glob("*.h")) if p.name != "rt_memory.h"]
    files += sorted(REFERENCE_KERNEL_DIR.glob("*/*.c[lu]")) + sorted((PACKAGE_DIR / "course" / "harness").glob("*"))
    raw = [r for p in files for r in _raw_scene_reads(p)]
    assert not raw, raw


# ---- the README's layout -----------------------------------------------------------------------

def _readme_layout() -> list[str]:
    text = (PROJECT_DIR / "README.md").read_text()
    block = re.search(r"## Layout\s+```\n(.*?)```", text, re.S).group(1)
    entries, parent = [], ""
    for line in block.splitlines():
        name = line.split()[0] if line.strip() else ""
        indent = len(line) - len(line.lstrip())
        if not name or indent > 4:          # an entry's second line
            continue
        if indent == 0:
            parent = name if name.endswith("/") else ""
            entries.append(name)
        else:
            entries.append(parent + name)
    return entries


def test_readme_layout_names_the_tree():
    """Every folder and file the README's layout names exists, and every package of rtlab and every
    module at its top is named there."""
    entries = _readme_layout()
    missing = [e for e in entries if not (PROJECT_DIR / e.rstrip("/")).exists()]
    assert not missing, f"README's layout names what is not there: {missing}"
    named = {e.rstrip("/") for e in entries}
    packages = {f"rtlab/{p.parent.name}" for p in PACKAGE_DIR.glob("*/__init__.py")}
    modules = {f"rtlab/{p.name}" for p in PACKAGE_DIR.glob("*.py") if not p.name.startswith("__")}
    assert not (packages | modules) - named, f"not in README's layout: {sorted((packages | modules) - named)}"


def test_readme_layout_lists_the_layers_in_order():
    """The README lists rtlab's packages so that each imports (inside functions too) only what is
    listed above it: its order is the layering."""
    order = [e.rstrip("/").removesuffix(".py").replace("/", ".") for e in _readme_layout()
             if e.startswith("rtlab/") and e != "rtlab/"]     # the root package: the public API, above all
    graph = _imports(_modules(), lazy=True)
    above: set[str] = set()
    wrong = []
    for layer in order:
        uses = {_layer(t) for m, ts in graph.items() if _layer(m) == layer for t in ts} - {layer}
        wrong += [f"{layer} uses {u}, listed below it" for u in sorted(uses - above)]
        above.add(layer)
    assert not wrong, wrong


# ---- settings and import side effects --------------------------------------------------------------

_ENV_READ = re.compile(r"os\.(?:environ(?:\.get|\.setdefault|\.pop)?\s*[\[(]|getenv\s*\()\s*[\"'](RTLAB_\w+)")


def test_settings_are_read_in_one_place():
    """No module of rtlab reads an RTLAB_* variable itself: rtlab/settings.py is the one place, so each
    is named and explained once (and the pattern finds the reads it forbids)."""
    assert _ENV_READ.search('x = os.environ.get("RTLAB_FOO", "")')
    assert _ENV_READ.search("os.environ['RTLAB_BAR'] = 1")
    assert _ENV_READ.search('os.getenv("RTLAB_BAZ")')
    reads = [f"{p.relative_to(PROJECT_DIR)}: {m.group(1)}" for p in PACKAGE_DIR.rglob("*.py")
             if p.name != "settings.py" for m in _ENV_READ.finditer(p.read_text())]
    assert not reads, f"RTLAB_* read outside rtlab/settings.py: {reads}"
    used = {m for p in PACKAGE_DIR.rglob("*.py") for m in re.findall(r"[\"'](RTLAB_\w+)[\"']", p.read_text())}
    from rtlab.settings import SETTINGS
    assert not used - set(SETTINGS), f"RTLAB_* names not in rtlab.settings.SETTINGS: {sorted(used - set(SETTINGS))}"


def test_readme_lists_every_setting():
    """README's table of settings is rtlab.settings.SETTINGS, no more and no less."""
    from rtlab.settings import SETTINGS
    text = (PROJECT_DIR / "README.md").read_text()
    table = set(re.findall(r"^\| `(\w+)` \|", text.split("### Settings", 1)[1].split("\n## ", 1)[0], re.M))
    assert table == set(SETTINGS), f"README has {sorted(table - set(SETTINGS))}, lacks {sorted(set(SETTINGS) - table)}"


def test_import_rtlab_changes_nothing():
    """`import rtlab` in a fresh process sets no environment variable, creates no folder, parses no
    kernel header and loads none of numba, pyopencl, pycuda or trimesh; the first use does."""
    probe = textwrap.dedent("""
        import os, sys, json
        before = dict(os.environ)
        import rtlab
        heavy = sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'pyopencl', 'pycuda', 'trimesh')
                       or m in ('rtlab.kernel_constants', 'rtlab.device.kernels'))
        changed = sorted(set(os.environ.items()) ^ set(before.items()))
        made = os.path.exists(os.environ["XDG_CACHE_HOME"])
        import rtlab.jit
        print(json.dumps({"heavy": heavy, "changed": changed, "made": made,
                          "after_jit": os.environ.get("OMP_WAIT_POLICY"),
                          "made_after_jit": os.path.exists(os.environ["XDG_CACHE_HOME"])}))
    """)
    import subprocess
    import sys
    import tempfile
    with tempfile.TemporaryDirectory() as home:
        env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY",)}
        env["XDG_CACHE_HOME"] = str(Path(home) / "cache")
        out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True, check=True)
    import json
    seen = json.loads(out.stdout.strip().splitlines()[-1])
    assert seen["heavy"] == [] and seen["changed"] == [] and not seen["made"], seen
    assert seen["after_jit"] == "PASSIVE" and seen["made_after_jit"], f"rtlab.jit prepares the process: {seen}"


# ---- functions a reader takes in at once ----------------------------------------------------------

LONG_FUNCTION = 60       # lines, docstring included
MANY_PARAMETERS = 8      # self/cls not counted


def _unreasoned_functions(source: str, where: str) -> list[str]:
    """'where:line name (why)' for each function over LONG_FUNCTION lines or MANY_PARAMETERS
    parameters that does not say why: "Why long:" / "Why many parameters:" in its docstring or in the
    comment lines right above it. A module docstring's "Why many parameters:" covers its numba
    functions (nopython mode takes arrays one by one); a typer command's parameters are its
    command-line options, so their number is the command's, not a design choice."""
    tree = ast.parse(source)
    lines = source.split("\n")
    module_doc = ast.get_docstring(tree) or ""
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        a = node.args
        params = [*a.posonlyargs, *a.args, *a.kwonlyargs] + [x for x in (a.vararg, a.kwarg) if x]
        n_params = len(params) - (1 if a.args and a.args[0].arg in ("self", "cls") else 0)
        n_lines = node.end_lineno - node.lineno + 1
        first = min([node.lineno] + [d.lineno for d in node.decorator_list]) - 1
        above = []
        while first - 1 - len(above) >= 0 and lines[first - 1 - len(above)].strip().startswith("#"):
            above.append(lines[first - 1 - len(above)])
        stated = (ast.get_docstring(node) or "") + "\n".join(above)
        numba = any("njit" in ast.unparse(d) for d in node.decorator_list)
        typer = any(isinstance(d, ast.Call) and ast.unparse(d.func).startswith("typer.")
                    for d in [*a.defaults, *a.kw_defaults] if d is not None)
        if n_lines > LONG_FUNCTION and "Why long:" not in stated:
            found.append(f"{where}:{node.lineno} {node.name} ({n_lines} lines, no 'Why long:')")
        if (n_params > MANY_PARAMETERS and "Why many parameters:" not in stated and not typer
                and not (numba and "Why many parameters:" in module_doc)):
            found.append(f"{where}:{node.lineno} {node.name} ({n_params} parameters, no 'Why many parameters:')")
    return found


def test_long_functions_and_long_signatures_say_why():
    """A function of rtlab over LONG_FUNCTION lines or MANY_PARAMETERS parameters states why it is one
    function (most are split into steps over a named state instead)."""
    found = [f for p in sorted(PACKAGE_DIR.rglob("*.py"))
             for f in _unreasoned_functions(p.read_text(), str(p.relative_to(PROJECT_DIR)))]
    assert not found, "\n".join(found)


def test_the_function_rule_finds_what_it_should():
    """The rule above can fail: a long function, a long signature (also under numba without the
    module's reason) are found; stated reasons and typer options are not."""
    body = "\n".join(f"    x{i} = {i}" for i in range(LONG_FUNCTION))
    many = ", ".join(f"a{i}" for i in range(MANY_PARAMETERS + 1))
    src = (f"def long_one():\n{body}\n\n"
           f"def wide({many}):\n    pass\n\n"
           f"@njit\ndef wide_numba({many}):\n    pass\n\n"
           f"# Why long: a reason\ndef long_said():\n{body}\n\n"
           f"def wide_said({many}):\n    '''Why many parameters: a reason'''\n\n"
           f"def command({', '.join(f'a{i}=typer.Option(1)' for i in range(MANY_PARAMETERS + 1))}):\n    pass\n")
    found = _unreasoned_functions(src, "x.py")
    assert [f.split()[1] for f in found] == ["long_one", "wide", "wide_numba"], found
    said = _unreasoned_functions('"""Why many parameters: numba"""\n' + src, "x.py")
    assert [f.split()[1] for f in said] == ["long_one", "wide"], said


def test_numba_cache_folder_follows_the_modules_that_compile_with_numba(tmp_path, monkeypatch):
    """numba revalidates a cached function by its own file's time stamp only: the float64 reference's
    walk (tracer.py) kept its compile of an old triangle test (watertight.py) and raised where the new
    one misses. The cache folder now changes with the content of every module that compiles with
    numba, not with the others, and the three newest folders stay."""
    from rtlab import paths
    package = tmp_path / "package"
    (package / "sub").mkdir(parents=True)
    (package / "walk.py").write_text("from .jit import njit\n")
    (package / "sub" / "test.py").write_text("from ..jit import njit\nX = 1\n")
    (package / "plain.py").write_text("X = 1\n")
    monkeypatch.setattr(paths, "PACKAGE_DIR", package)
    monkeypatch.setattr(paths, "user_cache_dir", lambda: tmp_path / "cache")
    first = paths.numba_cache_dir()
    (package / "plain.py").write_text("X = 2\n")
    assert paths.numba_cache_dir() == first
    (package / "sub" / "test.py").write_text("from ..jit import njit\nX = 2\n")
    second = paths.numba_cache_dir()
    assert second != first and second.is_dir()
    for k in range(5):
        (package / "walk.py").write_text(f"from .jit import njit\nY = {k}\n")
        newest = paths.numba_cache_dir()
    folders = list((tmp_path / "cache" / "numba").iterdir())
    assert len(folders) == 3 and newest in folders
