"""The `rtlab` command: the main job works, and bad input gets one clear line and a non-zero exit."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image


def run_cli(*args, cwd=None):
    proc = subprocess.run([sys.executable, "-m", "rtlab", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600)
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
    code, out, err = run_cli("info")
    assert code == 0, err
    assert "opencl" in out and "cuda" in out


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
