"""The grader's structural checks, against routes to unearned marks:

* lab 03 (rtlab.course.structure): lab 00's ``traverse_kd_stack`` copied into the stackless, short-stack
  and packet traversals (the lab-call rule reads calls, not copies). A stackless traversal keeps no more per-ray indexed private storage than its reference (none), the short stack no
  more than its RT_SHORT_STACK_SIZE entries, the packet its stack in the block's local memory: read
  from the same LLVM IR as the lab-call rule, before each compile. A stack of 64
  entries in structs of structs of KdStackEntry (no array type anywhere) is counted by
  what the code does with it, a variable index through whatever pointer.
* lab 01 (rtlab.course.regions, rtlab.course.ptx, checks.nvcc.NvccKind): the template's stub with its
  TODO comment deleted, and texture fetches of element 0, on the nvcc tests. A stub is told by its
  tokens; fetch_scene's PTX is followed and compared with the reference's; the shared-memory
  ray must be stored from the kernel's ray.

Each: the reference passes, legitimate other forms pass, each forged form fails with its message. Most
checks run on the compiler's output directly (seconds); one grading per lab shows the refusals end to end.
"""
from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from rtlab.backends.nvcc import nvcc_available
from rtlab.course import grade, load_config, write_template
from rtlab.course.regions import find_regions, stubbed_functions, template_stubs
from rtlab.paths import PROJECT_DIR

from .test_grading import assert_refused, reference_files

STEP03, STEP01 = "03_traversal", "01_memory"
SHARED = "kernels/shared"


def region_body(relpath: str, function: str) -> str:
    text = (PROJECT_DIR / relpath).read_text()
    [r] = [r for r in find_regions(text) if r.function == function]
    return r.body(text)


def replace_body(path: Path, function: str, body: str, before: str = "") -> None:
    """``function``'s solution region in ``path`` holding ``body``; ``before`` put ahead of its signature."""
    text = path.read_text()
    [r] = [r for r in find_regions(text) if r.function == function]
    text = text[:r.body_start] + body.rstrip("\n") + "\n" + text[r.body_end:]
    if before:
        sig = re.search(rf"^RT_FN [^\n]*\b{function}\(", text, re.M)
        text = text[:sig.start()] + before + text[sig.start():]
    path.write_text(text)


# --------------------------------------------------------------------------------------------------
# lab 03: no per-ray stack where the reference has none
# --------------------------------------------------------------------------------------------------
COPIED_STACK = region_body(f"{SHARED}/rt_kdtree.h", "traverse_kd_stack")      # lab 00's walk, copied verbatim
FILES = {"traverse_kd_restart": "rt_kd_restart.h", "traverse_kd_shortstack": "rt_kd_shortstack.h",
         "traverse_kd_ropes": "rt_kd_ropes.h", "traverse_kd_packet": "rt_packet.h"}
TRAVERSAL = {"traverse_kd_restart": "restart", "traverse_kd_shortstack": "shortstack",
             "traverse_kd_ropes": "ropes", "traverse_kd_packet": "packet"}


def restart_with_scalars() -> str:
    """A legitimate kd-restart written otherwise: more scalar locals and a per-axis array (12 B)."""
    body = region_body(f"{SHARED}/rt_kd_restart.h", "traverse_kd_restart")
    head = ("    float axis_t[3] = {0.0f, 0.0f, 0.0f};     /* per-axis scratch, no stack */\n"
            "    int restarts = 0;\n")
    body = body.replace("            intersect_leaf(", "            ++restarts;\n            axis_t[restarts % 3] = seg.tmax;\n"
                                                      "            intersect_leaf(", 1)
    assert "++restarts" in body
    return head + body


def shortstack_in_parallel_arrays() -> str:
    """A legitimate short stack: its entries in two arrays of RT_SHORT_STACK_SIZE (node, segment)."""
    body = region_body(f"{SHARED}/rt_kd_shortstack.h", "traverse_kd_shortstack")
    body = body.replace("KdShortStackEntry stack[RT_SHORT_STACK_SIZE];",
                        "int stack_node[RT_SHORT_STACK_SIZE];\n    KdSegment stack_seg[RT_SHORT_STACK_SIZE];")
    body = body.replace("stack[top].node", "stack_node[top]").replace("stack[top].seg", "stack_seg[top]")
    body = body.replace("ring: stack[top] is", "ring: entry top is")
    assert "stack[" not in body
    return body


# A stack of 64 KdStackEntry in structs of structs, indexed through a pointer (1 KiB)
NESTED_TYPES = ("typedef struct { KdStackEntry a, b, c, d; } NestedS4;\n"
                "typedef struct { NestedS4 a, b, c, d; } NestedS16;\n"
                "typedef struct { NestedS16 a, b, c, d; } NestedS64;\n\n")
NESTED_STACK = COPIED_STACK.replace("KdStackEntry stack[RT_STACK_SIZE];",
                                    "NestedS64 store;\n    KdStackEntry *stack = &store.a.a.a;   /* no array type */")
assert NESTED_STACK != COPIED_STACK
RESTART = region_body(f"{SHARED}/rt_kd_restart.h", "traverse_kd_restart")


def nested_stack(index: str, before: str = "") -> tuple[str, str]:
    """The nested-struct stack with each ``stack[i]`` written as ``index`` (``{i}``: the index), and
    its types with ``before`` to put ahead of the function."""
    body = re.sub(r"stack\[([^\]]*)\]", lambda m: index.format(i=m.group(1)), NESTED_STACK)
    return body, NESTED_TYPES + before


LEAF_HELPER = ("/* Whether the walk ends after a leaf: a hit inside the cell, or no cell left on the segment */\n"
               "RT_FN int leaf_ends_walk(const Hit *hit, KdSegment *seg, float t_exit)\n{\n"
               "    float t_hit = t_cull(hit->t);\n    int inside = t_hit < seg->tmax;\n"
               "    return inside || !kd_next_restart(seg, t_exit);\n}\n\n")


def restart_with_a_helper() -> str:
    """A legitimate kd-restart written otherwise: a couple more scalars (a leaf count, the root node
    loaded once) and a small helper of its own for the end of a leaf (LEAF_HELPER)."""
    body = RESTART.replace("    int planes = 0;\n", "    int planes = 0;\n    int leaves = 0;\n"
                                                   "    const int2 root = load_node(nodes, 0);\n", 1)
    body = body.replace("int2 n = load_node(nodes, 0);", "int2 n = root;", 1)
    body = body.replace("            intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);\n",
                        "            intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);\n            ++leaves;\n", 1)
    body = body.replace("if (t_cull(hit->t) < seg.tmax || !kd_next_restart(&seg, t_exit))",
                        "if (leaf_ends_walk(hit, &seg, t_exit))", 1)
    assert "leaf_ends_walk(hit" in body and "++leaves" in body and "= root;" in body
    return body


