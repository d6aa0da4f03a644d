"""Triangle meshes: the validated container every stage consumes (:class:`TriangleMesh`), file loading through
trimesh (:func:`load_mesh`), transforms (:func:`transform_matrix`, CONVENTIONS.md) and the in-process LRU cache that
loads and generates each mesh once for repeated renders (:func:`cached_mesh`).
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import struct
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import InputFileError

SUPPORTED_EXTENSIONS = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
#: The largest mesh file :func:`load_mesh` reads (bytes): trimesh holds it and its arrays in memory.
MAX_MESH_FILE_BYTES = 2 * 2**30
#: The largest |coordinate| of a mesh vertex, in the file and once placed (scene units): the kernels take float32 cross
#: products of edges (up to 2e8 long) and their squared lengths, 192 x (1e8)^4 ~ 2e34, which must stay below float32's
#: 3.4e38 (at 1e10 they overflow and every normal is lost); 100 times the bound of the config's own lengths (MAX_COORD).
MAX_MESH_COORD = 1.0e8
#: Text formats: read as UTF-8, or Latin-1 where it is not UTF-8.
_TEXT_FORMATS = (".obj", ".off", ".gltf")


class MeshLoadError(InputFileError):
    """A mesh file could not be read or holds no valid triangles (an InputFileError: CLI exit code 2)."""



def geometry_digest(vertices, triangles) -> str:
    """SHA-256 (hex) of a mesh as float32 vertices and int32 triangles, so a render refuses another mesh's CSM."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(np.asarray(vertices, np.float32)).tobytes())
    h.update(np.ascontiguousarray(np.asarray(triangles, np.int32)).tobytes())
    return h.hexdigest()


@dataclass
class TriangleMesh:
    """An indexed triangle mesh in scene units (+Y up): ``vertices`` (N, 3) float32 within +-:data:`MAX_MESH_COORD`,
    ``triangles`` (T, 3) int32, counter-clockwise about the normal (v1 - v0) x (v2 - v0). Raises ValueError on invalid
    input."""

    vertices: np.ndarray
    triangles: np.ndarray

    def __post_init__(self):
        v = np.asarray(self.vertices)
        t = np.asarray(self.triangles)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"vertices must have shape (N, 3), got {v.shape}")
        if t.ndim != 2 or t.shape[1] != 3:
            raise ValueError(f"triangles must have shape (T, 3), got {t.shape}")
        if t.shape[0] < 1:
            raise ValueError("triangles must hold at least one triangle")
        if not np.issubdtype(t.dtype, np.integer):
            if not np.issubdtype(t.dtype, np.floating) or not np.all(t == np.round(t)):
                raise ValueError(f"triangles must hold integer indices, got dtype {t.dtype}")
        v = np.ascontiguousarray(v, dtype=np.float32)
        if not np.all(np.isfinite(v)):
            bad = int(np.argwhere(~np.isfinite(v).all(axis=1))[0, 0])
            raise ValueError(f"vertices must be finite (vertex {bad} is {v[bad].tolist()})")
        far = _far_vertex(v)
        if far is not None:
            raise ValueError(f"vertices must lie within +-{MAX_MESH_COORD:g} (vertex {far} is {v[far].tolist()}; "
                             "warpscatter.scene.meshes.MAX_MESH_COORD, float32 products of larger ones overflow)")
        lo, hi = int(t.min()), int(t.max())
        if lo < 0 or hi >= v.shape[0]:
            raise ValueError(f"triangles index vertices in [{lo}, {hi}] but there are {v.shape[0]} vertices")
        self.vertices = v
        self.triangles = np.ascontiguousarray(t, dtype=np.int32)

    @classmethod
    def _trusted(cls, vertices: np.ndarray, triangles: np.ndarray) -> TriangleMesh:
        """A mesh around arrays known to be valid: no checks, no copies."""
        mesh = cls.__new__(cls)
        mesh.vertices, mesh.triangles = vertices, triangles
        return mesh

    @property
    def num_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def num_triangles(self) -> int:
        return int(self.triangles.shape[0])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) float64 bounds of the referenced vertices."""
        used = self.vertices[np.unique(self.triangles)].astype(np.float64)
        return used.min(axis=0), used.max(axis=0)

    def triangle_vertices(self) -> np.ndarray:
        """(T, 3, 3) float32 corner positions of every triangle."""
        return self.vertices[self.triangles]

    def face_normals(self) -> np.ndarray:
        """(T, 3) float32 unit normals (v1 - v0) x (v2 - v0); degenerate triangles get (0, 0, 0)."""
        tv = self.triangle_vertices().astype(np.float64)
        n = np.cross(tv[:, 1] - tv[:, 0], tv[:, 2] - tv[:, 0])
        length = np.linalg.norm(n, axis=1, keepdims=True)
        return np.where(length > 0.0, n / np.maximum(length, 1e-300), 0.0).astype(np.float32)

    def to_trimesh(self):
        """The same mesh as a ``trimesh.Trimesh`` (no vertex merging or other processing)."""
        import trimesh

        return trimesh.Trimesh(vertices=self.vertices, faces=self.triangles, process=False)

    @staticmethod
    def concatenate(meshes: Sequence[TriangleMesh]) -> tuple[TriangleMesh, np.ndarray]:
        """Join meshes, keeping triangle order: (mesh, part), part[t] the index of triangle t's input mesh."""
        meshes = list(meshes)
        if not meshes:
            raise ValueError("meshes must hold at least one TriangleMesh")
        for k, m in enumerate(meshes):
            if not isinstance(m, TriangleMesh):
                raise ValueError(f"meshes[{k}] is a {type(m).__name__}, not a TriangleMesh")
        offsets = np.cumsum([0] + [m.num_vertices for m in meshes[:-1]])
        vertices = np.concatenate([m.vertices for m in meshes], axis=0)
        triangles = np.concatenate(
            [m.triangles.astype(np.int64) + o for m, o in zip(meshes, offsets, strict=True)], axis=0
        )
        if vertices.shape[0] > np.iinfo(np.int32).max:
            raise ValueError(f"meshes hold {vertices.shape[0]} vertices in total, more than int32 indices allow")
        part = np.concatenate([np.full(m.num_triangles, k, dtype=np.int32) for k, m in enumerate(meshes)])
        return TriangleMesh(vertices, triangles.astype(np.int32)), part


