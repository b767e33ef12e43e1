"""Scene packing, as ``tally submit`` does it (client/scene_packer.hpp): every local file a
job spec's scene names, and every file *those* name, recursively, goes to the server's
asset store and is named by its hash, ``"sha256:<hex>"``:

- ``"file"`` (glTF, .gltf or .glb): its ``buffers[].uri`` and ``images[].uri``;
- ``"obj"`` (OBJ, unless the mesh names its own ``"material"``): its ``mtllib`` libraries,
  and their ``map_Kd`` textures (looked for next to the .mtl, then next to the OBJ);
- ``"map"`` (an environment map): the image itself.

A file whose references were rewritten is stored as the rewritten bytes. A spec field
naming no local file is left alone (the server's ``--asset-dir`` may have it); a file
named *inside* a packed file must exist, or :class:`PackError` names the file holding the
reference, its format, the reference and why.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import urllib.parse
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple

__all__ = ["PackError", "ScenePacker", "sha256_file", "FILE_FIELDS"]

# Scene fields that name a file (common/lighting/asset_resolver.hpp: is_scene_file_field).
FILE_FIELDS = frozenset({"obj", "map", "file"})
_REF = "sha256:"
_GLB_MAGIC = 0x46546C67  # "glTF"
_JSON_CHUNK = 0x4E4F534A  # "JSON"


class PackError(ValueError):
    """A file the scene names cannot be packed; the message names the user's path and format."""