def restart_reading_by_axis() -> str:
    """A legitimate kd-restart that reads the ray by axis: per-axis arrays of its origin and inverse
    direction (24 B) and a float4's lane picked by a variable (16 B): 40 B, within the slack."""
    return ("    float o[3] = {ray->o.x, ray->o.y, ray->o.z};\n"
            "    float inv[3] = {ray->inv_d.x, ray->inv_d.y, ray->inv_d.z};\n    float4 lo = scene_min;\n"
            "    int ax = hit->tri & 3;\n"
            "    float seen = ax < 3 ? o[ax] + inv[ax] + lo[ax] : 0.0f;\n    (void)seen;\n" + RESTART)


NESTED_REFUSED = (r"^traverse_kd_{f} keeps a per-ray private array store, NestedS64 indexed by a variable = 1024 B, "
                  r"where the reference traverse_kd_{f} keeps {ref}")

# (function, body, text before the function, an edit of the file) -> the refusal, or None for a pass
FORMS = {
    "reference": ("traverse_kd_shortstack", None, "", None, None),
    "restart with scalars": ("traverse_kd_restart", restart_with_scalars(), "", None, None),
    "short stack in two arrays": ("traverse_kd_shortstack", shortstack_in_parallel_arrays(), "", None, None),
    "restart with scalars and a helper": ("traverse_kd_restart", restart_with_a_helper(), LEAF_HELPER, None, None),
    "restart reading the ray by axis": ("traverse_kd_restart", restart_reading_by_axis(), "", None, None),
    # a nested-struct stack, and other ways to index private memory without an array type
    "nested-struct stack as restart": (
        "traverse_kd_restart", NESTED_STACK, NESTED_TYPES, None,
        NESTED_REFUSED.format(f="restart", ref=r"none \(0 B\): kd-restart is stackless")),
    "nested-struct stack as short stack": (
        "traverse_kd_shortstack", NESTED_STACK, NESTED_TYPES, None,
        NESTED_REFUSED.format(f="shortstack", ref=r"160 B \(its stack, \[4 x KdShortStackEntry\]\): a short stack")),
    "nested-struct stack as ropes": (
        "traverse_kd_ropes", NESTED_STACK, NESTED_TYPES, None, NESTED_REFUSED.format(f="ropes", ref=r"none \(0 B\)")),
    "nested-struct stack, pointer arithmetic": (
        "traverse_kd_restart", *nested_stack("(*(stack + ({i})))"), None,
        NESTED_REFUSED.format(f="restart", ref="none")),
    "nested-struct stack, through an integer": (
        "traverse_kd_restart", *nested_stack("(*(KdStackEntry *)((ulong)stack + (ulong)({i}) * sizeof(KdStackEntry)))"),
        None, NESTED_REFUSED.format(f="restart", ref="none")),
    "nested-struct stack, a helper indexes it": (
        "traverse_kd_restart", *nested_stack("(*kd_at(stack, {i}))",
                                             "RT_FN KdStackEntry *kd_at(KdStackEntry *s, int i) { return &s[i]; }\n\n"),
        None, NESTED_REFUSED.format(f="restart", ref="none")),
    "nested-struct stack, its pointer in a struct": (
        "traverse_kd_restart",
        NESTED_STACK.replace("KdStackEntry *stack = &store.a.a.a;",
                             "struct { KdStackEntry *p; int pad; } at;\n    at.p = &store.a.a.a;")
                    .replace("stack[", "at.p["),
        NESTED_TYPES, None, NESTED_REFUSED.format(f="restart", ref="none")),
    "a union indexed through a pointer": (
        "traverse_kd_ropes",
        NESTED_STACK.replace("NestedS64 store;\n    KdStackEntry *stack = &store.a.a.a;",
                             "union { NestedS64 s; int first; } u;\n    KdStackEntry *stack = &u.s.a.a.a;"),
        NESTED_TYPES, None,
        r"^traverse_kd_ropes keeps a per-ray private array u, a union indexed by a variable = 1024 B"),
    "recursive walk": (
        "traverse_kd_restart", "    kd_walk_rec(RT_SCENE_ARGS, 0, ray, hit, any_hit);\n",
        "RT_FN void kd_walk_rec(RT_SCENE_PARAMS, int node, const Ray *ray, Hit *hit, int any_hit)\n{\n"
        "    int2 n = load_node(nodes, node);\n    if (kd_is_leaf(n)) {\n"
        "        intersect_leaf(RT_SCENE_ARGS, n, ray, hit, any_hit);\n        return;\n    }\n"
        "    kd_walk_rec(RT_SCENE_ARGS, n.x >> 2, ray, hit, any_hit);\n"
        "    kd_walk_rec(RT_SCENE_ARGS, (n.x >> 2) + 1, ray, hit, any_hit);\n}\n\n", None,
        r"^traverse_kd_restart keeps a per-ray stack of call frames: kd_walk_rec calls kd_walk_rec \(recursion, in "
        r"kd_walk_rec, which traverse_kd_restart calls\), where the reference traverse_kd_restart calls nothing "
        r"recursively: kd-restart is stackless"),
    "copied stack as restart": (
        "traverse_kd_restart", COPIED_STACK, "", None,
        r"^traverse_kd_restart keeps a per-ray private array stack, \[\d+ x KdStackEntry\] = \d+ B, where the "
        r"reference traverse_kd_restart keeps none \(0 B\): kd-restart is stackless"),
    "copied stack as short stack": (
        "traverse_kd_shortstack", COPIED_STACK, "", None,
        r"^traverse_kd_shortstack keeps a per-ray private array stack, \[\d+ x KdStackEntry\] = \d+ B, where the "
        r"reference traverse_kd_shortstack keeps \d+ B \(its stack, \[4 x KdShortStackEntry\]\): a short stack "
        r"holds at most RT_SHORT_STACK_SIZE = 4 entries"),
    "copied stack as ropes": (
        "traverse_kd_ropes", COPIED_STACK, "", None,
        r"^traverse_kd_ropes keeps a per-ray private array stack, \[\d+ x KdStackEntry\] = \d+ B, where the "
        r"reference traverse_kd_ropes keeps none \(0 B\): the ropes traversal is stackless"),
    "copied stack as packet": (
        "traverse_kd_packet", "    if (!valid)\n        return;\n" + COPIED_STACK, "", None,
        r"^traverse_kd_packet keeps a per-ray private array stack, \[\d+ x KdStackEntry\] = \d+ B, where the "
        r"reference traverse_kd_packet keeps none \(0 B\): a packet keeps ONE stack for all its rays in the "
        r"block's local memory"),
    "stack in a helper": (
        "traverse_kd_restart", "    kd_walk_mine(RT_SCENE_ARGS, scene_min, scene_max, ray, hit, any_hit);\n",
        "RT_FN void kd_walk_mine(RT_SCENE_PARAMS, float4 scene_min, float4 scene_max, const Ray *ray, Hit *hit,\n"
        "                        int any_hit)\n{\n" + COPIED_STACK + "}\n\n", None,
        r"^traverse_kd_restart keeps a per-ray private array stack, \[\d+ x KdStackEntry\] = \d+ B \(in "
        r"kd_walk_mine, which traverse_kd_restart calls\), where the reference traverse_kd_restart keeps none"),
    "stack in a struct": (
        "traverse_kd_ropes", "    struct { int sp; KdStackEntry e[RT_STACK_SIZE]; } st;\n    st.sp = 0;\n    (void)st;\n",
        "", None,
        r"^traverse_kd_ropes keeps a per-ray private array st, a struct holding \[\d+ x KdStackEntry\] = \d+ B"),
    "stack in a wide vector": (
        "traverse_kd_restart", "    ulong16 trail = (ulong16)(0ul);\n    trail.s3 = 1ul;\n    (void)trail;\n"
        + region_body(f"{SHARED}/rt_kd_restart.h", "traverse_kd_restart"), "", None,
        r"^traverse_kd_restart keeps a per-ray private array trail, <16 x i64> = 128 B"),
    "packet walking ray by ray": (
        "traverse_kd_packet", "    if (!valid)\n        return;\n"
        + region_body(f"{SHARED}/rt_kd_restart.h", "traverse_kd_restart"), '#include "rt_kd_restart.h"\n\n', None,
        r"^traverse_kd_packet writes nothing to the block's local memory, where the reference traverse_kd_packet "
        r"keeps the packet's stack"),
    "packet with a stack per ray in local memory": (
        "traverse_kd_packet", None, "",
        lambda t: t.replace("    int stack_node[RT_STACK_SIZE];\n",
                            "    int stack_node[RT_STACK_SIZE];\n    int lane_stack[RT_TRACE_THREADS * RT_STACK_SIZE];\n"),
        r"^traverse_kd_packet's program holds \d+ B of local memory in \w+\.packet, more than 2x the reference's "
        r"\d+ B \(a stack for each ray of the block"),
}


