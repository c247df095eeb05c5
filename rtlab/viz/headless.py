"""Off-screen OpenGL for pyvista (tests, notebooks, ``rtlab inspect --screenshot``): VTK draws through
EGL (Debian ``libegl1 libgl1-mesa-dri``) or OSMesa (``libosmesa6``). VTK 9.4+ wheels pick the window
class from ``$VTK_DEFAULT_OPENGL_WINDOW``; :func:`ensure_headless_gl` tries each in a subprocess first
(a machine with neither would segfault in-process) and sets it before pyvista is imported.
``$RTLAB_VTK_WINDOW`` names the class to use without probing."""
from __future__ import annotations

import os
import subprocess
import sys

from .. import settings
from ..errors import InspectError

HEADLESS_WINDOWS = ("vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow")
_PROBE = """
import vtkmodules.vtkRenderingOpenGL2  # noqa: F401  (registers the OpenGL classes)
from vtkmodules.vtkRenderingCore import vtkRenderWindow, vtkRenderer
w = vtkRenderWindow()
w.SetOffScreenRendering(1)
w.AddRenderer(vtkRenderer())
w.SetSize(8, 8)
w.Render()
print("RTLAB-GL-OK", w.GetClassName())
"""
_headless: str | None = None


def _probe_window(cls: str, timeout: float = 120.0) -> tuple[bool, str]:
    env = dict(os.environ, VTK_DEFAULT_OPENGL_WINDOW=cls)
    try:
        r = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False, f"{cls}: no answer in {timeout:g} s"
    ok = r.returncode == 0 and f"RTLAB-GL-OK {cls}" in r.stdout
    why = "" if ok else (f"{cls}: exit status {r.returncode}" +
                         (f" (signal {-r.returncode})" if r.returncode < 0 else "") +
                         (f": {r.stderr.strip().splitlines()[-1][:200]}" if r.stderr.strip() else ""))
    return ok, why


def ensure_headless_gl() -> str:
    """The VTK window class for off-screen rendering, set in $VTK_DEFAULT_OPENGL_WINDOW; raises
    InspectError (never segfaults) when neither EGL nor OSMesa works."""
    global _headless
    if _headless:
        return _headless
    chosen = settings.get("RTLAB_VTK_WINDOW")
    if not chosen:
        reasons = []
        for cls in HEADLESS_WINDOWS:
            ok, why = _probe_window(cls)
            if ok:
                chosen = cls
                break
            reasons.append(why)
        if not chosen:
            raise InspectError("no OpenGL for off-screen rendering: install EGL (apt-get install libegl1 "
                               "libgl1-mesa-dri) or OSMesa (apt-get install libosmesa6). Tried: " + "; ".join(reasons))
    os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = chosen
    settings.setenv("RTLAB_VTK_WINDOW", chosen)      # child processes (notebook kernels) skip the probe
    _headless = chosen
    return chosen


def pyvista_module(off_screen: bool):
    if off_screen:
        ensure_headless_gl()
    elif not os.environ.get("DISPLAY") and sys.platform.startswith("linux"):
        raise InspectError("no display ($DISPLAY is not set): use --screenshot out.png for an image file")
    try:
        import pyvista as pv
    except ImportError:
        raise InspectError("pyvista is not installed: pip install -e '.[viz]'") from None
    return pv
