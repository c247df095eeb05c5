"""The variant registry: every part a variant is made of, by name -> the #define code the kernels test ->
the source that implements it -> the program that runs it. Python, the CLI (choices, `rtlab variants`),
the grader (a test's variant) and the tests read these tables; nothing else lists a variant.

    TRAVERSAL_SPECS["bvh"]       # code RT_TRAVERSAL_BVH, rt_bvh.h's traverse_bvh, reads the "bvh" structure
    program_for("trace", Variant("bvh", "watertight"))           # "library_trace"
    program_for("trace", Variant.paper(traversal="packet"), lab=True)   # "03_traversal"

Codes are the headers' (``#define RT_TRAVERSAL_BVH 5`` atop rt_port.h, read by rtlab.kernel_constants):
the kernels compile a part by its code, the traversal through rt_traverse.h's ``#if`` chain, which
tests/test_architecture.py checks against the header and function named here.

Programs: the library (``trace()``, ``render()``, Whitted frames, probes) compiles its own programs,
kernels/{cuda,opencl}/library_*.{cu,cl}; the lab steps are exercises over the same entry kernels
(kernels/shared/rt_entry_*.h). ``lab=True`` picks the lab step whose kernels run a variant: the
grader's tests and the paper's benches, whose variants live there (constants in global memory and a
ray in shared memory are lab step 01's study only).

A Variant names what it varies; a part left out (traversal, intersection, block: None) is the
library's default for the device it runs on (:func:`default_variant`), filled in by
:func:`resolve_variant`. The paper's variant (§4: kd stack, Moller-Trumbore, 32x4) is named
explicitly where the paper's tables and the labs need it: ``Variant.paper(...)``.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

from ..errors import VariantError
from ..kernel_constants import kernel_constant

PACKET_LANES = int(kernel_constant("RT_LANES"))   # rays a packet, children a wide node: one AVX register


def _code(prefix: str, name: str) -> int:
    """The code #define'd as prefix + NAME in rt_port.h ("bvh-packet" -> RT_TRAVERSAL_BVH_PACKET)."""
    return int(kernel_constant(prefix + name.upper().replace("-", "_")))


@dataclass(frozen=True)
class TraversalSpec:
    """One traversal: its code, where it is written, what it reads and how the kernels take rays."""
    name: str
    header: str                 # kernels/shared/ header that implements it (rt_traverse.h includes it)
    function: str               # its traversal function there
    structure: str              # what it reads (rtlab.device.device_scene.ACCEL_BUILDERS; "kd": the kd-tree as built)
    lab: str                    # the lab step that asks for it ("" for the course's own)
    rays_per_item: int = 1      # rays of trace_rays (pixels of a row of render_primary) a work-item takes
    lanes: bool = False         # SIMD lanes in a work-item (rt_lanes.h): RT_LANES children or rays
    box_fma: bool = False       # the fused box test may apply (RT_BVH_BOX_FMA, scene.near_origin)
    block_packet: bool = False  # a block is one packet, its stack in block-wide memory: only the kernels of
                                # closest hits and primary rays declare it (no shadow or secondary rays)
    leaf_tris: bool = False     # its leaves read their triangles' vertices from a leaf-ordered copy in tri_data
                                # (RT_BVH_LEAF_TRIS) with the tests that read vertices (uses_leaf_tris)
    fetch_rays: bool = False    # trace() takes its rays as lanes free up (trace_rays_fetch) where the device
                                # has warps (Backend.has_warp_votes): rays in no image order

    @property
    def code(self) -> int:
        return _code("RT_TRAVERSAL_", self.name)


