#!/usr/bin/env python3
"""Writes the small hand-made glTF files used by tests/test_import.cpp.

Run from anywhere: python3 tests/data/make_gltf_fixtures.py
Outputs (next to this script):
  sparse_quantized.gltf   sparse accessors, normalized u8/u16 weights, byte strides,
                          offsets, STEP/LINEAR/CUBICSPLINE samplers, i16 quaternions
  eight_influences.gltf   JOINTS_0/WEIGHTS_0 + JOINTS_1/WEIGHTS_1
  multi_skin.gltf         five skins: four form one skeleton (shared and top-most joints,
                          a duplicate node with another inverse bind matrix), one is a
                          second character; a mesh rigidly parented to a joint
  skinned_morph.gltf      a skinned face with morph targets (dense, sparse, with NORMAL deltas)
                          over two primitives, mesh and node default weights, a rigid hat
                          with its own target; clips animate weights (CUBICSPLINE, STEP)
                          together with a joint (three.js reference: tests/data/threejs)
  external_buffer.gltf/.bin, basic.glb   the basic character in the other containers
  armature_cm.gltf, armature_m.gltf      a tail of six joints under an armature node that
                          scales centimetres to metres (every skinning matrix scaled
                          0.01), and the same character in metres
  broken/*                one defect each (see BROKEN below)
Only the standard library is used; the output is deterministic.
"""
import base64
import json
import math
import os
import struct

HERE = os.path.dirname(os.path.abspath(__file__))

FLOAT, UBYTE, USHORT, SHORT, BYTE, UINT = 5126, 5121, 5123, 5122, 5120, 5125
FORMAT = {FLOAT: 'f', UBYTE: 'B', USHORT: 'H', SHORT: 'h', BYTE: 'b', UINT: 'I'}
SIZE = {FLOAT: 4, UBYTE: 1, USHORT: 2, SHORT: 2, BYTE: 1, UINT: 4}
COMPONENTS = {'SCALAR': 1, 'VEC2': 2, 'VEC3': 3, 'VEC4': 4, 'MAT4': 16}


class Gltf:
    """Accumulates one binary buffer and the JSON objects that refer to it."""

    def __init__(self):
        self.bin = bytearray()
        self.j = {'asset': {'version': '2.0', 'generator': 'progskin make_gltf_fixtures.py'},
                  'buffers': [], 'bufferViews': [], 'accessors': [], 'nodes': [], 'meshes': [],
                  'skins': [], 'animations': [], 'scenes': [{'nodes': []}], 'scene': 0}

    def align(self):
        while len(self.bin) % 4:
            self.bin.append(0)

    def view(self, data, stride=None, lead=0):
        """Adds a buffer view over `data`, preceded by `lead` padding bytes in the buffer."""
        self.align()
        self.bin += b'\xee' * lead
        v = {'buffer': 0, 'byteOffset': len(self.bin), 'byteLength': len(data)}
        if stride:
            v['byteStride'] = stride
        self.bin += data
        self.j['bufferViews'].append(v)
        return len(self.j['bufferViews']) - 1

    def accessor(self, ctype, type_, values, normalized=False, stride=None, offset=0, lead=0, minmax=False):
        """Packs `values` (list of tuples) into a new view (strided if asked) and an accessor."""
        fmt = '<' + FORMAT[ctype] * COMPONENTS[type_]
        elem = struct.calcsize(fmt)
        step = stride or elem
        data = bytearray(b'\xcd' * offset)
        for v in values:
            chunk = struct.pack(fmt, *v)
            data += chunk + b'\xab' * (step - elem)
        a = {'bufferView': self.view(bytes(data), stride, lead), 'componentType': ctype,
             'count': len(values), 'type': type_}
        if offset:
            a['byteOffset'] = offset
        if normalized:
            a['normalized'] = True
        if minmax:
            a['min'] = [min(v[i] for v in values) for i in range(COMPONENTS[type_])]
            a['max'] = [max(v[i] for v in values) for i in range(COMPONENTS[type_])]
        self.j['accessors'].append(a)
        return len(self.j['accessors']) - 1

    def sparse(self, ctype, type_, count, base, indices, values, index_type=UBYTE):
        """Accessor of `count` elements: `base` (list or None for zeros) with values at indices replaced."""
        a = {'componentType': ctype, 'count': count, 'type': type_}
        if base is not None:
            fmt = '<' + FORMAT[ctype] * COMPONENTS[type_]
            a['bufferView'] = self.view(b''.join(struct.pack(fmt, *v) for v in base))
        fmt = '<' + FORMAT[ctype] * COMPONENTS[type_]
        iv = self.view(b''.join(struct.pack('<' + FORMAT[index_type], i) for i in indices))
        vv = self.view(b''.join(struct.pack(fmt, *v) for v in values), lead=4)
        a['sparse'] = {'count': len(indices),
                       'indices': {'bufferView': iv, 'componentType': index_type},
                       'values': {'bufferView': vv}}
        self.j['accessors'].append(a)
        return len(self.j['accessors']) - 1

    def node(self, **kw):
        self.j['nodes'].append(kw)
        return len(self.j['nodes']) - 1

    def finish(self, uri=None):
        """The JSON with the buffer as a data URI (or an external `uri`)."""
        self.align()
        buf = {'byteLength': len(self.bin)}
        buf['uri'] = uri or 'data:application/octet-stream;base64,' + base64.b64encode(bytes(self.bin)).decode()
        j = json.loads(json.dumps(self.j))
        j['buffers'] = [buf]
        for key in ('skins', 'animations'):
            if not j[key]:
                del j[key]
        parents = {c for n in j['nodes'] for c in n.get('children', [])}
        j['scenes'][0]['nodes'] = [i for i in range(len(j['nodes'])) if i not in parents]
        return j

    def glb(self):
        """The model as a GLB container (binary chunk instead of the data URI)."""
        self.align()
        j = self.finish()
        j['buffers'] = [{'byteLength': len(self.bin)}]
        text = json.dumps(j, separators=(',', ':')).encode()
        text += b' ' * (-len(text) % 4)
        body = struct.pack('<II', len(text), 0x4E4F534A) + text + struct.pack('<II', len(self.bin), 0x004E4942) + self.bin
        return struct.pack('<III', 0x46546C67, 2, 12 + len(body)) + body