def _far_vertex(vertices: np.ndarray) -> int | None:
    """The first vertex with a coordinate beyond +-MAX_MESH_COORD, or None."""
    if vertices.size == 0 or float(np.abs(vertices).max()) <= MAX_MESH_COORD:
        return None
    return int(np.argwhere((np.abs(vertices) > MAX_MESH_COORD).any(axis=1))[0, 0])


def concatenate(meshes: Sequence[TriangleMesh]) -> tuple[TriangleMesh, np.ndarray]:
    """Module-level alias of :meth:`TriangleMesh.concatenate`."""
    return TriangleMesh.concatenate(meshes)



def load_mesh(path: str | os.PathLike) -> TriangleMesh:
    """Load a triangle mesh from OBJ, PLY, STL, GLB/glTF or OFF (polygons triangulated). Scenes are flattened with
    their node transforms, all triangles of all objects in file order; points and lines are ignored; vertices are
    not merged.

    Args:
        path: file path; the format is taken from the extension.

    Raises:
        MeshLoadError: missing, unsupported, too large, unparsable, or no valid triangles; names file and reason.
    """
    import trimesh

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()

    def fail(reason: str) -> MeshLoadError:
        return MeshLoadError(f"mesh file {path!r}: {reason}", path=path)

    if not os.path.isfile(path):
        raise fail("no such file")
    if ext not in SUPPORTED_EXTENSIONS:
        raise fail(f"unsupported extension {ext!r} (supported: {', '.join(SUPPORTED_EXTENSIONS)})")
    try:
        size = os.path.getsize(path)
        if size > MAX_MESH_FILE_BYTES:
            raise fail(f"the file has {size:,} bytes, more than the {MAX_MESH_FILE_BYTES:,} a mesh file may have "
                       f"(warpscatter.scene.meshes.MAX_MESH_FILE_BYTES)")
        with open(path, "rb") as f:
            data = f.read(MAX_MESH_FILE_BYTES + 1)
    except OSError as exc:
        raise fail(f"cannot be read ({exc.strerror or exc})") from exc
    if not data:
        raise fail("the file is empty")
    if len(data) > MAX_MESH_FILE_BYTES:  # grew since the size check
        raise fail(f"the file has more than the {MAX_MESH_FILE_BYTES:,} bytes a mesh file may have "
                   f"(warpscatter.scene.meshes.MAX_MESH_FILE_BYTES)")
    kind = ext[1:].upper()
    if ext in _TEXT_FORMATS and _looks_binary(data):
        raise fail(f"cannot be parsed as {kind} (binary data: {kind} files are text)")
    incomplete = _incomplete(data, ext)
    if incomplete:
        raise fail(incomplete)
    try:
        scene = trimesh.load_scene(io.BytesIO(_readable_text(data, ext)), file_type=ext[1:],
                                   resolver=trimesh.resolvers.FilePathResolver(path), process=False)
        geometries = scene.dump()
    except ImportError as exc:
        raise fail(f"cannot be parsed as {kind} (trimesh would need the module {exc.name!r} for this file, "
                   f"which is not installed: text that is not UTF-8 in a binary format?)") from exc
    except Exception as exc:  # trimesh raises many types on bad files
        raise fail(f"cannot be parsed as {kind} ({type(exc).__name__}: {exc})") from exc

    parts, skipped = [], []
    for g in geometries:
        faces = getattr(g, "faces", None)
        if isinstance(g, trimesh.Trimesh) and faces is not None and len(faces) > 0:
            parts.append((np.asarray(g.vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)))
        else:
            skipped.append(type(g).__name__)
    if not parts:
        what = f"only {', '.join(sorted(set(skipped)))} geometry" if skipped else "no geometry"
        raise fail(f"contains no triangles ({what})")
    meshes = []
    for k, (v, f) in enumerate(parts):
        try:
            meshes.append(TriangleMesh(v, f))
        except ValueError as exc:
            raise fail(f"object {k} is invalid ({exc})") from exc
    try:
        return TriangleMesh.concatenate(meshes)[0]
    except ValueError as exc:
        raise fail(str(exc)) from exc