# The CPU's traversals read one wide BVH (rt_bvh_wide.h, PACKET_LANES children a node): "bvh-wide" walks
# it one ray a work-item, a node's children in SIMD lanes; "bvh-packet" walks it with packets of
# PACKET_LANES rays a work-item where a packet's rays are coherent, ray by ray as "bvh-wide" where they
# are not. "bvh8" is the compressed 8-wide BVH (Ylitie et al. 2017) and "bvh4" a 4-wide one with float
# boxes, both collapsed from the same binary trees as "bvh".
TRAVERSAL_SPECS = {s.name: s for s in (
    TraversalSpec("stack", "rt_kdtree.h", "traverse_kd_stack", "kd", "00_primary"),
    TraversalSpec("packet", "rt_packet.h", "traverse_kd_packet", "kd", "03_traversal", block_packet=True),
    TraversalSpec("restart", "rt_kd_restart.h", "traverse_kd_restart", "kd", "03_traversal"),
    TraversalSpec("shortstack", "rt_kd_shortstack.h", "traverse_kd_shortstack", "kd", "03_traversal"),
    TraversalSpec("ropes", "rt_kd_ropes.h", "traverse_kd_ropes", "ropes", "03_traversal"),
    TraversalSpec("bvh", "rt_bvh.h", "traverse_bvh", "bvh", "03_traversal", box_fma=True, leaf_tris=True,
                  fetch_rays=True),
    TraversalSpec("bvh-packet", "rt_bvh_packet.h", "traverse_bvh_packet", "cpu-bvh", "",
                  rays_per_item=PACKET_LANES, lanes=True, box_fma=True),
    TraversalSpec("bvh8", "rt_bvh8.h", "traverse_bvh8", "bvh8", ""),
    TraversalSpec("bvh4", "rt_bvh4.h", "traverse_bvh4", "bvh4", "", fetch_rays=True),
    TraversalSpec("bvh-wide", "rt_bvh_wide.h", "traverse_bvh_wide", "cpu-bvh", "", lanes=True, box_fma=True),
)}
# Triangle tests (rt_intersect.h's intersect_ray_tri_<name>; the paper's Table 3 and Woop et al. 2013)
ISECT_FUNCTIONS = {name: f"intersect_ray_tri_{name}" for name in ("moller", "wald", "plucker", "watertight")}

# name -> code, for each part a Variant names
TRAVERSALS = {name: spec.code for name, spec in TRAVERSAL_SPECS.items()}
INTERSECTIONS = {name: _code("RT_ISECT_", name) for name in ISECT_FUNCTIONS}
NODE_MEMORY = {name: _code("RT_MEM_", name) for name in ("global", "texture")}
# Memory placement (§3.1.1, lab step 01): camera/lights/materials; the ray; rays to threads (§4.1)
CONST_MEMORY = {name: _code("RT_MEM_", name) for name in ("constant", "global")}
RAY_MEMORY = {name: _code("RT_MEM_", name) for name in ("registers", "shared", "indexed")}
RAY_ORDERS = {name: _code("RT_ORDER_", name) for name in ("rows", "morton")}
DEVICE_PARTS = ("traversal", "intersection", "block")     # what a Variant may leave to the device


def lookup(table: dict, name: str, what: str) -> int:
    try:
        return table[name]
    except KeyError:
        raise VariantError(f"unknown {what} '{name}'; choose one of: {', '.join(table)}") from None


