"""Mesh files: binary PLY (with vertex colours) and textured Wavefront OBJ (+ MTL + PNG texture).

Coordinates are metres in the world frame (= the capture camera frame, OpenCV axes: x right, y down,
z forward), written as they are: importers that convert axes (Blender's OBJ/PLY importers offer
forward/up options) should be told so or the scene code should place the object itself.

Every file is written atomically (``rgbd2scene.atomic.atomic_path``). The OBJ writer writes the texture
and the MTL first and the OBJ last, so an OBJ on disk implies its companions are complete.
Both writers format with numpy only (no per-vertex Python loop): PLY is a header plus the bytes of one
structured array per element; OBJ text is built as a byte matrix of digits and compacted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rgbd2scene.errors import UserError
from rgbd2scene.files.atomic import atomic_path
from rgbd2scene.files.images import write_image
from rgbd2scene.geometry.mesh import Mesh

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


# --------------------------------------------------------------------------------------------- PLY


def write_ply(path: str | Path, mesh: Mesh, *, double: bool = False, uvs: bool = True,
              comment: str | None = None) -> Path:
    """Write a binary little-endian PLY: x y z (float32 metres, or float64 with ``double``), uchar
    red green blue when the mesh has vertex colours, float s t (the UVs, v up as in OBJ/Blender)
    when it has UVs and ``uvs`` is set, and the triangles as ``list uchar int vertex_indices``.
    Returns the path."""
    path = Path(path)
    v = np.asarray(mesh.vertices)
    t = np.asarray(mesh.triangles)
    if v.ndim != 2 or v.shape[1] != 3 or t.ndim != 2 or (t.size and t.shape[1] != 3):
        raise ValueError(f"write_ply: bad mesh arrays {v.shape}, {t.shape}")
    if not np.isfinite(v).all():
        raise ValueError("write_ply: vertices contain NaN or infinite values")
    n, m = len(v), len(t)
    if m and (t.min() < 0 or t.max() >= n):
        raise ValueError("write_ply: triangle index out of range")
    ftype, fname = ("<f8", "double") if double else ("<f4", "float")
    fields = [("x", ftype), ("y", ftype), ("z", ftype)]
    props = [f"property {fname} x", f"property {fname} y", f"property {fname} z"]
    colors = mesh.vertex_colors
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    uv = mesh.uvs if uvs else None
    if uv is not None:
        fields += [("s", "<f4"), ("t", "<f4")]
        props += ["property float s", "property float t"]
    vert = np.empty(n, dtype=np.dtype(fields))
    vert["x"], vert["y"], vert["z"] = v[:, 0], v[:, 1], v[:, 2]
    if colors is not None:
        c = np.asarray(colors)
        if c.dtype != np.uint8:
            raise ValueError(f"write_ply: vertex colours must be uint8, got {c.dtype}")
        vert["red"], vert["green"], vert["blue"] = c[:, 0], c[:, 1], c[:, 2]
    if uv is not None:
        vert["s"], vert["t"] = uv[:, 0], uv[:, 1]
    face = np.empty(m, dtype=np.dtype([("n", "u1"), ("i", "<i4", (3,))]))
    face["n"] = 3
    face["i"] = t
    header = ["ply", "format binary_little_endian 1.0",
              f"comment {comment or 'rgbd2scene mesh: metres, world = capture camera frame (OpenCV axes)'}",
              f"element vertex {n}", *props,
              f"element face {m}", "property list uchar int vertex_indices", "end_header"]
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as f:
            f.write(("\n".join(header) + "\n").encode("ascii"))
            f.write(vert.tobytes())
            f.write(face.tobytes())
    except OSError as exc:
        raise UserError(f"{path}: cannot write the mesh ({exc.strerror or exc})") from None
    return path


def _ply_header(data: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str | None]]]], int]:
    """(format, [(element, count, [(property, numpy type or None for lists)])], data offset)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError("not a PLY file")
    offset = data.index(b"\n", end) + 1
    fmt, elements = "", []
    for line in data[:end].decode("ascii", "replace").splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property" and elements:
            if parts[1] == "list":
                elements[-1][2].append((parts[-1], None))
            else:
                elements[-1][2].append((parts[2], _PLY_TYPES.get(parts[1])))
    return fmt, elements, offset


