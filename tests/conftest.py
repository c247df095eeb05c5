"""Shared fixtures: backends over the available devices, scene files that must exist in CI."""
from __future__ import annotations

import os

import pytest

IN_CI = os.environ.get("CI", "").lower() == "true"


def require_scene_file(relpath: str):
    """Path of a scene file under the scene directories. Missing: a failure in CI (CI=true has
    ../shared/scenes), a skip with the reason elsewhere."""
    from rtlab.paths import find_scene_file, scene_search_dirs
    path = find_scene_file(relpath)
    if path is None:
        msg = f"scene file {relpath} not found in {', '.join(map(str, scene_search_dirs()))}"
        if IN_CI:
            pytest.fail(msg)
        pytest.skip(msg)
    return path


def _available_backends() -> list[tuple[str, str | None]]:
    """(backend, device) pairs to run backend tests on: every OpenCL device (PoCL in CI), and CUDA
    when a driver works. $RTLAB_TEST_BACKENDS narrows it: comma-separated 'backend' or
    'backend:device-name-part', e.g. 'cuda,opencl:NVIDIA'."""
    from rtlab.backends import backend_status
    want = [w.split(":", 1) for w in os.environ.get("RTLAB_TEST_BACKENDS", "").split(",") if w]
    out = []
    for row in backend_status():
        if not row["ok"]:
            continue
        if want and not any(w[0] == row["backend"] and (len(w) == 1 or w[1].lower() in row["device"].lower())
                            for w in want):
            continue
        out.append((row["backend"], row["id"]))
    return out


def pytest_generate_tests(metafunc):
    if "backend" in metafunc.fixturenames:
        pairs = _available_backends()
        ids = [f"{b}-{d}" for b, d in pairs]
        metafunc.parametrize("backend", pairs or [None], ids=ids or ["none"], indirect=True, scope="session")


@pytest.fixture(scope="session")
def backend(request):
    from rtlab.backends import get_backend
    if request.param is None:
        pytest.fail("no OpenCL or CUDA device available: install PoCL (apt-get install pocl-opencl-icd)")
    name, device = request.param
    return get_backend(name, device)


def pytest_collection_modifyitems(config, items):
    """GPU tests run only where a GPU backend works."""
    from rtlab.backends import backend_status
    has_gpu = any(r["ok"] and (r["backend"] == "cuda" or "NVIDIA" in r["platform"]) for r in backend_status())
    if has_gpu:
        return
    skip = pytest.mark.skip(reason="needs an NVIDIA GPU (CUDA or NVIDIA OpenCL)")
    for item in items:
        if "gpu" in item.keywords:
            item.add_marker(skip)