def program_problem(sub: Path, tmp: Path, traversal: str, stack_size: int = 21, short: int | None = None):
    """What the test process's check (lab-call rule, then structure rule) says of the submission's lab 03
    program for ``traversal``, compiled as a test compiles it."""
    from rtlab.course.deps import opencl_ir
    from rtlab.course.kernel_sources import build_student_tree
    from rtlab.course.lab_calls import ir_call_graph, lab_call_problem, lab_call_rules
    from rtlab.course.structure import structure_problem, structure_rules
    from rtlab.device.kernels import SceneFeatures, build_defines
    from rtlab.device.variants import Variant
    tree = build_student_tree(load_config(STEP03), sub, tmp)
    assert not tree.refused, tree.refused
    src = tree.root / "opencl" / f"{STEP03}.cl"
    variant = Variant.paper(traversal=traversal) if short is None else Variant.paper(traversal=traversal,
                                                                                      short_stack=short)
    defines = {**build_defines(variant, SceneFeatures()), "RT_STACK_SIZE": stack_size}
    ir = opencl_ir(src, [tree.root / "shared", src.parent], defines)
    graph = ir_call_graph(ir)
    return lab_call_problem(graph, lab_call_rules(STEP03)) or \
        structure_problem(ir, graph, structure_rules(STEP03), defines)


def test_structure_allowances_come_from_the_reference():
    """The reference's own IR sets each allowance: kd-restart, ropes and packet hold no private array;
    the short stack's grows with RT_SHORT_STACK_SIZE (its entries) and not with RT_STACK_SIZE; the
    packet writes local memory, whose size grows with RT_STACK_SIZE (its one stack)."""
    from rtlab.course.structure import structure_rules
    rules = structure_rules(STEP03)["functions"]
    assert set(rules) == set(FILES)
    for f in ("traverse_kd_restart", "traverse_kd_ropes", "traverse_kd_packet"):
        assert rules[f]["private"] == [0, 0, 0] and rules[f]["largest"] is None, (f, rules[f])
    a, b, c = rules["traverse_kd_shortstack"]["private"]
    assert a == 0 and b == 0 and c > 0, rules["traverse_kd_shortstack"]
    assert rules["traverse_kd_shortstack"]["largest"][:2] == ["stack", "[4 x KdShortStackEntry]"]
    assert rules["traverse_kd_packet"]["local_stores"] and rules["traverse_kd_packet"]["local"][1] > 0
    assert not any(rules[f]["local_stores"] for f in rules if f != "traverse_kd_packet")
    assert not any(rules[f]["recursive"] for f in rules)
    assert structure_rules("00_primary")["functions"] == {}      # lab 00's stack traversal: no rule


@pytest.mark.parametrize("traversal", ["restart", "shortstack", "ropes", "packet", "bvh"])
@pytest.mark.parametrize("stack_size, short", [(8, 2), (21, 4), (64, 8)])
def test_reference_traversals_pass_at_any_depth(traversal, stack_size, short, tmp_path):
    sub = reference_files(STEP03, tmp_path / "sub")
    assert program_problem(sub, tmp_path / "tree", traversal, stack_size, short) is None


@pytest.mark.parametrize("form", list(FORMS))
def test_structure_rule_on_each_form(form, tmp_path):
    function, body, before, edit, message = FORMS[form]
    sub = reference_files(STEP03, tmp_path / "sub")
    path = sub / SHARED / FILES[function]
    if body is not None:
        replace_body(path, function, body, before)
    if edit is not None:
        text = path.read_text()
        path.write_text(edit(text))
        assert path.read_text() != text
    problem = program_problem(sub, tmp_path / "tree", TRAVERSAL[function])
    if message is None:
        assert problem is None, problem
    else:
        assert problem and re.search(message, problem), problem
        assert "\n" not in problem


def test_structure_measure_reads_llvm_types():
    """Sizes as the data layout gives them (vectors of three padded to four, struct padding), clang's
    tail padding ([8 x i8] in Ray) not taken for an array, an array inside a struct taken."""
    from rtlab.course.structure import TypeTable, array_bytes, read_program, size_of
    ir = ('%struct.Ray = type { <3 x float>, <3 x float>, <3 x float>, float, float, [8 x i8] }\n'
          '%struct.E = type { i32, float, float, float }\n'
          '%struct.W = type { i32, [5 x %struct.E] }\n'
          'define internal void @f(ptr %0) #0 {\n'
          '  %ray = alloca %struct.Ray, align 16\n  %st = alloca %struct.W, align 4\n'
          '  %t = alloca [3 x float], align 4\n  %n = alloca i32, i32 6, align 4\n  ret void\n}\n')
    types = TypeTable(ir)
    assert size_of(types.parse("%struct.Ray")) == 64 and array_bytes(types.parse("%struct.Ray")) == 0
    assert size_of(types.parse("%struct.W")) == 84 and array_bytes(types.parse("%struct.W")) == 80
    assert size_of(types.parse("<3 x float>")) == 16 and array_bytes(types.parse("<8 x i32>")) == 32
    locals_ = {loc.name: loc.bytes for loc in read_program(ir).functions["f"]["locals"]}
    assert locals_ == {"ray": 0, "st": 80, "t": 12, "n": 24}