def sha256_file(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _unreadable(path: str) -> Optional[str]:
    """Why ``path`` is not a readable file, or None."""
    try:
        st = os.stat(path)
    except OSError as e:
        return e.strerror or str(e)
    if not os.path.isfile(path):
        return "is not a regular file"
    del st
    return None


def _read(path: str) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError as e:
        raise PackError(f"cannot read {os.path.normpath(path)}: {e.strerror or e}") from e


# (ref, local path) -> None: make sure the server has the file as it is on disk.
PutFile = Callable[[str, str], None]
# (ref, bytes, origin path) -> None: make sure the server has these (rewritten) bytes.
PutBytes = Callable[[str, bytes, str], None]


class ScenePacker:
    """Packs specs into a store given by two callables (see :class:`~tally_client.Client`)."""

    def __init__(self, put_file: PutFile, put_bytes: PutBytes, base_dir: str = "."):
        self._put_file = put_file
        self._put_bytes = put_bytes
        self._base = base_dir
        self._done: Dict[Tuple[str, str], str] = {}
        #: ``"sha256:<hex>"`` -> the user's path of that file, for error messages.
        self.origins: Dict[str, str] = {}
        self._obj_dir = "."
        self._depth = 0

    def pack_spec(self, spec: Mapping[str, Any]) -> Dict[str, Any]:
        """A copy of ``spec`` with its scene's files packed; ``spec`` is unchanged."""
        out = self._walk(dict(spec))
        assert isinstance(out, dict)
        return out

    def with_user_paths(self, text: str) -> str:
        """``text`` with every hash this packer gave a file replaced by the file's path."""
        for ref, path in self.origins.items():
            text = text.replace(ref, path)
        return text

    # --- the spec ------------------------------------------------------------------

    def _walk(self, v: Any) -> Any:
        if isinstance(v, dict):
            own_material = "material" in v
            out: Dict[str, Any] = {}
            for k, x in v.items():
                if k in FILE_FIELDS and isinstance(x, str) and not x.startswith(_REF):
                    local = x if os.path.isabs(x) else os.path.join(self._base, x)
                    if not os.path.isfile(local):
                        out[k] = x  # not ours: the server's --asset-dir may have it
                    elif k == "file":
                        out[k] = self._pack(local, "gltf")
                    elif k == "obj" and not own_material:
                        out[k] = self._pack(local, "obj")
                    else:
                        out[k] = self._pack(local, "plain")
                else:
                    out[k] = self._walk(x)
            return out
        if isinstance(v, list):
            return [self._walk(x) for x in v]
        return v

    # --- files ---------------------------------------------------------------------

    def _pack(self, path: str, kind: str) -> str:
        key = (os.path.realpath(path), kind)
        if key in self._done:
            return self._done[key]
        if self._depth > 4:
            raise PackError(f"{os.path.normpath(path)}: files name each other too deeply (a cycle?)")
        self._depth += 1
        try:
            if kind == "gltf":
                ref = self._pack_gltf(path)
            elif kind == "obj":
                ref = self._pack_obj(path)
            elif kind == "mtl":
                ref = self._pack_mtl(path)
            else:
                ref = _REF + sha256_file(path)
                self._put_file(ref, path)
        finally:
            self._depth -= 1
        self.origins.setdefault(ref, os.path.normpath(path))
        self._done[key] = ref
        return ref

    def _store(self, data: bytes, origin: str) -> str:
        ref = _REF + hashlib.sha256(data).hexdigest()
        self._put_bytes(ref, data, origin)
        return ref

    def _store_packed(self, path: str, original: bytes, rewritten: Optional[bytes]) -> str:
        """The file as it is on disk (sent from disk) when nothing was rewritten, else the
        rewritten bytes."""
        if rewritten is None:
            ref = _REF + hashlib.sha256(original).hexdigest()
            self._put_file(ref, path)
            return ref
        return self._store(rewritten, path)

    def _nested(self, referrer: str, fmt: str, what: str, name: str, directory: str, kind: str) -> str:
        if name.startswith(_REF):
            return name
        local = name if os.path.isabs(name) else os.path.join(directory, name)
        why = _unreadable(local)
        if why is not None:
            raise PackError(f"{os.path.normpath(referrer)} ({fmt}): {what} names {name!r}, which cannot be read "
                            f"({os.path.normpath(local)}: {why})")
        return self._pack(local, kind)

    def _pack_gltf(self, path: str) -> str:
        data = _read(path)
        glb = len(data) >= 4 and struct.unpack_from("<I", data, 0)[0] == _GLB_MAGIC
        fmt = "glTF binary" if glb else "glTF"
        json_end = 0
        if glb:
            if len(data) < 20 or struct.unpack_from("<I", data, 16)[0] != _JSON_CHUNK:
                raise PackError(f"{os.path.normpath(path)} (glTF binary): the file is cut short or its first chunk is not JSON")
            json_end = 20 + struct.unpack_from("<I", data, 12)[0]
            if json_end > len(data):
                raise PackError(f"{os.path.normpath(path)} (glTF binary): the JSON chunk runs past the end of the file")
            text = data[20:json_end]
        else:
            text = data
        try:
            doc = json.loads(text.decode("utf-8"))
        except UnicodeDecodeError as e:
            raise PackError(f"{os.path.normpath(path)} ({fmt}): not UTF-8 JSON: {e}") from e
        except json.JSONDecodeError as e:
            raise PackError(f"{os.path.normpath(path)} ({fmt}): not valid JSON: at line {e.lineno}, column {e.colno}: "
                            f"{e.msg}") from e
        if not isinstance(doc, dict):
            raise PackError(f"{os.path.normpath(path)} ({fmt}): not a glTF document (not a JSON object)")
        directory = os.path.dirname(path)
        changed = False
        for field in ("buffers", "images"):
            items = doc.get(field)
            if not isinstance(items, list):
                continue
            for i, item in enumerate(items):
                if not isinstance(item, dict) or not isinstance(item.get("uri"), str):
                    continue
                uri: str = item["uri"]
                if uri.startswith("data:") or uri.startswith(_REF):
                    continue
                # glTF URIs are percent-encoded; the server's tinygltf decodes them the same way.
                item["uri"] = self._nested(path, fmt, f"{field}[{i}]", urllib.parse.unquote_plus(uri), directory,
                                           "plain")
                changed = True
        if not changed:
            return self._store_packed(path, data, None)
        js = json.dumps(doc, separators=(",", ":")).encode("utf-8")
        if not glb:
            return self._store(js, path)
        js += b" " * (-len(js) % 4)
        rest = data[json_end:]
        version = struct.unpack_from("<I", data, 4)[0]
        out = struct.pack("<III", _GLB_MAGIC, version, 12 + 8 + len(js) + len(rest))
        out += struct.pack("<II", len(js), _JSON_CHUNK) + js + rest
        return self._store(out, path)

    def _map_lines(self, data: bytes, fix: Callable[[List[str], str], Optional[str]]) -> Tuple[bytes, bool]:
        """Each line (decoded as UTF-8, bytes kept otherwise) through ``fix(words, line)``;
        None keeps the line. Returns the new bytes and whether anything changed."""
        changed = False
        lines = data.split(b"\n")
        for i, raw in enumerate(lines):
            line = raw.decode("utf-8", "surrogateescape")
            fixed = fix(line.split(), line)
            if fixed is not None:
                lines[i] = fixed.encode("utf-8", "surrogateescape")
                changed = True
        return b"\n".join(lines), changed

    def _pack_obj(self, path: str) -> str:
        data = _read(path)
        directory = os.path.dirname(path)
        self._obj_dir = directory

        def fix(words: List[str], line: str) -> Optional[str]:
            if not words or words[0] != "mtllib":
                return None
            return "mtllib " + " ".join(self._nested(path, "OBJ", "mtllib", w, directory, "mtl") for w in words[1:])

        out, changed = self._map_lines(data, fix)
        return self._store_packed(path, data, out if changed else None)

    def _pack_mtl(self, path: str) -> str:
        data = _read(path)
        directory = os.path.dirname(path)
        obj_dir = self._obj_dir

        def fix(words: List[str], line: str) -> Optional[str]:
            # The server reads map_Kd (other maps are parsed and never opened).
            if len(words) < 2 or words[0] != "map_Kd" or words[-1].startswith(_REF):
                return None
            name = words[-1]
            where = directory
            if not os.path.isabs(name) and _unreadable(os.path.join(directory, name)) is not None \
                    and _unreadable(os.path.join(obj_dir, name)) is None:
                where = obj_dir
            ref = self._nested(path, "MTL", "map_Kd", name, where, "plain")
            at = line.rfind(name)
            return line[:at] + ref + line[at + len(name):]

        out, changed = self._map_lines(data, fix)
        return self._store_packed(path, data, out if changed else None)