_DATA_LINE = re.compile(rb"^[ \t]*[^\s#]", re.M)
_SHORT_OBJ_FACE = re.compile(rb"^[ \t]*f(?:[ \t]+\S+){0,2}[ \t]*\r?$", re.M)


def _count_data_lines(body: bytes) -> int:
    """Lines holding something other than blanks and a ``#`` comment."""
    return sum(1 for _ in _DATA_LINE.finditer(body))


def _incomplete(data: bytes, ext: str) -> str:
    """Why a mesh file is truncated or holds a face of fewer than 3 corners, which trimesh would read silently (a
    PLY or OFF file with fewer lines of data than its header declares, an OBJ face ``f 1 2``); "" when it is not."""
    if ext == ".obj":
        m = _SHORT_OBJ_FACE.search(data)
        if m:
            line = data.count(b"\n", 0, m.start()) + 1
            return (f"line {line}: a face with fewer than 3 vertices ({m.group().strip().decode('latin-1')!r}): a "
                    "truncated file?")
    elif ext == ".ply":
        end = data.find(b"end_header")
        if not data.startswith(b"ply") or end < 0:
            return ""
        header = data[:end].decode("latin-1").split("\n")
        if not any(line.split()[:2] == ["format", "ascii"] for line in header):
            return ""  # binary: trimesh checks the length
        counts = {}
        for line in header:
            words = line.split()
            if len(words) == 3 and words[0] == "element" and words[2].isdigit():
                counts[words[1]] = int(words[2])
        body = data[data.find(b"\n", end) + 1:] if data.find(b"\n", end) >= 0 else b""
        have, need = _count_data_lines(body), sum(counts.values())
        if have < need:
            declared = " and ".join(f"{n:,} {name!r}" for name, n in counts.items())
            return (f"truncated: its header declares {declared} elements ({need:,} lines of data) but {have:,} line(s) "
                    "of data follow")
    elif ext == ".off":
        text = re.sub(rb"#[^\n]*", b"", data)
        m = re.search(rb"(COFF|OFF)", text)
        if m is None:
            return ""
        lines = [line for line in text[m.end():].split(b"\n") if line.strip()]
        counts = lines[0].split() if lines else []
        if len(counts) < 2 or not counts[0].isdigit() or not counts[1].isdigit():
            return ""  # trimesh reports it
        nv, nf = int(counts[0]), int(counts[1])
        if len(lines) - 1 < nv + nf:
            return (f"truncated: its header declares {nv:,} vertices and {nf:,} faces ({nv + nf:,} lines of data) but "
                    f"{len(lines) - 1:,} line(s) of data follow")
        for k, line in enumerate(lines[1 + nv:1 + nv + nf]):
            words = line.split()
            if not words[0].isdigit() or int(words[0]) < 3 or len(words) < int(words[0]) + 1:
                return f"face {k} ({line.strip().decode('latin-1')!r}) has fewer than 3 vertices: a truncated file?"
    return ""


