#!/usr/bin/env python3
"""Writes a large synthetic skinned character as .glb, for start-up timings
(docs/performance.md) when no large production character is at hand.

usage: python3 scripts/make_big_character.py OUT.glb [--limbs 6] [--bones-per-limb 11] [--vertices 28000]

A root joint with `limbs` chains of `bones-per-limb` joints (default 1 + 6*11 = 67
joints, as a Mixamo biped), a tube of rings around every bone (about `vertices`
vertices in all), each vertex weighted smoothly over up to 3 joints, and two
clips of 4 s (LINEAR rotations at 30 keys per second, every joint with its own
phase). Deterministic; standard library only (tests/data/make_gltf_fixtures.py).
"""
import argparse
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'tests', 'data'))
from make_gltf_fixtures import FLOAT, UBYTE, UINT, Gltf, translation  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('out')
    ap.add_argument('--limbs', type=int, default=6)
    ap.add_argument('--bones-per-limb', type=int, default=11)
    ap.add_argument('--vertices', type=int, default=28000)
    a = ap.parse_args()
    g = Gltf()
    joints, parent, origin, direction = [], [], [], []
    g.node(name='root', children=[])
    joints.append(0), parent.append(-1), origin.append((0.0, 0.0, 0.0)), direction.append((0.0, 1.0, 0.0))
    for limb in range(a.limbs):
        ang = 2 * math.pi * limb / a.limbs
        d = (math.cos(ang), 0.4, math.sin(ang))
        n = math.sqrt(sum(x * x for x in d))
        d = tuple(x / n for x in d)
        p = 0
        for b in range(a.bones_per_limb):
            t = [0.0, 0.5, 0.0] if b == 0 else [x * 0.3 for x in d]
            idx = g.node(name='limb%d_bone%d' % (limb, b), translation=t)
            g.j['nodes'][joints[p]].setdefault('children', []).append(idx)
            o = tuple(origin[p][k] + t[k] for k in range(3))
            joints.append(idx), parent.append(p), origin.append(o), direction.append(d)
            p = len(joints) - 1
    B = len(joints)
    mesh_node = g.node(name='body', mesh=0, skin=0)
    per_bone = max(1, a.vertices // (B - 1))
    ring = 16
    rings = max(1, per_bone // ring)
    pos, jnt, wgt = [], [], []
    for j in range(1, B):
        o, d = origin[j], direction[j]
        u = (d[1], -d[0], 0.0) if abs(d[2]) > 0.5 else (0.0, d[2], -d[1])
        un = math.sqrt(sum(x * x for x in u)) or 1.0
        u = tuple(x / un for x in u)
        w = (d[1] * u[2] - d[2] * u[1], d[2] * u[0] - d[0] * u[2], d[0] * u[1] - d[1] * u[0])
        children = [c for c in range(B) if parent[c] == j]
        for r in range(rings):
            s = (r + 0.5) / rings
            for k in range(ring):
                phi = 2 * math.pi * k / ring
                rad = 0.08 + 0.02 * math.sin(3 * phi + j)
                pos.append(tuple(o[i] + 0.3 * s * d[i] + rad * (math.cos(phi) * u[i] + math.sin(phi) * w[i])
                                 for i in range(3)))
                if s < 0.3 and parent[j] > 0:
                    f = 0.5 + s / 0.6
                    jw = [(j, f), (parent[j], 1 - f)]
                elif s > 0.7 and children:
                    f = 0.5 + (1 - s) / 0.6
                    jw = [(j, f), (children[0], 1 - f)]
                else:
                    jw = [(j, 1.0)]
                jw += [(0, 0.0)] * (4 - len(jw))
                jnt.append(tuple(x for x, _ in jw))
                wgt.append(tuple(x for _, x in jw))
    V = len(pos)
    tris = []
    for j in range(B - 1):
        base = j * rings * ring
        for r in range(rings - 1):
            for k in range(ring):
                a0 = base + r * ring + k
                a1 = base + r * ring + (k + 1) % ring
                tris += [(a0,), (a1,), (a0 + ring,), (a0 + ring,), (a1,), (a1 + ring,)]
    p_acc = g.accessor(FLOAT, 'VEC3', pos, minmax=True)
    j_acc = g.accessor(UBYTE, 'VEC4', jnt)
    w_acc = g.accessor(FLOAT, 'VEC4', wgt)
    i_acc = g.accessor(UINT, 'SCALAR', tris)
    g.j['meshes'].append({'name': 'body', 'primitives': [{'attributes': {'POSITION': p_acc, 'JOINTS_0': j_acc,
                                                                         'WEIGHTS_0': w_acc}, 'indices': i_acc}]})
    ibm = g.accessor(FLOAT, 'MAT4', [translation(-o[0], -o[1], -o[2]) for o in origin])
    g.j['skins'].append({'joints': joints, 'inverseBindMatrices': ibm})
    keys = 121
    times = g.accessor(FLOAT, 'SCALAR', [(i / 30.0,) for i in range(keys)], minmax=True)
    for clip, amp in (('sway', 0.35), ('wave', 0.7)):
        samplers, channels = [], []
        for j in range(B):
            axis = (0.0, 0.0, 1.0) if j % 2 else (1.0, 0.0, 0.0)
            q = []
            for i in range(keys):
                h = 0.5 * amp * math.sin(2 * math.pi * i / (keys - 1) * (1 + j % 3) + j)
                q.append((axis[0] * math.sin(h), axis[1] * math.sin(h), axis[2] * math.sin(h), math.cos(h)))
            samplers.append({'input': times, 'output': g.accessor(FLOAT, 'VEC4', q)})
            channels.append({'sampler': len(samplers) - 1, 'target': {'node': joints[j], 'path': 'rotation'}})
        g.j['animations'].append({'name': clip, 'samplers': samplers, 'channels': channels})
    with open(a.out, 'wb') as f:
        f.write(g.glb())
    print('%s: %d joints, %d vertices, %d triangles, 2 clips of %.1f s' % (a.out, B, V, len(tris) // 3,
                                                                           (keys - 1) / 30.0))
    del mesh_node


if __name__ == '__main__':
    main()