def _read_ply_uvs(path: Path) -> np.ndarray | None:
    """The vertex s/t (or u/v, texture_u/texture_v) of a binary little-endian PLY whose vertex element
    comes first and has scalar properties only; None otherwise."""
    with open(path, "rb") as f:
        head = f.read(65536)
    try:
        fmt, elements, offset = _ply_header(head)
    except ValueError:
        return None
    if fmt != "binary_little_endian" or not elements or elements[0][0] != "vertex":
        return None
    _, count, props = elements[0]
    if any(t is None for _, t in props):
        return None
    names = [p for p, _ in props]
    for un, vn in (("s", "t"), ("u", "v"), ("texture_u", "texture_v")):
        if un in names and vn in names:
            break
    else:
        return None
    dtype = np.dtype([(p, "<" + t) for p, t in props])
    vert = np.fromfile(path, dtype=dtype, count=count, offset=offset)
    if len(vert) != count:
        return None
    return np.stack([vert[un], vert[vn]], axis=1).astype(np.float32)


def read_ply(path: str | Path) -> Mesh:
    """Read a triangle-mesh PLY (via Open3D): vertices float64, triangles int32, vertex colours
    uint8 (None when the file has none), UVs from s/t properties where present (else None);
    pixels and texture are None."""
    import open3d as o3d

    path = Path(path)
    if not path.is_file():
        raise UserError(f"{path}: mesh file not found")
    m = o3d.io.read_triangle_mesh(str(path), enable_post_processing=False, print_progress=False)
    vertices = np.asarray(m.vertices, dtype=np.float64).copy()
    if len(vertices) == 0:
        raise UserError(f"{path}: not a readable PLY mesh (no vertices)")
    triangles = np.asarray(m.triangles).astype(np.int32)
    colors = None
    if m.has_vertex_colors():
        colors = np.clip(np.rint(np.asarray(m.vertex_colors) * 255.0), 0, 255).astype(np.uint8)
    uvs = _read_ply_uvs(path)
    if uvs is not None and len(uvs) != len(vertices):
        uvs = None
    return Mesh(vertices=vertices, triangles=triangles, vertex_colors=colors, uvs=uvs, pixels=None,
                texture=None)


# --------------------------------------------------------------------------------------------- OBJ