_CONTROL_BYTES = bytes(b for b in range(32) if b not in b"\t\n\r\f\v") + b"\x7f"


def _looks_binary(data: bytes) -> bool:
    """Whether the start of a file is not text: a NUL byte, or more than 1 % control characters in its first 64 kB."""
    sample = data[:65536]
    if b"\x00" in sample:
        return True
    return len(sample) - len(sample.translate(None, _CONTROL_BYTES)) > 0.01 * len(sample)


def _readable_text(data: bytes, ext: str) -> bytes:
    """``data`` with its text made UTF-8 (non-UTF-8 read as Latin-1; binary STL header bytes >= 0x80 -> ``?``), so
    trimesh never guesses the encoding (which needs the optional charset_normalizer)."""
    if ext == ".stl" and len(data) >= 84 and len(data) == 84 + 50 * struct.unpack_from("<I", data, 80)[0]:
        return bytes(b if b < 0x80 else 0x3F for b in data[:80]) + data[80:]
    if ext in _TEXT_FORMATS or ext == ".stl":
        try:
            data.decode("utf-8")
        except UnicodeDecodeError:
            return data.decode("latin-1").encode("utf-8")
    return data



def _vec3(name: str, value, default: float) -> np.ndarray:
    if value is None:
        return np.full(3, default, dtype=np.float64)
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a number or 3 numbers, got {value!r}") from exc
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,):
        raise ValueError(f"{name} must be a number or 3 numbers, got {value!r}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite, got {a.tolist()}")
    return a


def rotation_matrix(axis: str, angle_deg: float) -> np.ndarray:
    """Right-handed 3x3 rotation about ``axis`` ('x', 'y' or 'z') by ``angle_deg`` degrees."""
    a = np.radians(float(angle_deg))
    c, s = np.cos(a), np.sin(a)
    if axis == "x":
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    if axis == "y":
        return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    if axis == "z":
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    raise ValueError(f"axis must be 'x', 'y' or 'z', got {axis!r}")


def transform_matrix(translate=None, rotate_deg=None, scale=None) -> np.ndarray:
    """The 4x4 float64 matrix ``M = T @ Rz @ Ry @ Rx @ S`` of a mesh-entry transform (CONVENTIONS.md).

    Args:
        translate: [tx, ty, tz] in scene units (default zeros).
        rotate_deg: [rx, ry, rz] in degrees, right-handed (default zeros).
        scale: a positive number or three positive numbers [sx, sy, sz] (default 1).

    Raises:
        ValueError: naming the malformed or non-finite argument, or a scale not > 0.
    """
    t = _vec3("translate", translate, 0.0)
    r = _vec3("rotate_deg", rotate_deg, 0.0)
    s = _vec3("scale", scale, 1.0)
    if np.any(s <= 0.0):
        raise ValueError(f"scale must be > 0, got {s.tolist()}")
    m = np.eye(4)
    m[:3, :3] = rotation_matrix("z", r[2]) @ rotation_matrix("y", r[1]) @ rotation_matrix("x", r[0]) @ np.diag(s)
    m[:3, 3] = t
    return m


