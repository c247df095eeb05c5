"""Write the PTX that NVIDIA's OpenCL compiler made of the library's programs for trace() on a view,
with their defines and build logs, so the two backends' code can be compared offline (ptxas, nvdisasm).

    python experiments/dump_opencl_ptx.py OUT_DIR [--views bunny/far] [--kinds primary,diffuse]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from rtlab.backends import get_backend
from rtlab.benches.rays import make_rays
from rtlab.device.tracing import trace


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out")
    ap.add_argument("--views", default="bunny/far")
    ap.add_argument("--kinds", default="primary,diffuse")
    ap.add_argument("--size", type=int, default=1024)
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    backend = get_backend("opencl", "NVIDIA")
    for view in a.views.split(","):
        for kind in a.kinds.split(","):
            batch = make_rays(view, kind, a.size, check_rays=16)
            trace(batch.scene, batch.origins, batch.directions, backend,
                  width=batch.size if kind == "primary" else None)
    for i, prog in enumerate(backend._programs.values()):
        stem = f"{i:02d}-{Path(prog.path).stem}"
        (out / f"{stem}.ptx").write_bytes(prog._program.binaries[0])
        (out / f"{stem}.json").write_text(json.dumps({"path": str(prog.path), "defines": prog.defines,
                                                      "log": prog.build_log}, indent=1, default=str))
        print(stem, prog.path, len(prog._program.binaries[0]), "bytes of PTX")


if __name__ == "__main__":
    main()