def write_json(name, j):
    path = os.path.join(HERE, name)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, 'w') as f:
        json.dump(j, f, indent=1)
        f.write('\n')


def translation(x, y, z):
    """Column-major 4x4 translation as glTF stores it."""
    return (1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, x, y, z, 1)


def quat_z(deg):
    """Rotation about +z as glTF (x, y, z, w)."""
    h = math.radians(deg) / 2
    return (0.0, 0.0, math.sin(h), math.cos(h))


# ---------------------------------------------------------------------------
# The basic character: root joint at the origin, child joint 1 unit up, a quad
# from y=0 to y=2 weighted to the root at the bottom and the child at the top.

def basic(ctype_weights=FLOAT):
    g = Gltf()
    g.node(name='root', children=[1])
    g.node(name='bone', translation=[0, 1, 0])
    g.node(name='quad', mesh=0, skin=0)
    pos = g.accessor(FLOAT, 'VEC3', [(0, 0, 0), (1, 0, 0), (0, 2, 0), (1, 2, 0)], minmax=True)
    joints = g.accessor(UBYTE, 'VEC4', [(0, 1, 0, 0)] * 4)
    w = [(1, 0, 0, 0), (1, 0, 0, 0), (0, 1, 0, 0), (0, 1, 0, 0)]
    weights = g.accessor(ctype_weights, 'VEC4', w)
    idx = g.accessor(USHORT, 'SCALAR', [(0,), (1,), (2,), (2,), (1,), (3,)])
    g.j['meshes'].append({'primitives': [{'attributes': {'POSITION': pos, 'JOINTS_0': joints, 'WEIGHTS_0': weights},
                                          'indices': idx}]})
    ibm = g.accessor(FLOAT, 'MAT4', [translation(0, 0, 0), translation(0, -1, 0)])
    g.j['skins'].append({'joints': [0, 1], 'inverseBindMatrices': ibm})
    times = g.accessor(FLOAT, 'SCALAR', [(0.0,), (1.0,)])
    rot = g.accessor(FLOAT, 'VEC4', [quat_z(0), quat_z(90)])
    g.j['animations'].append({'name': 'bend', 'samplers': [{'input': times, 'output': rot}],
                              'channels': [{'sampler': 0, 'target': {'node': 1, 'path': 'rotation'}}]})
    return g