@dataclass(frozen=True)
class Variant:
    """What the paper varies (§3.1, §4). Each field becomes a -D define or the launch shape. A part
    left None is the library's default for the device (resolve_variant); Variant.paper() is §4's."""
    traversal: str | None = None
    intersection: str | None = None
    node_memory: str = "global"
    block: tuple[int, int] | None = None   # threads in x (along a row) by y; the paper's Fig. 4 sweeps it
    short_stack: int = 4          # short-stack entries (Horn et al. 2007), RT_SHORT_STACK_SIZE
    constants: str = "constant"   # camera, lights, materials: CONST_MEMORY (RT_CONST_MEM)
    ray_memory: str = "registers" # the ray: RAY_MEMORY (RT_RAY_MEM); "shared" is CUDA only
    max_registers: int = 0        # register cap per thread (-maxrregcount / -cl-nv-maxrregcount); 0: none
    ray_order: str = "rows"       # threads to pixels within a block: RAY_ORDERS (RT_RAY_ORDER)
    count_work: bool = False      # an instrumented build whose loaders count reads (RT_COUNT_WORK): the
                                  # grader's work budget; global placement only

    def __post_init__(self):
        if not 1 <= int(self.short_stack) <= 64:
            raise VariantError(f"short_stack must be 1..64 entries, got {self.short_stack}")
        if self.traversal is not None:
            lookup(TRAVERSALS, self.traversal, "traversal")
        if self.intersection is not None:
            lookup(INTERSECTIONS, self.intersection, "intersection test")
        lookup(NODE_MEMORY, self.node_memory, "memory placement")
        lookup(CONST_MEMORY, self.constants, "constant placement")
        lookup(RAY_MEMORY, self.ray_memory, "ray placement")
        lookup(RAY_ORDERS, self.ray_order, "ray order")
        if self.block is not None:
            if len(self.block) != 2 or min(self.block) < 1:
                raise VariantError(f"block must be two positive sizes (x, y), got {self.block}")
            object.__setattr__(self, "block", (int(self.block[0]), int(self.block[1])))
            if self.ray_order == "morton" and any(b & (b - 1) for b in self.block):
                raise VariantError(f"Morton ray order needs power-of-two block sides, got "
                                   f"{self.block[0]}x{self.block[1]}")
        if self.max_registers and not 16 <= int(self.max_registers) <= 255:
            raise VariantError(f"max_registers must be 0 (no cap) or 16..255, got {self.max_registers}")
        if self.count_work and self.node_memory != "global":
            raise VariantError("count_work counts the loads of the global placement; node_memory must be 'global'")

    @classmethod
    def paper(cls, **parts) -> "Variant":
        """The paper's variant (kd stack, Moller-Trumbore, 32x4 blocks) with ``parts`` replaced: the
        lab steps' and the paper benches' base."""
        return PAPER_VARIANT.with_(**parts)

    @property
    def spec(self) -> TraversalSpec:
        return TRAVERSAL_SPECS[self.require("traversal")]

    def unresolved(self) -> list[str]:
        """The parts left to the device (None)."""
        return [name for name in DEVICE_PARTS if getattr(self, name) is None]

    def require(self, part: str):
        value = getattr(self, part)
        if value is None:
            raise VariantError(f"variant {self.label()} leaves its {part} to the device: resolve it for a backend "
                               f"first (rtlab.device.variants.resolve_variant)")
        return value

    def resolve(self, defaults: "Variant") -> "Variant":
        """This variant with the parts it leaves to the device taken from ``defaults``."""
        return replace(self, **{name: getattr(defaults, name) for name in self.unresolved()})

    def needs_memory_kernels(self) -> bool:
        """Whether only lab step 01's entry kernels can run this variant."""
        return self.constants != "constant" or self.ray_memory == "shared"

    def with_(self, **kw) -> "Variant":
        """This variant with the fields ``kw`` names replaced (Variant.paper's too): an unknown field is
        a VariantError naming the fields, not dataclasses' TypeError."""
        unknown = [k for k in kw if k not in VARIANT_FIELDS]
        if unknown:
            raise VariantError(f"Variant has no field {', '.join(map(repr, unknown))}; "
                               f"fields: {', '.join(VARIANT_FIELDS)}")
        return replace(self, **kw)

    def label(self) -> str:
        name = self.traversal or "default"
        traversal = f"shortstack{self.short_stack}" if name == "shortstack" else name
        block = f"{self.block[0]}x{self.block[1]}" if self.block else "default"
        extra = "".join([f"/const-{self.constants}" if self.constants != "constant" else "",
                         f"/ray-{self.ray_memory}" if self.ray_memory != "registers" else "",
                         f"/{self.ray_order}" if self.ray_order != "rows" else "",
                         f"/maxrreg{self.max_registers}" if self.max_registers else "",
                         "/counted" if self.count_work else ""])
        return f"{traversal}/{self.intersection or 'default'}/{self.node_memory}/{block}{extra}"


VARIANT_FIELDS = tuple(f.name for f in fields(Variant))
PAPER_BLOCK = (32, 4)
PAPER_VARIANT = Variant(traversal="stack", intersection="moller", block=PAPER_BLOCK)
# The library's defaults (rtlab.device.tracing says why each): on a GPU the binary BVH with the
# watertight test in 8x16 blocks, and for rays through trace() the 4-wide BVH in its place; on a CPU
# bvh-packet with the watertight test; in a student tree, where the lane form of the watertight test
# is a stub, the CPU takes the scalar test on the kd stack.
GPU_DEFAULT_VARIANT = Variant(traversal="bvh", intersection="watertight", block=(8, 16))
GPU_RAYS_VARIANT = GPU_DEFAULT_VARIANT.with_(traversal="bvh4")
CPU_DEFAULT_VARIANT = Variant(traversal="bvh-packet", intersection="watertight", block=PAPER_BLOCK)
SCALAR_CPU_VARIANT = Variant(traversal="stack", intersection="watertight", block=PAPER_BLOCK)


def default_variant(device, rays: bool = False) -> Variant:
    """The variant the library runs when none is named, for ``device``: a Backend, or "gpu" / "cpu".
    ``rays``: for rays through trace() (GPU_RAYS_VARIANT on a GPU), not frames (render, Whitted)."""
    from ..paths import tree_has_stubs
    gpu = device == "gpu" if isinstance(device, str) else device.is_gpu()
    if gpu:
        return GPU_RAYS_VARIANT if rays else GPU_DEFAULT_VARIANT
    return SCALAR_CPU_VARIANT if tree_has_stubs("shared/rt_intersect_lanes.h") else CPU_DEFAULT_VARIANT


