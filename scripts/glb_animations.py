#!/usr/bin/env python3
"""Takes the animations out of a .glb, or puts another file's animations into
a progressive file of the same nodes: the two steps of measuring how a skin
built without animation does on motion it never saw (docs/performance.md,
"Characters without animation").

usage:
  python3 scripts/glb_animations.py strip IN.glb OUT.glb
      OUT is IN without its "animations" (an avatar exported for a game to
      drive); the binary chunk is kept as it is.
  python3 scripts/glb_animations.py graft PROGRESSIVE.glb ANIMATED.glb OUT.gltf
      OUT is PROGRESSIVE (a `progskin build` output) with ANIMATED's
      animations, buffers embedded as data URIs. Both files must list the same
      nodes by name in the same order (a build keeps the input's nodes). The
      server tables stored in PROGRESSIVE's extension are left out, so that a
      server computes them on the grafted clips.

exit codes: 0 ok, 1 bad input, 2 bad command line
"""
import base64
import json
import struct
import sys


def read_glb(path):
    with open(path, "rb") as f:
        d = f.read()
    if len(d) < 20 or d[:4] != b"glTF":
        raise ValueError(f"{path}: not a binary glTF (.glb)")
    off, doc, binary = 12, None, b""
    while off + 8 <= len(d):
        length, kind = struct.unpack_from("<II", d, off)
        chunk = d[off + 8:off + 8 + length]
        if len(chunk) != length:
            raise ValueError(f"{path}: a chunk runs past the end of the file")
        off += 8 + length
        if kind == 0x4E4F534A:
            doc = json.loads(chunk)
        elif kind == 0x004E4942:
            binary = chunk
    if doc is None:
        raise ValueError(f"{path}: no JSON chunk")
    return doc, binary


def write_glb(path, doc, binary):
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(text) + (8 + len(binary) if binary else 0)
    with open(path, "wb") as f:
        f.write(struct.pack("<III", 0x46546C67, 2, total))
        f.write(struct.pack("<II", len(text), 0x4E4F534A) + text)
        if binary:
            f.write(struct.pack("<II", len(binary), 0x004E4942) + binary)


def strip(src, dst):
    doc, binary = read_glb(src)
    doc.pop("animations", None)
    write_glb(dst, doc, binary)


def data_uri(b):
    return "data:application/octet-stream;base64," + base64.b64encode(b).decode()


def graft(progressive, animated, dst):
    doc, binary = read_glb(progressive)
    src, src_bin = read_glb(animated)
    if [n.get("name") for n in doc.get("nodes", [])] != [n.get("name") for n in src.get("nodes", [])]:
        raise ValueError(f"{progressive} and {animated} do not list the same nodes in the same order")
    if not src.get("animations"):
        raise ValueError(f"{animated}: no animations")
    if doc.get("buffers"):
        doc["buffers"][0]["uri"] = data_uri(binary)
    doc.setdefault("buffers", []).append({"byteLength": len(src_bin), "uri": data_uri(src_bin)})
    buffer = len(doc["buffers"]) - 1
    views, accessors = {}, {}

    def view(v):
        if v not in views:
            bv = dict(src["bufferViews"][v])
            bv["buffer"] = buffer
            doc.setdefault("bufferViews", []).append(bv)
            views[v] = len(doc["bufferViews"]) - 1
        return views[v]

    def accessor(a):
        if a not in accessors:
            x = dict(src["accessors"][a])
            if "bufferView" in x:
                x["bufferView"] = view(x["bufferView"])
            doc.setdefault("accessors", []).append(x)
            accessors[a] = len(doc["accessors"]) - 1
        return accessors[a]

    animations = json.loads(json.dumps(src["animations"]))
    for an in animations:
        for s in an["samplers"]:
            s["input"], s["output"] = accessor(s["input"]), accessor(s["output"])
    doc["animations"] = animations
    for skin in doc.get("skins", []):
        skin.get("extensions", {}).get("PROGSKIN_progressive_skin", {}).pop("server", None)
    with open(dst, "w") as f:
        json.dump(doc, f)


def main(argv):
    if len(argv) >= 1 and argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0
    try:
        if len(argv) == 3 and argv[0] == "strip":
            strip(argv[1], argv[2])
        elif len(argv) == 4 and argv[0] == "graft":
            graft(argv[1], argv[2], argv[3])
        else:
            print(__doc__, file=sys.stderr)
            return 2
    except (OSError, ValueError, KeyError, IndexError) as e:
        print(f"glb_animations.py: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
