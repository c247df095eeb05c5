"""The `rtlab` command: the main job works, and bad input gets one clear line and a non-zero exit."""
from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image


def run_cli(*args, cwd=None, env=None):
    proc = subprocess.run([sys.executable, "-m", "rtlab", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600, env={**os.environ, **(env or {})})
    return proc.returncode, proc.stdout, proc.stderr


def assert_clear_error(code, out, err, *needles):
    assert code != 0
    assert "Traceback" not in err and "Traceback" not in out, err
    text = " ".join((out + err).split())
    for n in needles:
        assert n in text, text


def test_render_default_scene_writes_png(tmp_path):
    out = tmp_path / "img.png"
    code, stdout, err = run_cli("render", "--size", "64", "--repeats", "1", "--out", out, "--check")
    assert code == 0, err
    img = np.asarray(Image.open(out))
    assert img.shape == (64, 64, 3) and img.std() > 10
    assert "Mrays/s" in stdout and "0 mismatches" in " ".join(stdout.split())


def test_info_lists_backends():
    """Each backend's row says what backend_status says: its devices as ok, or why it is unavailable
    (in a terminal wide enough that rich does not fold the cells); then the lab steps."""
    from rtlab.backends import backend_status
    from rtlab.device.kernels import lab_steps
    code, out, err = run_cli("info", env={"COLUMNS": "500"})
    assert code == 0, err
    cells = [[c.strip() for c in line.split("│")[1:-1]] for line in out.splitlines() if line.startswith("│")]
    for row in backend_status():
        shown = next((c for c in cells if c[:2] == [row["backend"], row["id"]]), None)
        assert shown is not None, f"no row for {row['backend']} {row['id']}:\n{out}"
        assert shown[3] == row["device"] and shown[4] == ("ok" if row["ok"] else row["why"]), shown
    assert f"lab steps with kernels: {', '.join(lab_steps())}" in out


def test_build_prints_table2_row():
    code, out, err = run_cli("build", "default")
    assert code == 0, err
    for col in ("#triangles", "#nodes", "#links"):
        assert col in out


@pytest.mark.parametrize("args, needles", [
    (("render", "no_such_scene"), ["unknown scene", "no_such_scene"]),
    (("render", "--backend", "vulkan"), ["unknown backend", "vulkan"]),
    (("render", "--backend", "opencl", "--device", "no-such-device"), ["no OpenCL device matches", "no-such-device"]),
    (("render", "--traversal", "zigzag", "--size", "16"), ["unknown traversal", "zigzag"]),
    (("render", "--block", "32by4"), ["--block"]),
])
def test_bad_arguments(args, needles):
    assert_clear_error(*run_cli(*args), *needles)


def _write_ply(path, vertices, faces):
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x",
             "property float y", "property float z", f"element face {len(faces)}",
             "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(map(str, v)) for v in vertices]
    lines += ["3 " + " ".join(map(str, f)) for f in faces]
    path.write_text("\n".join(lines) + "\n")


def test_bad_meshes(tmp_path):
    missing = tmp_path / "missing.ply"
    assert_clear_error(*run_cli("render", missing), "missing.ply")

    empty = tmp_path / "empty.ply"
    _write_ply(empty, [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [])
    assert_clear_error(*run_cli("render", empty), "empty.ply")

    nan = tmp_path / "nan.ply"
    _write_ply(nan, [[0, 0, 0], [1, "nan", 0], [0, 1, 0]], [[0, 1, 2]])
    assert_clear_error(*run_cli("render", nan), "nan.ply", "NaN")

    flat = tmp_path / "degenerate.ply"
    _write_ply(flat, [[0, 0, 0], [1, 1, 1], [2, 2, 2]], [[0, 1, 2], [0, 0, 1]])
    assert_clear_error(*run_cli("render", flat), "degenerate.ply")

    garbage = tmp_path / "garbage.obj"
    garbage.write_text("this is not an obj file\nf 1 2 x\n")
    assert_clear_error(*run_cli("render", garbage), "garbage.obj")


def test_bench_markdown_names_the_command_it_ran(tmp_path):
    """--md writes the command that made the table: the arguments main() was given (options and
    flags as typed, defaults left out), not the process's sys.argv (pytest's here)."""
    import shlex
    from rtlab.cli import main
    md = tmp_path / "primary.md"
    args = ["bench", "primary", "--scenes", "default", "--backends", "opencl", "--size", "16", "--repeats", "1",
            "--no-check", "--md", str(md)]
    assert main(args) == 0
    assert f"Command: `rtlab {shlex.join(args)}`" in md.read_text()


def test_render_says_what_it_did_not_check_or_use(tmp_path):
    """Without --check the time stood alone, as if there were no error to show; Whitted options given
    to a primary render were dropped without a word."""
    code, out, err = run_cli("render", "--size", "8", "--repeats", "1", "--materials", "paper", "--compact",
                             "--out", tmp_path / "r.png")
    assert code == 0, err
    text = " ".join(out.split())
    assert "per launch; error: not checked (--check)" in text, text
    assert "warning: --materials paper, --compact have no effect without --shadows or --bounces" in text, text
    assert text.index("error: not checked") < text.index("wrote")


def test_mesh_warnings_are_one_line_each(tmp_path):
    """A missing MTL and zero-area triangles went to an INFO log no handler printed: now one line each."""
    mesh = tmp_path / "some.obj"
    mesh.write_text("mtllib missing.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n")
    code, out, err = run_cli("render", mesh, "--size", "8", "--repeats", "1", "--out", tmp_path / "r.png")
    assert code == 0, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert lines == [f"warning: {mesh}: material library {tmp_path / 'missing.mtl'} not found; using default materials",
                     f"warning: {mesh}: 1 of 2 triangles have zero area (first: triangle 1); kept as they are"], err


def test_kernel_dir_from_the_environment_is_checked_as_kernels_is(tmp_path):
    """$RTLAB_KERNEL_DIR naming a missing or partial folder was summed up as "no template stubs, every
    lab function is written", then a missing program; one naming a folder that is not UTF-8 crashed in
    pyopencl's build. Now the one-line error --kernels gives."""
    partial = tmp_path / "partial"
    (partial / "shared").mkdir(parents=True)
    for folder in (tmp_path / "missing", partial):
        code, out, err = run_cli("render", "--size", "8", env={"RTLAB_KERNEL_DIR": str(folder)})
        assert_clear_error(code, out, err, f"{folder} (from $RTLAB_KERNEL_DIR) is not a folder of kernel sources")
        assert "every lab function is written" not in out
    code, out, err = run_cli("render", "--size", "8", env={"RTLAB_KERNEL_DIR": os.fsdecode(b"/tmp/sub\xe9")})
    assert_clear_error(code, out, err, "/tmp/sub\\xe9 (from $RTLAB_KERNEL_DIR): file names must be UTF-8")


def test_whitted_renders_name_the_stubs_they_call(tmp_path):
    """A primary render names the stubs its kernel calls; a Whitted render gave only the tree's list
    (cut before the shadow functions). The summary comes before the scene is read (none here)."""
    from rtlab.course.kernel_sources import copy_stubbed, reference_kernels
    stubbed = tmp_path / "kernels"
    copy_stubbed(reference_kernels(), stubbed, None)
    for mode in (["--shadows", "one-pass"], ["--bounces", "1"], ["--bounces", "1", "--schedule", "wavefront"]):
        code, out, err = run_cli("render", "no_such_scene", "--kernels", stubbed, "--traversal", "stack",
                                 "--isect", "moller", *mode)
        text = " ".join(out.split())
        assert "warning: this stack/moller/" in text and "still a stub" in text, f"{mode}: {text}"
        assert_clear_error(code, out, err, "no_such_scene")