# ---------------------------------------------------------------------------

def sparse_quantized():
    g = Gltf()
    # An animated node with a matrix (glTF forbids it; the importer decomposes it into TRS).
    g.node(name='root', children=[1], matrix=list(translation(2, 0, 0)))
    g.node(name='bone', translation=[0, 1, 0])
    g.node(name='mesh', mesh=0, skin=0)
    # Primitive 0: interleaved-style strided views with byte offsets, sparse positions.
    base = [(0, 0, 0), (1, 0, 0), (0, 2, 0), (1, 2, 0)]
    g.align()
    pos_view = g.view(b'\x00' * 8 + b''.join(struct.pack('<3f', *p) + b'\xab' * 4 for p in base), stride=16, lead=12)
    iv = g.view(struct.pack('<H', 2))
    vv = g.view(struct.pack('<3f', 0.0, 2.5, 0.0))
    g.j['accessors'].append({'bufferView': pos_view, 'byteOffset': 8, 'componentType': FLOAT, 'count': 4,
                             'type': 'VEC3',
                             'sparse': {'count': 1, 'indices': {'bufferView': iv, 'componentType': USHORT},
                                        'values': {'bufferView': vv}}})
    pos0 = len(g.j['accessors']) - 1
    nrm0 = g.accessor(FLOAT, 'VEC3', [(0, 0, 1)] * 4)
    j0 = g.accessor(UBYTE, 'VEC4', [(0, 1, 0, 0)] * 4, stride=8, offset=4)
    # u8 weights: exact, exact, 200/255 (renormalised), 254/255 (renormalised for u8 tolerance).
    w0 = g.accessor(UBYTE, 'VEC4', [(255, 0, 0, 0), (128, 127, 0, 0), (100, 100, 0, 0), (0, 254, 0, 0)],
                    normalized=True, stride=12)
    # Primitive 1: positions without a buffer view (zeros) plus sparse values; u16 joints and weights.
    pos1 = g.sparse(FLOAT, 'VEC3', 3, None, [1, 2], [(1, 0, 0), (0, 1, 0)])
    j1 = g.accessor(USHORT, 'VEC4', [(1, 0, 0, 0), (0, 1, 0, 0), (1, 0, 0, 0)])
    w1 = g.accessor(USHORT, 'VEC4', [(65535, 0, 0, 0), (32768, 32767, 0, 0), (65535, 0, 0, 0)], normalized=True)
    g.j['meshes'].append({'primitives': [
        {'attributes': {'POSITION': pos0, 'NORMAL': nrm0, 'JOINTS_0': j0, 'WEIGHTS_0': w0}},
        {'attributes': {'POSITION': pos1, 'JOINTS_0': j1, 'WEIGHTS_0': w1}, 'mode': 4}]})
    ibm = g.accessor(FLOAT, 'MAT4', [translation(0, 0, 0), translation(0, -1, 0)], stride=64)
    g.j['skins'].append({'joints': [0, 1], 'inverseBindMatrices': ibm})
    # Clips: CUBICSPLINE translation, STEP rotation (normalized i16), LINEAR scale with u8-free floats.
    t2 = g.accessor(FLOAT, 'SCALAR', [(0.0,), (2.0,)])
    cubic = g.accessor(FLOAT, 'VEC3', [(0, 0, 0), (0, 1, 0), (1, 0, 0),    # key 0: in, value, out
                                       (0, 0, 3), (0, 2, 0), (0, 0, 0)])   # key 1: in, value, out
    t3 = g.accessor(FLOAT, 'SCALAR', [(0.0,), (1.0,), (2.0,)])
    q = [quat_z(0), quat_z(90), quat_z(180)]
    steps = g.accessor(SHORT, 'VEC4', [tuple(round(c * 32767) for c in x) for x in q], normalized=True)
    scales = g.accessor(FLOAT, 'VEC3', [(1, 1, 1), (2, 2, 2), (1, 1, 1)])
    g.j['animations'] = [
        {'name': 'cubic', 'samplers': [{'input': t2, 'output': cubic, 'interpolation': 'CUBICSPLINE'}],
         'channels': [{'sampler': 0, 'target': {'node': 1, 'path': 'translation'}}]},
        {'name': 'steps', 'samplers': [{'input': t3, 'output': steps, 'interpolation': 'STEP'}],
         'channels': [{'sampler': 0, 'target': {'node': 1, 'path': 'rotation'}}]},
        {'name': 'grow', 'samplers': [{'input': t3, 'output': scales}],
         'channels': [{'sampler': 0, 'target': {'node': 0, 'path': 'scale'}}]},
    ]
    write_json('sparse_quantized.gltf', g.finish())