def test_indexed_storage_is_read_from_what_the_code_does():
    """A local counts by the bytes a variable index reaches, whatever its type: a struct indexed through
    a pointer kept in another local, or passed to a helper that indexes its parameter (all of it); a
    vector's lane picked by a variable (that vector); not a struct read at constant offsets only, nor
    one passed to a helper that reads a field."""
    from rtlab.course.structure import read_program
    ir = ('%struct.E = type { i32, float, float, float }\n'
          '%struct.S4 = type { %struct.E, %struct.E, %struct.E, %struct.E }\n'
          '%struct.P = type { <4 x float>, <4 x float>, float }\n'
          'define internal ptr @at(ptr noundef %s, i32 noundef %i) #0 {\nentry:\n'
          '  %s.addr = alloca ptr, align 8\n  %i.addr = alloca i32, align 4\n'
          '  store ptr %s, ptr %s.addr, align 8\n  store i32 %i, ptr %i.addr, align 4\n'
          '  %0 = load ptr, ptr %s.addr, align 8\n  %1 = load i32, ptr %i.addr, align 4\n'
          '  %idx = sext i32 %1 to i64\n  %e = getelementptr inbounds %struct.E, ptr %0, i64 %idx\n'
          '  ret ptr %e\n}\n'
          'define internal float @first(ptr noundef %s) #0 {\nentry:\n  %s.addr = alloca ptr, align 8\n'
          '  store ptr %s, ptr %s.addr, align 8\n  %0 = load ptr, ptr %s.addr, align 8\n'
          '  %t = getelementptr inbounds %struct.E, ptr %0, i32 0, i32 1\n  %1 = load float, ptr %t, align 4\n'
          '  ret float %1\n}\n'
          'define internal void @f(i32 noundef %k) #0 {\nentry:\n'
          '  %k.addr = alloca i32, align 4\n  %kept = alloca %struct.S4, align 4\n  %p = alloca ptr, align 8\n'
          '  %passed = alloca %struct.S4, align 4\n  %fixed = alloca %struct.S4, align 4\n'
          '  %read = alloca %struct.S4, align 4\n  %lanes = alloca %struct.P, align 16\n'
          '  store i32 %k, ptr %k.addr, align 4\n  %0 = load i32, ptr %k.addr, align 4\n'
          '  %a = getelementptr inbounds %struct.S4, ptr %kept, i32 0, i32 0\n  store ptr %a, ptr %p, align 8\n'
          '  %1 = load ptr, ptr %p, align 8\n  %idx = sext i32 %0 to i64\n'
          '  %e = getelementptr inbounds %struct.E, ptr %1, i64 %idx\n  store i32 1, ptr %e, align 4\n'
          '  %b = getelementptr inbounds %struct.S4, ptr %passed, i32 0, i32 0\n'
          '  %call = call ptr @at(ptr noundef %b, i32 noundef %0)\n'
          '  %c = getelementptr inbounds %struct.S4, ptr %fixed, i32 0, i32 3\n  store i32 2, ptr %c, align 4\n'
          '  %r = getelementptr inbounds %struct.S4, ptr %read, i32 0, i32 2\n'
          '  %call2 = call float @first(ptr noundef %r)\n'
          '  %v = getelementptr inbounds %struct.P, ptr %lanes, i32 0, i32 1\n'
          '  %2 = load <4 x float>, ptr %v, align 16\n  %3 = extractelement <4 x float> %2, i32 %0\n'
          '  ret void\n}\n')
    locals_ = {loc.name: (loc.bytes, loc.indexed) for loc in read_program(ir).functions["f"]["locals"]}
    assert locals_ == {"k.addr": (0, False), "kept": (64, True), "p": (0, False), "passed": (64, True),
                       "fixed": (0, False), "read": (0, False), "lanes": (16, True)}, locals_


def test_lab03_nested_struct_stack_scores_nothing(tmp_path):
    """Lab 00's walk in kd-restart and the short stack, its stack 64 KdStackEntry in structs of
    structs: both traversals are refused, saying so."""
    sub = reference_files(STEP03, tmp_path / "sub")
    for f in ("traverse_kd_restart", "traverse_kd_shortstack"):         # rt_kd_shortstack.h includes
        replace_body(sub / SHARED / FILES[f], f, NESTED_STACK,             # rt_kd_restart.h: its types
                     NESTED_TYPES if f == "traverse_kd_restart" else "")
    report = grade(STEP03, sub, tests=["trace_restart", "trace_shortstack"])
    for name, f in (("trace_restart", "restart"), ("trace_shortstack", "shortstack")):
        t = report.test(name)
        assert t.score == 0 and t.status == "refused", (name, t.status, t.output)
        assert f"traverse_kd_{f} keeps a per-ray private array store, NestedS64 indexed by a variable = 1024 B" \
            in t.output, t.output
    assert report.score == 0


def test_lab03_copied_stack_scores_nothing_and_a_restart_of_its_own_passes(tmp_path):
    """Lab 00's stack walk copied into the short stack, ropes and packet
    traversals: each of their tests is refused
    with the structure rule's message; a kd-restart written with scalar locals of its own passes."""
    sub = reference_files(STEP03, tmp_path / "sub")
    replace_body(sub / SHARED / "rt_kd_restart.h", "traverse_kd_restart", restart_with_scalars())
    for f in ("traverse_kd_shortstack", "traverse_kd_ropes", "traverse_kd_packet"):
        replace_body(sub / SHARED / FILES[f], f, ("    if (!valid)\n        return;\n" if f == "traverse_kd_packet"
                                                  else "") + COPIED_STACK)
    report = grade(STEP03, sub, tests=["trace_restart", "trace_shortstack", "trace_ropes", "trace_packet",
                                       "render_packet"])
    assert report.test("trace_restart").passed, report.test("trace_restart").output
    why = {"trace_shortstack": "traverse_kd_shortstack keeps a per-ray private array stack",
           "trace_ropes": "traverse_kd_ropes keeps a per-ray private array stack",
           "trace_packet": "traverse_kd_packet keeps a per-ray private array stack",
           "render_packet": "traverse_kd_packet keeps a per-ray private array stack"}
    assert_refused(report, why)
    assert report.score == report.test("trace_restart").max_score


# --------------------------------------------------------------------------------------------------
# lab 01: a stub is told by its tokens; the CUDA functions by their PTX
# --------------------------------------------------------------------------------------------------
MEMORY_H, MEMORY_CU = f"{SHARED}/rt_memory.h", "kernels/cuda/01_memory.cu"


def test_a_stub_is_told_by_its_tokens_not_its_todo_line():
    """The template's stub with its TODO (and STUB) comment deleted, re-spaced or re-commented is still
    the stub; any other body is not; no reference region of any lab equals its stub."""
    from rtlab.course.kernel_sources import reference_kernels, reference_stubs, tree_stubs
    from rtlab.course.template import template_files
    assert tree_stubs(reference_kernels()) == {}
    stubs = reference_stubs(MEMORY_CU)
    tmpl = template_files(load_config(STEP01))[MEMORY_CU]
    assert stubbed_functions(tmpl, stubs) == ["place_ray_shared"]
    no_todo = "\n".join(line for line in tmpl.splitlines() if "TODO (lab" not in line and "STUB:" not in line)
    assert stubbed_functions(no_todo) == []                     # its own region no longer names its stub...
    assert stubbed_functions(no_todo, stubs) == ["place_ray_shared"]     # ...the reference's does
    spaced = no_todo.replace("slots[lane] = make_ray(", "/* mine */ slots [ lane ]=make_ray (\n        ")
    assert stubbed_functions(spaced, stubs) == ["place_ray_shared"]
    other = no_todo.replace("f3(0.0f, 0.0f, 1.0f), 0.0f, 0.0f)", "f3(0.0f, 0.0f, 1.0f), 0.0f, 1.0f)")
    assert other != no_todo and stubbed_functions(other, stubs) == []
    assert template_stubs(tmpl)["place_ray_shared"] == stubs["place_ray_shared"]