def resolve_variant(variant, device, rays: bool = False) -> Variant:
    """The variant to run on ``device`` (a Backend, or "gpu" / "cpu"): default_variant(device, rays) for None;
    a Variant with the parts it leaves out (None) taken from that default; for a string the default
    with the named parts replaced: a traversal ("bvh"), a triangle test ("moller"), or both as
    "traversal/test" ("stack/watertight"), so a name never silently changes the triangle test."""
    default = default_variant(device, rays)
    if variant is None:
        return default
    if isinstance(variant, Variant):
        return variant.resolve(default)
    if not isinstance(variant, str):
        text = repr(variant)
        raise VariantError(f"variant must be an rtlab Variant or a name such as 'bvh' or 'stack/moller', got "
                           f"{type(variant).__name__} {text if len(text) <= 40 else text[:37] + '...'}")
    parts = [p.strip().lower() for p in variant.split("/") if p.strip()]
    if not parts or len(parts) > 2:
        raise VariantError(f"variant {variant!r}: name a traversal, a triangle test or 'traversal/test' "
                           f"(traversals: {', '.join(TRAVERSALS)}; tests: {', '.join(INTERSECTIONS)})")
    chosen = {}
    for part in parts:
        key = "traversal" if part in TRAVERSALS else "intersection" if part in INTERSECTIONS else None
        if key is None or key in chosen:
            raise VariantError(f"variant {variant!r}: {part!r} is not a traversal ({', '.join(TRAVERSALS)}) or a "
                               f"triangle test ({', '.join(INTERSECTIONS)}){' (named twice)' if key else ''}")
        chosen[key] = part
    return default.with_(**chosen)


# ---- programs ------------------------------------------------------------------------------------
# What a program is for -> the library's program (kernels/{cuda,opencl}/<name>.{cu,cl}) and the lab
# step whose kernels do the same. "trace": trace_rays, trace_ray_grid, render_primary; "loop": the
# brute force over the first n triangles (trace_rays_loop, intersect_triangles); "shadows": shadow
# rays one-pass and two-pass; "bounces": the kernel tree and the wavefront; "fetch": scene buffers
# read back through a placement (lab step 01 only).
LIBRARY_PROGRAMS = {"trace": "library_trace", "loop": "library_trace", "shadows": "library_shadows",
                    "bounces": "library_bounces"}
LAB_PROGRAMS = {"trace": "00_primary", "loop": "02_intersect", "shadows": "04_shadows", "bounces": "05_kernel_tree",
                "fetch": "01_memory"}
MEMORY_STEP = "01_memory"
PACKET_STEP = "03_traversal"


def program_for(purpose: str, variant: Variant, lab: bool = False) -> str:
    """The program (a kernel pair's stem) whose kernels do ``purpose`` for ``variant``: the library's,
    or with ``lab`` the lab step's (lab step 01's for its memory placements, 03's for the kd packet)."""
    if purpose not in LAB_PROGRAMS:
        raise VariantError(f"no program for {purpose!r}; purposes: {', '.join(LAB_PROGRAMS)}")
    spec = variant.spec
    if purpose in ("shadows", "bounces") and spec.block_packet:
        raise VariantError(f"the {spec.name} traversal has no shadow or secondary-ray kernels (its stack lives in "
                           "block-wide memory, declared by the kernels of closest hits and primary rays): choose a "
                           "single-ray traversal")
    special = variant.needs_memory_kernels() or variant.ray_order != "rows"
    if purpose == "trace" and special and (spec.block_packet or spec.rays_per_item > 1):
        raise VariantError(f"the {spec.name} traversal takes rays in packets, with constants in constant memory, the "
                           "ray in registers and threads on pixels in rows")
    if not lab:
        if variant.needs_memory_kernels():
            raise VariantError(f"{variant.label()}: constants in global memory and a ray in shared memory are lab step "
                               f"{MEMORY_STEP}'s placement study, not the library's: run its kernels (lab=True)")
        if purpose not in LIBRARY_PROGRAMS:
            raise VariantError(f"the library has no {purpose!r} program: it is lab step {LAB_PROGRAMS[purpose]}'s (lab=True)")
        return LIBRARY_PROGRAMS[purpose]
    if purpose == "trace" and variant.needs_memory_kernels():
        return MEMORY_STEP
    if purpose == "trace" and spec.block_packet:
        return PACKET_STEP
    return LAB_PROGRAMS[purpose]


def registry_rows() -> list[dict]:
    """The traversal table as rows (`rtlab variants`): sources in kernels/shared/; whose default it is."""
    defaults = (("GPU", GPU_DEFAULT_VARIANT), ("GPU rays", GPU_RAYS_VARIANT), ("CPU", CPU_DEFAULT_VARIANT),
                ("paper", PAPER_VARIANT))
    return [{"traversal": s.name, "code": s.code, "source": s.header, "function": s.function, "reads": s.structure,
             "lab step": s.lab or "-", "default": ", ".join(d for d, v in defaults if v.traversal == s.name) or "-"}
            for s in TRAVERSAL_SPECS.values()]