def apply_transform(mesh: TriangleMesh, matrix) -> TriangleMesh:
    """A new mesh with the affine 4x4 ``matrix`` applied (in float64); a mirror also reverses the winding.

    Raises:
        ValueError: when ``matrix`` is not a finite affine 4x4 matrix or is singular.
        InputFileError: when it places a vertex beyond +-:data:`MAX_MESH_COORD` (a ValueError too).
    """
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError(f"matrix must be a finite 4x4 array, got shape {m.shape}")
    if not np.allclose(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"matrix must be affine (last row 0, 0, 0, 1), got last row {m[3].tolist()}")
    det = np.linalg.det(m[:3, :3])
    if abs(det) < 1e-300:
        raise ValueError("matrix is singular (zero determinant)")
    if np.array_equal(m[:3, :3], np.eye(3)) and not np.any(m[:3, 3]) and not np.any(np.signbit(m[:3, 3])):
        # identity: v @ I + 0 is exactly v + 0 (-0.0 -> +0.0)
        return TriangleMesh(mesh.vertices + np.float32(0.0), mesh.triangles.copy())
    v = mesh.vertices.astype(np.float64) @ m[:3, :3].T + m[:3, 3]
    far = _far_vertex(v)
    if far is not None:
        raise InputFileError(f"the mesh placed by its transform (scale, rotate_deg, translate) has vertex {far} at "
                             f"{v[far].tolist()}, beyond +-{MAX_MESH_COORD:g} scene units (warpscatter.scene.meshes."
                             "MAX_MESH_COORD: float32 products of larger coordinates overflow); scale it down")
    tris = mesh.triangles if det > 0 else mesh.triangles[:, ::-1]
    return TriangleMesh(v, tris.copy())


#: Total size (vertex and index bytes) of the meshes :func:`cached_mesh` keeps; 0 turns the cache off.
MESH_CACHE_BYTES = 256 * 2**20

_cache: OrderedDict[Hashable, tuple[np.ndarray, np.ndarray]] = OrderedDict()
_cache_lock = threading.Lock()
_cache_state = {"bytes": 0, "hits": 0, "misses": 0}


def file_key(path: str | os.PathLike) -> tuple | None:
    """Cache key of a mesh file (path, size, times, inode); None when it cannot be stat'ed."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return ("file", os.path.abspath(os.fspath(path)), st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)


def cached_mesh(key: Hashable | None, build: Callable[[], TriangleMesh]) -> TriangleMesh:
    """The mesh ``build()`` makes (a new one), built once per ``key`` while cached, around shared read-only arrays.
    ``key`` None bypasses the cache; errors are not cached."""
    if key is not None:
        with _cache_lock:
            hit = _cache.get(key)
            if hit is not None:
                _cache.move_to_end(key)
                _cache_state["hits"] += 1
                return TriangleMesh._trusted(*hit)
            _cache_state["misses"] += 1
    mesh = build()
    vertices, triangles = mesh.vertices, mesh.triangles
    vertices.flags.writeable = False
    triangles.flags.writeable = False
    size = vertices.nbytes + triangles.nbytes
    if key is not None and size <= MESH_CACHE_BYTES:
        with _cache_lock:
            old = _cache.pop(key, None)
            if old is not None:
                _cache_state["bytes"] -= old[0].nbytes + old[1].nbytes
            _cache[key] = (vertices, triangles)
            _cache_state["bytes"] += size
            while _cache_state["bytes"] > MESH_CACHE_BYTES:
                v, t = _cache.popitem(last=False)[1]
                _cache_state["bytes"] -= v.nbytes + t.nbytes
    return TriangleMesh._trusted(vertices, triangles)


def clear_mesh_cache() -> None:
    """Forget every cached mesh (and reset the hit and miss counts)."""
    with _cache_lock:
        _cache.clear()
        _cache_state.update(bytes=0, hits=0, misses=0)


def mesh_cache_info() -> dict:
    """``{"entries", "bytes", "hits", "misses", "max_bytes"}`` of the mesh cache."""
    with _cache_lock:
        return {"entries": len(_cache), **_cache_state, "max_bytes": MESH_CACHE_BYTES}