def test_student_tree_lists_a_stub_whose_todo_line_was_deleted(tmp_path):
    from rtlab.course.kernel_sources import build_student_tree
    sub = tmp_path / "sub"
    write_template(STEP01, sub)
    for rel in (MEMORY_H, MEMORY_CU):
        p = sub / rel
        p.write_text("\n".join(line for line in p.read_text().splitlines() if "TODO (lab" not in line) + "\n")
    tree = build_student_tree(load_config(STEP01), sub, tmp_path / "tree")
    assert tree.stubs[MEMORY_CU] == ["place_ray_shared"]
    assert set(tree.stubs[MEMORY_H]) == {f for lf in load_config(STEP01).files if lf.path == MEMORY_H
                                         for f in lf.functions}


FETCH, SHARED_RAY = "texture", "shared"
PTX_FORMS = {
    # legitimate forms: pass
    "int4 fetch, its xy": (FETCH, MEMORY_H, "fetch_int2_texture",
                           "    int4 v = tex1Dfetch<int4>(tex, i);\n    return make_int2(v.x, v.y);", None),
    "index arithmetic": (FETCH, MEMORY_H, "fetch_float4_texture",
                         "    int j = (i * 2) / 2;\n    return tex1Dfetch<float4>(tex, j);", None),
    "slot through a pointer": (SHARED_RAY, MEMORY_CU, "place_ray_shared",
                               "    Ray *s = slots + lane;\n    *s = ray;\n    return s;", None),
    "field by field": (SHARED_RAY, MEMORY_CU, "place_ray_shared",
                       "    slots[lane].o = ray.o;\n    slots[lane].d = ray.d;\n    slots[lane].inv_d = ray.inv_d;\n"
                       "    slots[lane].tmin = ray.tmin;\n    slots[lane].tmax = ray.tmax;\n    return &slots[lane];", None),
    "make_ray again": (SHARED_RAY, MEMORY_CU, "place_ray_shared",
                       "    slots[lane] = make_ray(ray.o, ray.d, ray.tmin, ray.tmax);\n    return &slots[lane];", None),
    # forged: fail, each with its message
    "element 0": (
        FETCH, MEMORY_H, "fetch_int_texture", "    return tex1Dfetch<int>(tex, 0);",
        r"for objects \(fetch_int_texture\), element \d+: stores \(objects\[0\]\.x, 0, 0, 0\) where the reference "
        r"stores \(objects\[\d+\]\.x, 0, 0, 0\): fetch_int_texture must return element i"),
    "half an int2": (
        FETCH, MEMORY_H, "fetch_int2_texture", "    int4 v = tex1Dfetch<int4>(tex, i);\n    return make_int2(v.x, 0);",
        r"for nodes \(fetch_int2_texture\), element (\d+): stores \(nodes\[\1\]\.x, 0, 0, 0\) where the reference "
        r"stores \(nodes\[\1\]\.x, nodes\[\1\]\.y, 0, 0\)"),
    "element i + 1": (
        FETCH, MEMORY_H, "fetch_float4_texture", "    return tex1Dfetch<float4>(tex, i + 1);",
        r"for node_data \(fetch_float4_texture\), element 5: stores \(node_data\[6\]\.x, node_data\[6\]\.y, "
        r"node_data\[6\]\.z, node_data\[6\]\.w\) where the reference stores \(node_data\[5\]\.x"),
    "low bits of i": (
        FETCH, MEMORY_H, "fetch_int_texture", "    return tex1Dfetch<int>(tex, i & 1023);",
        r"element 262143: stores \(objects\[1023\]\.x, 0, 0, 0\) where the reference stores \(objects\[262143\]\.x"),
    "branch on what it read": (
        FETCH, MEMORY_H, "fetch_int_texture",
        "    int v = tex1Dfetch<int>(tex, 0);\n    if (v == 12345)\n        return tex1Dfetch<int>(tex, i & 1);\n"
        "    return v;",
        r"fetch_scene's PTX could not be followed \('bra' depends on a value it read"),
    "constant direction": (
        SHARED_RAY, MEMORY_CU, "place_ray_shared",
        "    slots[lane] = make_ray(ray.o, f3(0.0f, 0.0f, 1.0f), ray.tmin, ray.tmax);\n    return &slots[lane];",
        r"render_primary: place_ray_shared stores 3 of the slot's fields from the kernel's ray \(its origin and "
        r"direction\) where the reference stores 9: bytes 12, 16, 20, 24, 28, 32 of the slot get no value"),
    "the thread's index": (
        SHARED_RAY, MEMORY_CU, "place_ray_shared",
        "    float l = (float)lane;\n    slots[lane] = make_ray(f3(l, l + 1.0f, l + 2.0f), f3(l + 3.0f, 1.0f, 2.0f), "
        "0.0f, 1e30f);\n    return &slots[lane];",
        r"render_primary: place_ray_shared stores 0 of the slot's fields from the kernel's ray"),
    "origin twice": (
        SHARED_RAY, MEMORY_CU, "place_ray_shared",
        "    slots[lane] = make_ray(ray.o, ray.o, ray.tmin, ray.tmax);\n    return &slots[lane];",
        r"render_primary: .* only 6 distinct values of the ray reach the slot, the reference's 9"),
    "the stub, tmax changed": (
        SHARED_RAY, MEMORY_CU, "place_ray_shared",
        "    slots[lane] = make_ray(f3(0.0f, 0.0f, 0.0f), f3(0.0f, 0.0f, 1.0f), 0.0f, 1.0f);\n    return &slots[lane];",
        r"render_primary: place_ray_shared stores 0 of the slot's fields"),
}


def _ptx_facts(kernels_root: Path, placement: str) -> dict:
    from rtlab.backends.nvcc import nvcc_ptx
    from rtlab.course.checks.nvcc import ptx_facts
    from rtlab.device.kernels import SceneFeatures, build_defines, build_options
    from rtlab.device.variants import Variant
    variant = Variant.paper(node_memory="texture") if placement == FETCH else Variant.paper(ray_memory="shared")
    ptx = nvcc_ptx(kernels_root / "cuda" / f"{STEP01}.cu", build_defines(variant, SceneFeatures()),
                   extra_options=build_options(variant, "cuda"))
    return ptx_facts(ptx, variant.node_memory, variant.ray_memory)


