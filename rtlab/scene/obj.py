"""OBJ and MTL details trimesh does not give exactly: an MTL's materials as exact floats, an OBJ's
material libraries and ``usemtl`` groups, and the line of a face or vertex trimesh cannot read (a
face referring to a vertex that does not exist, or to vertex 0, which trimesh reads as another)."""
from __future__ import annotations

import re
from pathlib import Path

from rtlab.scene.model import Material


def _mtl_floats(values: list[str]) -> tuple[float, float, float] | None:
    try:
        numbers = [float(x) for x in values[:3]]
    except ValueError:  # "Kd spectral file.rfl" and similar: not supported, keep the default
        return None
    if len(numbers) == 1:
        numbers *= 3
    return tuple(numbers) if len(numbers) == 3 else None


def parse_mtl(path: Path) -> dict[str, Material]:
    """Materials of an MTL file, as exact floats (trimesh's materials round colours to 8 bits)."""
    materials: dict[str, Material] = {}
    current: Material | None = None
    dissolve_seen = False
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines():
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        key, values = parts[0], parts[1:]
        if key == "newmtl":
            current = Material(name=" ".join(values))
            materials[current.name] = current
            dissolve_seen = False
        elif current is None or not values:
            continue
        elif key in ("Kd", "Ks") and (rgb := _mtl_floats(values)) is not None:
            setattr(current, "diffuse" if key == "Kd" else "specular", rgb)
        elif key == "Ns":
            current.shininess = float(values[0])
        elif key == "d" and values[0] != "-halo":
            current.transparency = 1.0 - float(values[0])
            dissolve_seen = True
        elif key == "Tr" and not dissolve_seen:  # d wins where a file has both
            current.transparency = float(values[0])
        elif key == "Ni":
            current.ior = float(values[0])
    return materials


def obj_directives(data: bytes, keyword: bytes) -> list[str]:
    pattern = rb"^[ \t]*" + keyword + rb"[ \t]+(.+?)[ \t]*\r?$"
    return [m.group(1).decode("utf-8", "replace") for m in re.finditer(pattern, data, re.MULTILINE)]


def obj_material_libraries(path: Path, data: bytes) -> list[Path]:
    libraries = []
    for entry in obj_directives(data, b"mtllib"):
        candidates = [entry] + entry.split()  # one name with spaces, or several names
        found = next((path.parent / c for c in candidates if (path.parent / c).is_file()), None)
        libraries.append(found if found else path.parent / entry)
    return libraries


# A face corner whose vertex index is 0 (or -0): one regex over the file, a fraction of trimesh's parse
_ZERO_CORNER = re.compile(rb"^[ \t]*f[ \t](?:[^\r\n]*?[ \t])?[-+]?0+(?=[/ \t\r\n]|$)", re.MULTILINE)


def obj_has_zero_index(data: bytes) -> bool:
    """Whether a face of the OBJ text refers to vertex 0: not an OBJ index (they start at 1, or at -1
    from the end), which trimesh reads as another vertex without a word (first_bad_obj_face says where)."""
    return _ZERO_CORNER.search(data) is not None


def first_bad_obj_face(path: Path) -> str | None:
    """Where an OBJ file has a vertex without three coordinates, or a face corner that cannot be read
    or refers to a vertex that does not exist (only run after a failed parse, or obj_has_zero_index)."""
    n_vertices = 0
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    n_total = sum(1 for line in lines if line.startswith("v "))
    for line_no, line in enumerate(lines, 1):
        if line.startswith("v "):
            n_vertices += 1
            if len(line.split("#", 1)[0].split()) < 4:
                return f"line {line_no}: vertex {line.strip()!r} has fewer than 3 coordinates (x, y and z)"
        elif line.startswith("f "):
            for token in line.split()[1:]:
                try:
                    index = int(token.split("/")[0])
                except ValueError:
                    return f"line {line_no}: cannot read face corner {token!r}"
                if index == 0:
                    return f"line {line_no}: face corner {token!r} refers to vertex 0; OBJ indices start at 1"
                resolved = index - 1 if index > 0 else n_vertices + index
                if not 0 <= resolved < n_total:
                    return (f"line {line_no}: face refers to vertex {index}, but the file has "
                            f"{n_total} vertices (valid: 1..{n_total})")
    return None