def eight_influences():
    g = Gltf()
    for i in range(8):
        g.node(name='j%d' % i, translation=[0, 0 if i == 0 else 1, 0], **({'children': [i + 1]} if i < 7 else {}))
    g.node(name='mesh', mesh=0, skin=0)
    pos = g.accessor(FLOAT, 'VEC3', [(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    j0 = g.accessor(UBYTE, 'VEC4', [(0, 1, 2, 3)] * 3)
    w0 = g.accessor(FLOAT, 'VEC4', [(0.125,) * 4, (0.5, 0, 0, 0), (0.25, 0.25, 0, 0)])
    j1 = g.accessor(USHORT, 'VEC4', [(4, 5, 6, 7)] * 3)
    w1 = g.accessor(FLOAT, 'VEC4', [(0.125,) * 4, (0, 0, 0, 0.5), (0.25, 0, 0.25, 0)])
    pos_b = g.accessor(FLOAT, 'VEC3', [(0, 0, 1), (1, 0, 1), (0, 1, 1)])
    jb = g.accessor(UBYTE, 'VEC4', [(7, 0, 0, 0)] * 3)
    wb = g.accessor(FLOAT, 'VEC4', [(1, 0, 0, 0)] * 3)
    g.j['meshes'].append({'primitives': [
        {'attributes': {'POSITION': pos, 'JOINTS_0': j0, 'WEIGHTS_0': w0, 'JOINTS_1': j1, 'WEIGHTS_1': w1}},
        {'attributes': {'POSITION': pos_b, 'JOINTS_0': jb, 'WEIGHTS_0': wb}}]})
    ibm = g.accessor(FLOAT, 'MAT4', [translation(0, -i, 0) for i in range(8)])
    g.j['skins'].append({'joints': list(range(8)), 'inverseBindMatrices': ibm})
    write_json('eight_influences.gltf', g.finish())


def multi_skin():
    g = Gltf()
    g.node(name='armature', translation=[1, 0, 0], children=[1, 5, 6, 9, 10])       # 0
    g.node(name='hip', translation=[0, 1, 0], children=[2, 3])                      # 1
    g.node(name='left', translation=[0.5, 0, 0])                                    # 2
    g.node(name='right', translation=[-0.5, 0, 0], children=[4])                    # 3
    g.node(name='prop', translation=[0, 0, 1], rotation=list(quat_z(90)), mesh=1)   # 4 rigid
    g.node(name='body', mesh=0, skin=0)                                             # 5
    g.node(name='arm', mesh=2, skin=1)                                              # 6
    g.node(name='other_root', translation=[5, 0, 0])                                # 7
    g.node(name='other_mesh', mesh=2, skin=3)                                       # 8
    g.node(name='tail', mesh=0, skin=2)                                             # 9
    g.node(name='cape', mesh=2, skin=4)                                             # 10
    tri = g.accessor(FLOAT, 'VEC3', [(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    joints = g.accessor(UBYTE, 'VEC4', [(0, 0, 0, 0), (1, 0, 0, 0), (0, 1, 0, 0)])
    weights = g.accessor(FLOAT, 'VEC4', [(1, 0, 0, 0), (1, 0, 0, 0), (0.5, 0.5, 0, 0)])
    g.j['meshes'].append({'primitives': [{'attributes': {'POSITION': tri, 'JOINTS_0': joints, 'WEIGHTS_0': weights}}]})
    prop = g.accessor(FLOAT, 'VEC3', [(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    prop_n = g.accessor(FLOAT, 'VEC3', [(1, 0, 0)] * 3)
    g.j['meshes'].append({'primitives': [{'attributes': {'POSITION': prop, 'NORMAL': prop_n}}]})
    other_j = g.accessor(UBYTE, 'VEC4', [(0, 0, 0, 0)] * 3)
    other_w = g.accessor(FLOAT, 'VEC4', [(1, 0, 0, 0)] * 3)
    g.j['meshes'].append({'primitives': [{'attributes': {'POSITION': tri, 'JOINTS_0': other_j, 'WEIGHTS_0': other_w}}]})
    hip, left, right = translation(-1, -1, 0), translation(-1.5, -1, 0), translation(-0.5, -1, 0)
    g.j['skins'] = [
        {'joints': [1, 2], 'inverseBindMatrices': g.accessor(FLOAT, 'MAT4', [hip, left])},
        {'joints': [3], 'inverseBindMatrices': g.accessor(FLOAT, 'MAT4', [right])},
        {'joints': [2, 1], 'inverseBindMatrices': g.accessor(FLOAT, 'MAT4', [left, hip])},
        {'joints': [7], 'inverseBindMatrices': g.accessor(FLOAT, 'MAT4', [translation(-5, 0, 0)])},
        {'joints': [1], 'inverseBindMatrices': g.accessor(FLOAT, 'MAT4', [translation(-1, -2, 0)])},
    ]
    times = g.accessor(FLOAT, 'SCALAR', [(0.0,), (1.0,)])
    rot = g.accessor(FLOAT, 'VEC4', [quat_z(0), quat_z(90)])
    move = g.accessor(FLOAT, 'VEC3', [(5, 0, 0), (5, 1, 0)])
    g.j['animations'] = [{'name': 'wave', 'samplers': [{'input': times, 'output': rot}, {'input': times, 'output': move}],
                          'channels': [{'sampler': 0, 'target': {'node': 3, 'path': 'rotation'}},
                                       {'sampler': 1, 'target': {'node': 7, 'path': 'translation'}}]}]
    write_json('multi_skin.gltf', g.finish())


def skinned_morph():
    g = Gltf()
    g.node(name='root', children=[1])                                                     # 0 joint
    g.node(name='neck', translation=[0, 1, 0], children=[2])                              # 1 joint
    g.node(name='head', translation=[0, 1, 0], children=[4])                              # 2 joint
    g.node(name='face', mesh=0, skin=0)                                                   # 3 skinned
    g.node(name='hat', translation=[0, 0.5, 0], rotation=list(quat_z(30)), mesh=1, weights=[0.6])  # 4 rigid

    def blend(y):
        # (joint, weight) pairs along the column: root below 1, neck 1..2, head above 2.
        if y <= 0.75:
            return (0, 0, 0, 0), (1.0, 0.0, 0.0, 0.0)
        if y < 1.25:
            a = (y - 0.75) / 0.5
            return (0, 1, 0, 0), (1 - a, a, 0.0, 0.0)
        if y <= 1.75:
            return (1, 0, 0, 0), (1.0, 0.0, 0.0, 0.0)
        if y < 2.25:
            a = (y - 1.75) / 0.5
            return (1, 2, 0, 0), (1 - a, a, 0.0, 0.0)
        return (2, 0, 0, 0), (1.0, 0.0, 0.0, 0.0)

    prims = []
    for rows in (range(0, 7), range(6, 13)):
        verts = [(x, 0.25 * r, 0.0) for r in rows for x in (-0.5, 0.5)]
        n = len(verts)
        pos = g.accessor(FLOAT, 'VEC3', verts, minmax=True)
        nrm = g.accessor(FLOAT, 'VEC3', [(0, 0, 1)] * n)
        jw = [blend(v[1]) for v in verts]
        joints = g.accessor(UBYTE, 'VEC4', [j for j, _ in jw])
        weights = g.accessor(FLOAT, 'VEC4', [w for _, w in jw])
        quads = []
        for r in range(len(rows) - 1):
            a, b, c, d = 2 * r, 2 * r + 1, 2 * r + 2, 2 * r + 3
            quads += [(a,), (b,), (c,), (c,), (b,), (d,)]
        idx = g.accessor(USHORT, 'SCALAR', quads)
        smile = g.accessor(FLOAT, 'VEC3', [(0.1 * v[1] * (1 if v[0] > 0 else -1), 0.05 * math.sin(3 * v[1]), 0.2)
                                           for v in verts], minmax=True)
        blink_at = [i for i, v in enumerate(verts) if v[1] > 2.4]
        if blink_at:
            blink = g.sparse(FLOAT, 'VEC3', n, None, blink_at, [(0.0, -0.15, 0.05)] * len(blink_at))
            g.j['accessors'][blink]['min'] = [0.0, -0.15, 0.0]
            g.j['accessors'][blink]['max'] = [0.0, 0.0, 0.05]
        else:  # no buffer view, no sparse: all zeros
            g.j['accessors'].append({'componentType': FLOAT, 'count': n, 'type': 'VEC3',
                                     'min': [0.0, 0.0, 0.0], 'max': [0.0, 0.0, 0.0]})
            blink = len(g.j['accessors']) - 1
        first_upper = rows[0] >= 6
        puff = g.accessor(FLOAT, 'VEC3', [(0.3 * v[0], 0.0, 0.1) if first_upper else (0.0, 0.0, 0.0) for v in verts],
                          minmax=True)
        puff_n = g.accessor(FLOAT, 'VEC3', [(0.1, 0.0, 0.0)] * n)
        prims.append({'attributes': {'POSITION': pos, 'NORMAL': nrm, 'JOINTS_0': joints, 'WEIGHTS_0': weights},
                      'indices': idx,
                      'targets': [{'POSITION': smile}, {'POSITION': blink}, {'POSITION': puff, 'NORMAL': puff_n}]})
    g.j['meshes'].append({'name': 'face', 'primitives': prims, 'weights': [0.0, 0.0, 0.25],
                          'extras': {'targetNames': ['smile', 'blink', 'puff']}})
    hat = g.accessor(FLOAT, 'VEC3', [(-0.3, 0, 0), (0.3, 0, 0), (0, 0.4, 0)], minmax=True)
    tall = g.accessor(FLOAT, 'VEC3', [(0, 0, 0), (0, 0, 0), (0.1, 0.5, 0)], minmax=True)
    g.j['meshes'].append({'name': 'hat', 'primitives': [{'attributes': {'POSITION': hat}, 'targets': [{'POSITION': tall}]}],
                          'weights': [0.2]})
    ibm = g.accessor(FLOAT, 'MAT4', [translation(0, 0, 0), translation(0, -1, 0), translation(0, -2, 0)])
    g.j['skins'].append({'joints': [0, 1, 2], 'inverseBindMatrices': ibm})
    t3 = g.accessor(FLOAT, 'SCALAR', [(0.0,), (1.0,), (2.0,)], minmax=True)
    nod = g.accessor(FLOAT, 'VEC4', [quat_z(0), quat_z(25), quat_z(-10)])
    tw = g.accessor(FLOAT, 'SCALAR', [(0.0,), (0.8,), (2.0,)], minmax=True)
    cubic = g.accessor(FLOAT, 'SCALAR', [(x,) for x in (0, 0, 0, 0, 0, 0.25, 1.5, 0, 0,          # key 0: in, value, out
                                                       -0.5, 2, 0, 0.8, 0.5, 0.6, 0.3, -1, 0.2,  # key 1
                                                       0, 0, 0, 0.2, 0.1, 0, 0, 0, 0)])          # key 2
    ts = g.accessor(FLOAT, 'SCALAR', [(0.0,), (0.5,), (1.0,)], minmax=True)
    steps = g.accessor(FLOAT, 'SCALAR', [(x,) for x in (0, 0, 0, 0, 1, 0, 0, 0, 0)])
    g.j['animations'] = [
        {'name': 'talk', 'samplers': [{'input': t3, 'output': nod},
                                      {'input': tw, 'output': cubic, 'interpolation': 'CUBICSPLINE'}],
         'channels': [{'sampler': 0, 'target': {'node': 1, 'path': 'rotation'}},
                      {'sampler': 1, 'target': {'node': 3, 'path': 'weights'}}]},
        {'name': 'blink', 'samplers': [{'input': ts, 'output': steps, 'interpolation': 'STEP'}],
         'channels': [{'sampler': 0, 'target': {'node': 3, 'path': 'weights'}}]},
    ]
    write_json('skinned_morph.gltf', g.finish())
    return g


def containers():
    g = basic()
    with open(os.path.join(HERE, 'basic.glb'), 'wb') as f:
        f.write(g.glb())
    write_json('external_buffer.gltf', g.finish(uri='external_buffer.bin'))
    with open(os.path.join(HERE, 'external_buffer.bin'), 'wb') as f:
        f.write(g.bin)


# ---------------------------------------------------------------------------
# Broken files: each has exactly one defect; test_import.cpp checks the message.

def broken():
    os.makedirs(os.path.join(HERE, 'broken'), exist_ok=True)

    def put(name, j):
        write_json(os.path.join('broken', name), j)

    with open(os.path.join(HERE, 'broken', 'not_gltf.gltf'), 'w') as f:
        f.write('This is a text file, not glTF.\n')

    g = basic()
    j = g.finish()
    del j['skins']
    del j['nodes'][2]['skin']
    put('no_skin.gltf', j)

    j = basic().finish()
    j['accessors'][0]['count'] = 40  # POSITION: 4 vertices in the view, 40 claimed
    put('accessor_out_of_range.gltf', j)

    j = basic().finish()
    j['bufferViews'][0]['byteLength'] = 4096  # view runs past the end of the buffer
    put('view_out_of_range.gltf', j)

    g = basic()
    g.j['accessors'][1]['bufferView'] = g.view(struct.pack('<16B', *([0, 1, 0, 0] * 3 + [0, 5, 0, 0])))
    put('joint_out_of_range.gltf', g.finish())

    g = basic()
    g.j['accessors'][0] = dict(g.j['accessors'][0])
    g.j['accessors'][0]['bufferView'] = g.view(struct.pack('<12f', 0, 0, 0, 1, 0, 0, 0, float('nan'), 0, 1, 2, 0))
    del g.j['accessors'][0]['min'], g.j['accessors'][0]['max']
    put('nan_position.gltf', g.finish())

    g = basic()  # JSON cannot hold NaN, so the bad number sits in the binary keyframe data
    g.j['animations'][0]['samplers'][0]['output'] = g.accessor(FLOAT, 'VEC4', [quat_z(0), (0, 0, float('nan'), 1)])
    put('nan_keyframe.gltf', g.finish())

    j = basic().finish()
    j['nodes'][1]['children'] = [0]  # root -> bone -> root
    put('cyclic_nodes.gltf', j)

    j = basic().finish()
    j['nodes'][1]['children'] = [2]  # the mesh node is now a child of root and of bone
    j['nodes'][0]['children'] = [1, 2]
    put('shared_child.gltf', j)

    j = basic().finish()
    j['buffers'][0]['uri'] = 'missing_buffer.bin'
    put('missing_buffer.gltf', j)

    data = basic().glb()
    with open(os.path.join(HERE, 'broken', 'truncated.glb'), 'wb') as f:
        f.write(data[:len(data) // 2])

    g = basic()
    g.j['accessors'][2]['bufferView'] = g.view(struct.pack('<16f', 1, 0, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0))
    put('zero_weights.gltf', g.finish())

    g = basic()
    g.j['accessors'][2]['bufferView'] = g.view(struct.pack('<16f', 1, 0, 0, 0, 1, 0, 0, 0, 1.5, -0.5, 0, 0, 0, 1, 0, 0))
    put('negative_weight.gltf', g.finish())

    g = basic()
    g.j['animations'][0]['samplers'][0]['input'] = g.accessor(FLOAT, 'SCALAR', [(1.0,), (1.0,)])
    put('bad_key_times.gltf', g.finish())

    g = basic()
    g.j['skins'][0]['inverseBindMatrices'] = g.accessor(FLOAT, 'MAT4', [translation(0, 0, 0)])
    put('ibm_count.gltf', g.finish())


def broken_morphs():
    # Written after skinned_morph(): each has one defect in its morph data.
    def put(name, j):
        write_json(os.path.join('broken', name), j)

    j = json.loads(json.dumps(skinned_morph_json()))
    j['nodes'][4]['weights'] = [0.6, 0.1]  # the hat has 1 target
    put('morph_weights_count.gltf', j)

    j = json.loads(json.dumps(skinned_morph_json()))
    del j['meshes'][0]['primitives'][1]['targets'][2]  # primitive 1: 2 targets, primitive 0: 3
    put('morph_target_count.gltf', j)

    j = json.loads(json.dumps(skinned_morph_json()))
    j['animations'][1]['samplers'][0]['output'] = j['animations'][0]['samplers'][0]['input']  # 3 values, 9 needed
    put('morph_channel_count.gltf', j)


def skinned_morph_json():
    with open(os.path.join(HERE, 'skinned_morph.gltf')) as f:
        return json.load(f)


# ---------------------------------------------------------------------------
# A tail of six joints under an armature node, as tools that export from
# centimetre scenes write it: the armature turns -90 degrees about x and
# scales by `scale`; joints, inverse bind matrices, vertices and the clip's
# translations are in 1/scale units (centimetres for 0.01), so every skinning
# matrix carries the armature's scale. armature_m.gltf is the same character
# with scale 1 (metres): both skin the same mesh in the world.

def armature(scale, name):
    u = 1.0 / scale
    g = Gltf()
    n_joints, seg = 6, 0.3
    g.node(name='Armature', rotation=[-math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)], scale=[scale] * 3, children=[1, n_joints + 1])
    for j in range(n_joints):
        kw = {'name': 'joint%d' % j, 'translation': [0.0, (seg if j else 0.1) * u, 0.0]}
        if j + 1 < n_joints:
            kw['children'] = [j + 2]
        g.node(**kw)
    g.node(name='tail', mesh=0, skin=0)
    # A box around the chain, 4 vertices per ring, one ring per joint and a tip.
    pos, joints, weights = [], [], []
    for r in range(n_joints + 1):
        y = 0.1 + seg * r
        for dx, dz in ((-0.05, -0.05), (0.05, -0.05), (0.05, 0.05), (-0.05, 0.05)):
            pos.append((dx * u, y * u, dz * u))
            a, b = min(r, n_joints - 1), max(r - 1, 0)
            joints.append((a, b, 0, 0))
            weights.append((0.7, 0.3, 0, 0) if a != b else (1, 0, 0, 0))
    idx = []
    for r in range(n_joints):
        for k in range(4):
            a, b = r * 4 + k, r * 4 + (k + 1) % 4
            idx += [(a,), (b,), (a + 4,), (b,), (b + 4,), (a + 4,)]
    pa = g.accessor(FLOAT, 'VEC3', pos, minmax=True)
    ja = g.accessor(UBYTE, 'VEC4', joints)
    wa = g.accessor(FLOAT, 'VEC4', weights)
    ia = g.accessor(USHORT, 'SCALAR', idx)
    g.j['meshes'].append({'primitives': [{'attributes': {'POSITION': pa, 'JOINTS_0': ja, 'WEIGHTS_0': wa}, 'indices': ia}]})
    ibm = g.accessor(FLOAT, 'MAT4', [translation(0, -(0.1 + seg * j) * u, 0) for j in range(n_joints)])
    g.j['skins'].append({'joints': list(range(1, n_joints + 1)), 'inverseBindMatrices': ibm})
    # Two seconds at 30 keys per second: every joint swings, the root walks.
    keys = 61
    times = g.accessor(FLOAT, 'SCALAR', [(k / 30.0,) for k in range(keys)])
    samplers, channels = [], []
    for j in range(n_joints):
        rot = [quat_z(25 * math.sin(2 * math.pi * (k / 60.0) + 0.7 * j)) for k in range(keys)]
        samplers.append({'input': times, 'output': g.accessor(FLOAT, 'VEC4', rot)})
        channels.append({'sampler': j, 'target': {'node': j + 1, 'path': 'rotation'}})
    walk = [(0.4 * math.sin(2 * math.pi * k / 60.0) * u, 0.1 * u, 0.05 * math.cos(4 * math.pi * k / 60.0) * u)
            for k in range(keys)]
    samplers.append({'input': times, 'output': g.accessor(FLOAT, 'VEC3', walk)})
    channels.append({'sampler': n_joints, 'target': {'node': 1, 'path': 'translation'}})
    g.j['animations'].append({'name': 'swing', 'samplers': samplers, 'channels': channels})
    write_json(name, g.finish())


def main():
    armature(0.01, 'armature_cm.gltf')
    armature(1.0, 'armature_m.gltf')
    sparse_quantized()
    eight_influences()
    multi_skin()
    skinned_morph()
    containers()
    broken()
    broken_morphs()


if __name__ == '__main__':
    main()