@pytest.mark.skipif(not nvcc_available(), reason="no nvcc (the CUDA toolkit) on PATH")
@pytest.mark.parametrize("form", list(PTX_FORMS))
def test_nvcc_checks_read_the_ptx(form, tmp_path):
    from rtlab.course.checks.nvcc import SHARED_RAY_KERNELS, fetch_problems, shared_problems
    placement, rel, function, body, message = PTX_FORMS[form]
    ref = _ptx_facts(PROJECT_DIR / "kernels", placement)
    shutil.copytree(PROJECT_DIR / "kernels", tmp_path / "kernels")
    replace_body(tmp_path / rel, function, body)
    got = _ptx_facts(tmp_path / "kernels", placement)
    if placement == FETCH:
        problems = fetch_problems(got["fetch_followed"], ref["fetch_followed"])
    else:
        problems = [p for k in SHARED_RAY_KERNELS
                    for p in shared_problems(k, got["shared_stores"][k], ref["shared_stores"][k])]
    if message is None:
        assert problems == [], problems
    else:
        assert problems and re.search(message, problems[0]), problems


@pytest.mark.skipif(not nvcc_available(), reason="no nvcc (the CUDA toolkit) on PATH")
def test_lab01_nvcc_tests_fail_a_stub_without_its_todo_and_wrong_fetches(tmp_path):
    """The template with place_ray_shared's TODO and STUB lines deleted, and texture fetches of element 0
    and of half an int2: 0 on the nvcc tests, saying why; the reference keeps full marks."""
    tests = ["cuda_textures", "cuda_shared_ray"]
    sub = tmp_path / "forged"
    write_template(STEP01, sub)
    cu = sub / MEMORY_CU
    cu.write_text("\n".join(line for line in cu.read_text().splitlines()
                            if "TODO (lab" not in line and "STUB:" not in line) + "\n")
    h = sub / MEMORY_H
    for function, body in (("fetch_int2_texture", "    int4 v = tex1Dfetch<int4>(tex, 0);\n    return make_int2(v.x, 0);"),
                           ("fetch_float4_texture", "    return tex1Dfetch<float4>(tex, 0);"),
                           ("fetch_int_texture", "    return tex1Dfetch<int>(tex, 0);")):
        replace_body(h, function, body)
    report = grade(STEP01, sub, tests=tests)
    assert report.score == 0, [(t.name, t.output) for t in report.tests]
    tex, ray = report.test("cuda_textures"), report.test("cuda_shared_ray")
    assert re.search(r"followed through its PTX for nodes \(fetch_int2_texture\), element \d+: stores "
                     r"\(nodes\[0\]\.x, 0, 0, 0\)", tex.output), tex.output
    assert "place_ray_shared still holds the template's stub" in ray.output, ray.output
    assert "render_primary: place_ray_shared stores" in ray.output and "trace_rays: place_ray_shared stores" \
        in ray.output, ray.output
    ref = grade(STEP01, reference_files(STEP01, tmp_path / "ref"), tests=tests)
    assert ref.score == ref.max_score == 30, [(t.name, t.output) for t in ref.tests]


def test_lab03_template_still_compiles_its_stubs_are_not_refused(tmp_path):
    """The template's packet stub writes no local memory, but a stub is no forged packet: the structure
    rule leaves the template's stubs to their own tests (they fail as stubs), and the compile test,
    which builds the packet traversal, passes."""
    write_template(STEP03, tmp_path / "tmpl")
    report = grade(STEP03, tmp_path / "tmpl", tests=["compile", "trace_packet", "trace_restart"])
    assert report.test("compile").passed, report.test("compile").output
    for name in ("trace_packet", "trace_restart"):
        t = report.test(name)
        assert t.status == "failed" and "keeps" not in t.output and "template's stub" in t.output, (name, t.output)


@pytest.mark.parametrize("guard", [
    "sizeof(MY_XSTR(POCL_DEVICE_ADDRESS_BITS)) < 8",       # "64" under PoCL, the name itself under the rules' clang
    "__CLANG_ATOMIC_LLONG_LOCK_FREE == 2",                   # 2 under PoCL, 1 there: no # operator, no directive
    "sizeof(MY_XSTR(LLVM_15_0)) == 1",                       # PoCL's own _kernel.h defines it empty
    "__AVX__ == 1"])                                         # a CPU macro the kernels use (rt_lanes.h)
def test_code_behind_a_value_the_two_compilers_disagree_on_is_seen(guard, tmp_path):
    """A constant condition on a macro whose value differs between the clang that reads
    the code for the rules and PoCL's compile is folded away, with lab 00's walk behind it, where PoCL
    runs it (lab 00's walk in lab 03 with no traversal written; PoCL's own LLVM_15_0 too). The
    # operator, and the runtime's and reserved names the kernels do not use, are refused as text; a CPU
    macro the kernels use has PoCL's value in the rules' clang (-march=native), so the copied walk
    behind it is seen and refused."""
    sub = reference_files(STEP03, tmp_path / "sub")
    path = sub / SHARED / FILES["traverse_kd_restart"]
    replace_body(path, "traverse_kd_restart", f"    if ({guard}) {{\n{COPIED_STACK}\n    }}\n    return;",
                 "#define MY_STR(x) #x\n#define MY_XSTR(x) MY_STR(x)\n" if "MY_XSTR" in guard else "")
    t = grade(STEP03, sub, tests=["trace_restart"]).test("trace_restart")
    assert t.score == 0, t.output
    if "MY_XSTR" in guard:
        assert "the # operator (a macro argument made a string) is not allowed" in t.output, t.output
    elif "LOCK" in guard:
        assert "__CLANG_ATOMIC_LLONG_LOCK_FREE is a name the compiler or the OpenCL runtime provides" in t.output
    else:
        assert "traverse_kd_restart keeps a per-ray private array stack" in t.output, t.output


def test_a_call_behind_pocls_empty_inline_is_seen(tmp_path):
    """PoCL compiles every kernel with -Dinline=, and a macro that tests for an empty
    argument (no # operator, no reserved name) folded lab 00's walk away in the rules' clang, where
    `inline` was still a keyword (5 / 5 on trace_restart). The rules' clang now gets PoCL's -Dinline=."""
    sub = reference_files(STEP03, tmp_path / "sub")
    probe = ("#define RESTART_PROBE() ~, 1\n#define RESTART_SECOND(a, b, rest...) b\n"
             "#define RESTART_CHECK(args...) RESTART_SECOND(args, 0, 0)\n"
             "#define RESTART_EMPTY(x) RESTART_CHECK(RESTART_PROBE x ())\n")
    replace_body(sub / SHARED / FILES["traverse_kd_restart"], "traverse_kd_restart",
                 "    if (RESTART_EMPTY(inline))\n        traverse_kd_stack(RT_SCENE_ARGS, scene_min, scene_max, ray, hit, "
                 "any_hit);\n    return;", probe)
    t = grade(STEP03, sub, tests=["trace_restart"]).test("trace_restart")
    assert t.score == 0 and "traverse_kd_restart calls traverse_kd_stack" in t.output, t.output