#: The digits of 0000-9999: row j holds every number's j-th digit (ASCII), for four digits per division by 10000
_FOUR_DIGITS = (np.arange(10000) // np.array([[1000], [100], [10], [1]]) % 10 + 48).astype(np.uint8)


def _write_digits(out: np.ndarray, values: np.ndarray, leading_zeros: bool) -> None:
    """Write the ASCII digits of non-negative integers right-aligned into ``out`` (..., width) (digits above the
    width are dropped). Leading zeros are written as ``0`` with ``leading_zeros``, else as NULs (removed when the
    text is compacted; the units digit is always written). Four digits per integer division, looked up a digit
    column at a time from contiguous arrays: a division and a byte column per digit were most of an OBJ's time."""
    values = np.asarray(values, dtype=np.int64)
    width = out.shape[-1]
    rest = values
    for end in range(width, 0, -4):
        quotient = rest // 10000
        four = rest - quotient * 10000
        for j in range(max(0, end - 4), end):
            out[..., j] = _FOUR_DIGITS[4 - (end - j)][four]
        rest = quotient
    if not leading_zeros:
        for j in range(width - 1):
            out[..., j] *= values >= 10 ** (width - 1 - j)


def _digits(values: np.ndarray, width: int) -> np.ndarray:
    """ASCII digits of non-negative integers, right-aligned in ``width`` columns with NUL padding
    (NULs are removed when the text is compacted); the units digit is always written."""
    values = np.asarray(values, dtype=np.int64)
    out = np.empty(values.shape + (width,), dtype=np.uint8)
    _write_digits(out, values, leading_zeros=False)
    return out


def _n_digits(max_value: int) -> int:
    return max(1, len(str(int(max_value))))


def _fixed(values: np.ndarray, decimals: int) -> np.ndarray:
    """(..., W) uint8 text of floats in fixed-point notation with ``decimals`` decimals, led by a
    space, NUL-padded (e.g. b" -0.12500000")."""
    x = np.asarray(values, dtype=np.float64)
    q = np.rint(np.abs(x) * 10.0**decimals).astype(np.int64)
    scale = 10**decimals
    ip = q // scale
    width = _n_digits(ip.max()) if ip.size else 1
    text = np.empty(x.shape + (2 + width + (1 + decimals if decimals > 0 else 0),), dtype=np.uint8)
    text[..., 0] = 32
    text[..., 1] = np.where((x < 0) & (q != 0), 45, 0)
    _write_digits(text[..., 2:2 + width], ip, leading_zeros=False)
    if decimals > 0:
        text[..., 2 + width] = 46
        _write_digits(text[..., 3 + width:], q - ip * scale, leading_zeros=True)  # fractional digits keep zeros
    return text


def _lines(prefix: bytes, cells: np.ndarray) -> bytes:
    """Rows of (N, k, W) cell text as lines ``prefix cell cell ...\\n`` with the NULs removed."""
    n = cells.shape[0]
    body = cells.reshape(n, -1)
    pre = np.frombuffer(prefix, dtype=np.uint8)
    block = np.empty((n, len(pre) + body.shape[1] + 1), dtype=np.uint8)
    block[:, :len(pre)] = pre
    block[:, len(pre):-1] = body
    block[:, -1] = 10
    return block[block != 0].tobytes()


def obj_text(mesh: Mesh, mtl_name: str | None = None, material: str = "material0", object_name: str = "mesh",
             decimals: int = 8, uv_decimals: int = 7) -> bytes:
    """The OBJ text of a mesh: ``v`` lines (metres, ``decimals`` places), ``vt`` lines (one per vertex,
    when the mesh has UVs), faces ``f a/a b/b c/c`` (1-based; ``f a b c`` without UVs)."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    t = np.asarray(mesh.triangles, dtype=np.int64)
    if not np.isfinite(v).all():
        raise ValueError("obj: vertices contain NaN or infinite values")
    out = [b"# rgbd2scene mesh: metres, world = capture camera frame (OpenCV axes: x right, y down, "
           b"z forward)\n"]
    if mtl_name:
        out.append(f"mtllib {mtl_name}\n".encode())
    out.append(f"o {object_name}\n".encode())
    if len(v):
        out.append(_lines(b"v", _fixed(v, decimals)))
    has_uv = mesh.uvs is not None
    if has_uv and len(v):
        out.append(_lines(b"vt", _fixed(np.asarray(mesh.uvs, dtype=np.float64), uv_decimals)))
    if mtl_name:
        out.append(f"usemtl {material}\n".encode())
    out.append(b"s off\n")
    if len(t):
        idx = t + 1
        width = _n_digits(idx.max())
        # each vertex's cell (" a/a", or " a" without UVs) once, then looked up by the faces (a vertex is in
        # about six of them)
        d = _digits(np.arange((len(v) if len(v) else idx.max()) + 1), width)
        cells = np.empty((len(d), 2 * width + 2 if has_uv else width + 1), dtype=np.uint8)
        cells[:, 0] = 32
        cells[:, 1:1 + width] = d
        if has_uv:
            cells[:, 1 + width] = 47
            cells[:, 2 + width:] = d
        out.append(_lines(b"f", cells[idx]))
    return b"".join(out)


def write_textured_obj(folder: str | Path, mesh: Mesh, name: str = "mesh") -> dict[str, Path]:
    """Write ``folder/name.obj``, ``name.mtl`` and ``name_texture.png`` (the capture image).

    One ``vt`` per vertex (u = (col+0.5)/W, v = 1-(row+0.5)/H), faces ``f a/a b/b c/c``, the MTL's
    ``map_Kd`` names the PNG. Without a texture (or UVs) the OBJ and MTL are written untextured.
    Returns the written paths by kind ("obj", "mtl", "texture").
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"{folder}: cannot create output folder ({exc.strerror})") from None
    obj_path, mtl_path = folder / f"{name}.obj", folder / f"{name}.mtl"
    tex_path = folder / f"{name}_texture.png"
    try:
        return _write_obj_files(mesh, name, obj_path, mtl_path, tex_path)
    except OSError as exc:
        raise UserError(f"{folder}: cannot write the OBJ files ({exc.strerror or exc})") from None


def _write_obj_files(mesh: Mesh, name: str, obj_path: Path, mtl_path: Path,
                     tex_path: Path) -> dict[str, Path]:
    material = f"{name}_material"
    textured = mesh.texture is not None and mesh.uvs is not None
    paths: dict[str, Path] = {}
    if textured:
        tex = np.asarray(mesh.texture)
        if tex.dtype != np.uint8 or tex.ndim != 3 or tex.shape[2] != 3:
            raise ValueError(f"obj: texture must be uint8 (H, W, 3), got {tex.dtype} {tex.shape}")
        try:
            write_image(tex_path, tex)
        except OSError:
            raise UserError(f"{tex_path}: could not write the texture PNG") from None
        paths["texture"] = tex_path
    mtl = [f"# rgbd2scene material for {name}.obj", f"newmtl {material}", "Ka 1.000 1.000 1.000",
           "Kd 1.000 1.000 1.000", "Ks 0.000 0.000 0.000", "Ns 0.0", "d 1.0", "illum 1"]
    if textured:
        mtl.append(f"map_Kd {tex_path.name}")
    with atomic_path(mtl_path) as tmp:
        tmp.write_bytes(("\n".join(mtl) + "\n").encode())
    paths["mtl"] = mtl_path
    text = obj_text(mesh, mtl_name=mtl_path.name, material=material, object_name=name)
    with atomic_path(obj_path) as tmp:
        tmp.write_bytes(text)
    paths["obj"] = obj_path
    return paths