# --------------------------------------------------------------------------------------------------
# what PoCL's own headers still do to the one text, overloads, and a kept TODO line
# --------------------------------------------------------------------------------------------------
WALK_PARAMS = "RT_SCENE_PARAMS, float4 lo, float4 hi, const Ray *ray"
RENAMED_BUILTIN = (f"__attribute__((overloadable)) void sin({WALK_PARAMS}, const Hit *hit, int any_hit) {{ }}\n"
                   f"__attribute__((overloadable)) void _cl_sin({WALK_PARAMS}, Hit *hit, int any_hit)\n"
                   "{ traverse_kd_stack(RT_SCENE_ARGS, lo, hi, ray, hit, any_hit); }\n")
TAGGED_OVERLOAD = ("typedef struct { int unused; } MyWalkTag;\n"
                   f"__attribute__((overloadable)) void intersect_ray_tri_watertight(MyWalkTag tag, {WALK_PARAMS}, "
                   "Hit *hit, int any_hit)\n{\n" + COPIED_STACK.replace("scene_min", "lo").replace("scene_max", "hi")
                   + "\n}\n")


UCN_HELPER = (f"RT_FN void r\\u00e9start({WALK_PARAMS}, Hit *hit, int any_hit)\n"
              "{ traverse_kd_stack(RT_SCENE_ARGS, lo, hi, ray, hit, any_hit); }\n")
DECOY_STUB = ("#if 0\nRT_FN void traverse_kd_restart(void)\n{\n    /* BEGIN SOLUTION */\n    return;\n"
              "    /* END SOLUTION */\n}\n#endif\n")


SLOTS = 64
SWITCH_SLOTS = ("typedef struct {\n" + "".join(f"    KdStackEntry e{i};\n" for i in range(SLOTS)) + "} MySlots;\n"
                "RT_FN KdStackEntry *my_slot(MySlots *s, int i)\n{\n    switch (i) {\n"
                + "".join(f"    case {i}: return &s->e{i};\n" for i in range(1, SLOTS)) + "    }\n    return &s->e0;\n}\n")
SWITCH_WALK = re.sub(r"stack\[([^\]]+)\]\.", r"my_slot(&stack, \1)->",
                     COPIED_STACK.replace("KdStackEntry stack[RT_STACK_SIZE];", "MySlots stack;"))


TERNARY_SLOTS = SWITCH_SLOTS.split("RT_FN KdStackEntry *my_slot")[0] + (
    "RT_FN KdStackEntry *my_slot(MySlots *s, int i)\n{\n    return "
    + " ".join(f"i == {i} ? &s->e{i} :" for i in range(SLOTS - 1)) + f" &s->e{SLOTS - 1};\n}}\n")
COPY_SLOTS = SWITCH_SLOTS.split("RT_FN KdStackEntry *my_slot")[0] + (
    "RT_FN void slot_put(MySlots *s, int i, KdStackEntry v)\n{\n    switch (i) {\n"
    + "".join(f"    case {i}: s->e{i} = v; break;\n" for i in range(SLOTS)) + "    }\n}\n"
    "RT_FN KdStackEntry slot_get(MySlots *s, int i)\n{\n    KdStackEntry v = s->e0;\n    switch (i) {\n"
    + "".join(f"    case {i}: v = s->e{i}; break;\n" for i in range(1, SLOTS)) + "    }\n    return v;\n}\n")
COPY_WALK = (COPIED_STACK.replace("KdStackEntry stack[RT_STACK_SIZE];", "MySlots stack;\n    KdStackEntry top;")
             .replace("stack[sp].node = second;", "top.node = second;")
             .replace("stack[sp].tmin = entry_tmin;", "top.tmin = entry_tmin;")
             .replace("stack[sp].tmax = tmax;", "top.tmax = tmax;")
             .replace("stack[sp].t_stop = sp > 0 ? rt_min(entry_tmin, stack[sp - 1].t_stop) : entry_tmin;",
                      "top.t_stop = sp > 0 ? rt_min(entry_tmin, slot_get(&stack, sp - 1).t_stop) : entry_tmin;\n"
                      "                slot_put(&stack, sp, top);")
             .replace("stack[sp - 1].t_stop", "slot_get(&stack, sp - 1).t_stop")
             .replace("node = stack[sp].node;", "top = slot_get(&stack, sp);\n        node = top.node;")
             .replace("tmin = stack[sp].tmin;", "tmin = top.tmin;").replace("tmax = stack[sp].tmax;", "tmax = top.tmax;"))


SEPARATE_SLOTS = ("#define MY_PUT(i, v) switch (i) { " + " ".join(f"case {i}: e{i} = (v); break;" for i in range(SLOTS))
                  + " }\n#define MY_GET(i, v) switch (i) { " + " ".join(f"case {i}: (v) = e{i}; break;" for i in range(SLOTS))
                  + " }\n")
SEPARATE_WALK = (COPIED_STACK
                 .replace("KdStackEntry stack[RT_STACK_SIZE];",
                          "KdStackEntry " + ", ".join(f"e{i}" for i in range(SLOTS)) + ", top, below;")
                 .replace("stack[sp].node = second;", "top.node = second;")
                 .replace("stack[sp].tmin = entry_tmin;", "top.tmin = entry_tmin;")
                 .replace("stack[sp].tmax = tmax;", "top.tmax = tmax;\n                if (sp > 0) { MY_GET(sp - 1, below) }")
                 .replace("stack[sp].t_stop = sp > 0 ? rt_min(entry_tmin, stack[sp - 1].t_stop) : entry_tmin;",
                          "top.t_stop = sp > 0 ? rt_min(entry_tmin, below.t_stop) : entry_tmin;\n"
                          "                MY_PUT(sp, top)")
                 .replace("        if (sp == 0 || t_cull(hit->t) < stack[sp - 1].t_stop",
                          "        if (sp > 0) { MY_GET(sp - 1, below) }\n        if (sp == 0 || t_cull(hit->t) < below.t_stop")
                 .replace("node = stack[sp].node;", "MY_GET(sp, top)\n        node = top.node;")
                 .replace("tmin = stack[sp].tmin;", "tmin = top.tmin;").replace("tmax = stack[sp].tmax;", "tmax = top.tmax;"))


@pytest.mark.parametrize("route", ["renamed_builtin", "overload", "todo_kept", "ucn_name", "decoy_stub", "switch_slots",
                                   "ternary_slots", "copied_slots", "separate_slots"])
def test_a_walk_hidden_from_the_rules_scores_nothing(route, tmp_path):
    """Lab 00's walk in kd-restart, hidden from the rules, is refused: behind an overload of ``sin`` whose
    PoCL name ``_cl_sin`` (its headers rename the built-ins; the rules' clang does not) the student
    defines too; copied into an overload of an allowed lab function (the call graph reads functions by
    source name); pasted under the template's kept TODO line (a stub is told by its code, not its
    comments); behind a helper named with a universal character name (r\\u00e9start, which clang's IR
    quotes); with a decoy stub region of the same function under #if 0; with its stack in 64 named
    slots picked by a switch or a chain of ?: (merged in a phi), moved by struct copies in a switch's
    cases, or in 64 separate locals a switch picks among."""
    sub = reference_files(STEP03, tmp_path / "sub")
    path = sub / SHARED / FILES["traverse_kd_restart"]
    if route == "renamed_builtin":
        replace_body(path, "traverse_kd_restart", "    sin(RT_SCENE_ARGS, scene_min, scene_max, ray, hit, any_hit);",
                     RENAMED_BUILTIN)
        why = "_cl_sin is a name the compiler or the OpenCL runtime provides"
    elif route == "overload":
        replace_body(path, "traverse_kd_restart", "    MyWalkTag tag;\n    intersect_ray_tri_watertight(tag, "
                     "RT_SCENE_ARGS, scene_min, scene_max, ray, hit, any_hit);", TAGGED_OVERLOAD)
        why = "intersect_ray_tri_watertight is defined as an overload (__attribute__((overloadable)))"
    elif route == "ucn_name":
        replace_body(path, "traverse_kd_restart", "    r\\u00e9start(RT_SCENE_ARGS, scene_min, scene_max, ray, hit, "
                     "any_hit);", UCN_HELPER)
        why = "a backslash outside a string or a comment"
    elif route == "decoy_stub":
        replace_body(path, "traverse_kd_restart", COPIED_STACK, DECOY_STUB)
        why = "traverse_kd_restart keeps a per-ray private array stack"
    elif route in ("ternary_slots", "copied_slots"):
        walk = SWITCH_WALK if route == "ternary_slots" else COPY_WALK
        assert "stack[" not in walk
        replace_body(path, "traverse_kd_restart", walk, TERNARY_SLOTS if route == "ternary_slots" else COPY_SLOTS)
        why = "traverse_kd_restart keeps a per-ray private array stack, MySlots indexed by a variable"
    elif route == "separate_slots":
        assert "stack[" not in SEPARATE_WALK
        replace_body(path, "traverse_kd_restart", SEPARATE_WALK, SEPARATE_SLOTS)
        why = "traverse_kd_restart keeps a per-ray private array e"
    elif route == "switch_slots":
        assert "my_slot(&stack, sp - 1)->t_stop" in SWITCH_WALK and "stack[" not in SWITCH_WALK
        replace_body(path, "traverse_kd_restart", SWITCH_WALK, SWITCH_SLOTS)
        why = "traverse_kd_restart keeps a per-ray private array stack, MySlots indexed by a variable"
    else:
        todo = "    /* TODO (lab 03_traversal): write traverse_kd_restart here; labs/03_traversal/README.md says. */\n"
        replace_body(path, "traverse_kd_restart", todo + COPIED_STACK)
        why = "traverse_kd_restart keeps a per-ray private array stack"
    t = grade(STEP03, sub, tests=["trace_restart"]).test("trace_restart")
    assert t.score == 0 and why in t.output, t.output


def test_the_ir_readers_read_quoted_symbols_and_refuse_what_they_cannot_read():
    from rtlab.course.lab_calls import ir_call_graph, unread_definitions
    ir = ('define void @"r\\C3\\A9start"(ptr %a) {\nentry:\n  call void @traverse_kd_stack(ptr %a)\n  ret void\n}\n'
          'define void @traverse_kd_restart(ptr %a) {\nentry:\n  call void @"r\\C3\\A9start"(ptr %a)\n  ret void\n}\n')
    graph = ir_call_graph(ir)
    assert graph == {"r\\C3\\A9start": {"traverse_kd_stack"}, "traverse_kd_restart": {"r\\C3\\A9start"}}
    assert unread_definitions(ir) == 0
    assert unread_definitions(ir + 'define void @"bad\\ZZ"() {\n  ret void\n}\n') == 1


SLAB_CLIP = """RT_FN int my_clip(const Ray *ray, float4 lo, float4 hi, float *t0, float *t1)
{
    float o[3] = {ray->o.x, ray->o.y, ray->o.z};
    float inv[3] = {ray->inv_d.x, ray->inv_d.y, ray->inv_d.z};
    float bl[3] = {lo.x, lo.y, lo.z};
    float bh[3] = {hi.x, hi.y, hi.z};
    float d[3] = {ray->d.x, ray->d.y, ray->d.z};
    if (d[0] == 0.0f && d[1] == 0.0f && d[2] == 0.0f) return 0;
    float a = ray->tmin, b = ray->tmax;
    for (int k = 0; k < 3; ++k) {
        float n = (bl[k] - o[k]) * inv[k], f = (bh[k] - o[k]) * inv[k];
        if (n != n || f != f) continue;
        a = fmax(a, fmin(n, f));
        b = fmin(b, fmax(n, f));
    }
    *t0 = a; *t1 = b;
    return a <= b;
}
"""


STATE_CLIP = """typedef struct { float o[3], inv[3], bl[3], bh[3], d[3]; float a, b; float4 lo4, hi4; int side, planes, pass; } ClipState;
RT_FN int my_clip(const Ray *ray, float4 lo, float4 hi, float *t0, float *t1)
{
    ClipState w;
    w.o[0] = ray->o.x; w.o[1] = ray->o.y; w.o[2] = ray->o.z;
    w.inv[0] = ray->inv_d.x; w.inv[1] = ray->inv_d.y; w.inv[2] = ray->inv_d.z;
    w.bl[0] = lo.x; w.bl[1] = lo.y; w.bl[2] = lo.z;
    w.bh[0] = hi.x; w.bh[1] = hi.y; w.bh[2] = hi.z;
    w.d[0] = ray->d.x; w.d[1] = ray->d.y; w.d[2] = ray->d.z;
    w.lo4 = lo; w.hi4 = hi; w.side = 0; w.planes = 0; w.pass = 0;
    w.a = ray->tmin; w.b = ray->tmax;
    for (int k = 0; k < 3; ++k) {
        float n = (w.bl[k] - w.o[k]) * w.inv[k], f = (w.bh[k] - w.o[k]) * w.inv[k];
        if (n != n || f != f) continue;
        w.a = fmax(w.a, fmin(n, f));
        w.b = fmin(w.b, fmax(n, f));
    }
    *t0 = w.a; *t1 = w.b;
    return w.a <= w.b;
}
"""


@pytest.mark.parametrize("clip", ["arrays", "state_struct"])
def test_a_restart_with_a_slab_clip_of_per_axis_arrays_passes(clip, tmp_path):
    """A student's restart that clips with per-axis arrays indexed by the axis, in a helper of its own,
    is legitimate: five arrays (60 B, within the slack), or the same arrays inside a state struct of over
    96 B (a variable index counts the array it ranges over, not the struct)."""
    sub = reference_files(STEP03, tmp_path / "sub")
    path = sub / SHARED / FILES["traverse_kd_restart"]
    body = region_body(f"{SHARED}/{FILES['traverse_kd_restart']}", "traverse_kd_restart")
    replace_body(path, "traverse_kd_restart", "    float c0, c1;\n    if (!my_clip(ray, scene_min, scene_max, &c0, &c1))\n"
                 "        return;\n" + body, SLAB_CLIP if clip == "arrays" else STATE_CLIP)
    t = grade(STEP03, sub, tests=["trace_restart"]).test("trace_restart")
    assert t.passed, t.output
