#!/usr/bin/env python3
"""Writes a skinned humanoid .glb from a BVH motion-capture file: the BVH's
skeleton and motion, hands with fingers, and a mesh of capsules around the
bones. For the scenes of humanoids that docs/performance.md measures (issue 27:
bits per bone on the wire with four humanoids of at least 40 bones).

usage: python3 scripts/make_humanoid.py IN.bvh [-o OUT.glb] [--fps 30] [--no-fingers] [--in-place]

Made for the CMU motion-capture BVH conversions (Bruce Hahne's "cmuconvert"
set; tested with subject 131 trial 01, cmu_131_01.bvh: 31 joints, 120 frames
per second, 994 frames, Start Walk Stop; "The data used in this project was
obtained from mocap.cs.cmu.edu. The database was created with funding from
NSF EIA-0196217."), and reads any BVH of the common layout.

Units and axes: those BVH files are Y-up and right-handed with the character
facing +Z and its left on +X (the glTF convention), in the CMU ASF's length
unit, 1/0.45 inch (0.0254 / 0.45 = 0.05644 m): every length is scaled by
--scale (default that factor) to metres; no axis changes. Euler channels are
applied in the order listed (Zrotation Yrotation Xrotation: R = Rz Ry Rx).

Skeleton: every BVH joint (End Sites are not joints), in the BVH's order.
With fingers (the default) each hand gets five fingers of three joints
(Mixamo's LeftHandIndex1..3 and so on): index, middle, ring and pinky under
the BVH's LFingers/RFingers joint (the knuckles), the thumb under
LThumb/RThumb. With the CMU skeleton that is 31 + 2 x 15 = 61 joints
(31 with --no-fingers).

Mesh: a capsule (rings of 8-12 vertices, round caps) around every bone
segment (a joint to each child or End Site), in the bind pose (BVH rest pose,
the hips at their first frame's height), each vertex weighted smoothly over
up to 4 joints of its bone's line (ancestors and descendants, inverse fourth
power of the distance to their segments, weights under 2 % dropped): 5,226
vertices and 10,200 triangles for the CMU skeleton with fingers (3,362 and
6,616 without).

Animation: one clip, "mocap", resampled from the BVH at --fps keys per second
(default 30; LINEAR: rotations slerped, translations lerped between BVH
frames), the root's translation (the walk included; --in-place holds its
horizontal part at the first frame's) and every joint's rotation. The finger motion is synthetic (the motion capture has none): a
gentle curl and release of every finger, each finger a little behind the
previous one, period 2.4 s, 10-35 degrees per joint.

Deterministic; standard library only (tests/data/make_gltf_fixtures.py).
Exit codes: 0 ok, 1 the BVH cannot be read or is malformed (the message names
the file and line), 2 bad arguments.
"""
import argparse
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'tests', 'data'))
from make_gltf_fixtures import FLOAT, UBYTE, UINT, Gltf, translation  # noqa: E402

PROG = 'make_humanoid.py'
CMU_SCALE = 0.0254 / 0.45


class BvhError(Exception):
    pass


# ---------------------------------------------------------------------------
# Quaternions (x, y, z, w)

def qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def qaxis(axis, rad):
    s = math.sin(rad / 2)
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(rad / 2))


def qnorm(q):
    n = math.sqrt(sum(c * c for c in q)) or 1.0
    return tuple(c / n for c in q)


def qslerp(a, b, t):
    d = sum(x * y for x, y in zip(a, b))
    if d < 0:
        b, d = tuple(-c for c in b), -d
    if d > 0.9995:
        return qnorm(tuple(x + t * (y - x) for x, y in zip(a, b)))
    th = math.acos(min(1.0, d))
    s = math.sin(th)
    wa, wb = math.sin((1 - t) * th) / s, math.sin(t * th) / s
    return qnorm(tuple(wa * x + wb * y for x, y in zip(a, b)))


AXES = {'X': (1.0, 0.0, 0.0), 'Y': (0.0, 1.0, 0.0), 'Z': (0.0, 0.0, 1.0)}


# ---------------------------------------------------------------------------
# BVH

class Joint:
    def __init__(self, name, parent, offset):
        self.name, self.parent, self.offset = name, parent, offset
        self.channels = []   # ('position' | 'rotation', 'X' | 'Y' | 'Z')
        self.first = 0       # index of its first channel in a frame
        self.ends = []       # End Site offsets
        self.children = []


def read_bvh(path):
    """Joints (depth-first, parents first), frame time, frames (lists of floats)."""
    try:
        with open(path, encoding='latin-1') as f:
            text = f.read()
    except OSError as e:
        raise BvhError('cannot read: %s' % (e.strerror or e))
    tokens = []
    for n, line in enumerate(text.splitlines(), 1):
        tokens += [(t, n) for t in line.split()]
    pos = [0]

    def peek():
        return tokens[pos[0]][0] if pos[0] < len(tokens) else None

    def take(what=None, exact=True):
        if pos[0] >= len(tokens):
            raise BvhError('line %d: unexpected end of file%s' % (tokens[-1][1] if tokens else 0,
                                                                  ' (expected %s)' % what if what else ''))
        t, n = tokens[pos[0]]
        pos[0] += 1
        if exact and what is not None and t != what:
            raise BvhError('line %d: expected %s, found %r' % (n, what, t))
        return t

    def line():
        return tokens[min(pos[0], len(tokens) - 1)][1] if tokens else 0

    def number():
        n = line()
        t = take('a number', False)
        try:
            v = float(t)
        except ValueError:
            raise BvhError('line %d: expected a number, found %r' % (n, t))
        if not math.isfinite(v):
            raise BvhError('line %d: %r is not a finite number' % (n, t))
        return v

    joints = []
    nchan = [0]

    def joint(parent):
        name = take()
        take('{')
        take('OFFSET')
        j = Joint(name, parent, tuple(number() for _ in range(3)))
        index = len(joints)
        joints.append(j)
        if parent is not None:
            joints[parent].children.append(index)
        if peek() == 'CHANNELS':
            take()
            n = line()
            count = take()
            if not count.isdigit():
                raise BvhError('line %d: expected a channel count, found %r' % (n, count))
            j.first = nchan[0]
            for _ in range(int(count)):
                n = line()
                c = take()
                kind = {'position': 'position', 'rotation': 'rotation'}.get(c[1:].lower())
                if kind is None or c[0].upper() not in AXES:
                    raise BvhError('line %d: unknown channel %r' % (n, c))
                j.channels.append((kind, c[0].upper()))
            nchan[0] += len(j.channels)
        while peek() != '}':
            n = line()
            t = take('JOINT, End Site or }', False)
            if t == 'JOINT':
                joint(index)
            elif t == 'End':
                take('Site')
                take('{')
                take('OFFSET')
                j.ends.append(tuple(number() for _ in range(3)))
                take('}')
            else:
                raise BvhError('line %d: expected JOINT, End Site or }, found %r' % (n, t))
        take('}')

    take('HIERARCHY')
    take('ROOT')
    joint(None)
    if peek() == 'ROOT':
        raise BvhError('line %d: more than one ROOT (one skeleton per file)' % line())
    take('MOTION')
    take('Frames:')
    n = line()
    frames = take('a frame count', False)
    if not frames.isdigit() or int(frames) < 1:
        raise BvhError('line %d: expected a frame count of at least 1, found %r' % (n, frames))
    take('Frame')
    take('Time:')
    n = line()
    frame_time = number()
    if frame_time <= 0:
        raise BvhError('line %d: the frame time must be positive' % n)
    data = []
    for _ in range(int(frames)):
        data.append([number() for _ in range(nchan[0])])
    if peek() is not None:
        raise BvhError('line %d: more numbers than %s frames of %d channels' % (line(), frames, nchan[0]))
    return joints, frame_time, data


def local_pose(j, frame):
    """A joint's translation (BVH units) and rotation in one frame."""
    t = list(j.offset)
    q = (0.0, 0.0, 0.0, 1.0)
    for i, (kind, axis) in enumerate(j.channels):
        v = frame[j.first + i]
        if kind == 'position':
            t['XYZ'.index(axis)] += v
        else:
            q = qmul(q, qaxis(AXES[axis], math.radians(v)))
    return t, qnorm(q)


# ---------------------------------------------------------------------------
# Fingers (synthetic): (name, joint offsets from the knuckle joint, BVH units)

FINGERS = (  # name, lateral z, knuckle y, segment lengths (BVH units; 1 = 5.6 cm)
    ('Index', 0.42, 0.00, (0.72, 0.44, 0.34)),
    ('Middle', 0.14, -0.03, (0.78, 0.50, 0.37)),
    ('Ring', -0.14, -0.02, (0.72, 0.46, 0.34)),
    ('Pinky', -0.40, 0.05, (0.56, 0.34, 0.30)),
)
THUMB = (0.55, 0.44, 0.36)
CURL = ((10, 15), (12, 20), (8, 14))  # per joint level: base and amplitude, degrees
THUMB_CURL = ((4, 8), (6, 12), (6, 12))
PERIOD = 2.4


class Bone:
    """A joint of the output skeleton."""

    def __init__(self, name, parent, offset, bvh=None, curl=None):
        self.name, self.parent, self.offset, self.bvh, self.curl = name, parent, offset, bvh, curl
        self.ends = []
        self.children = []


def skeleton(bvh, fingers):
    bones = []

    def add(b):
        bones.append(b)
        if b.parent is not None:
            bones[b.parent].children.append(len(bones) - 1)
        return len(bones) - 1

    def hand(knuckles, thumb, side):
        """Fingers under the knuckle joint, the thumb under the thumb joint; side +1 left, -1 right."""
        prefix = 'LeftHand' if side > 0 else 'RightHand'
        axis = (0.0, 0.0, -float(side))  # flexion: the tip towards the palm (-X left, +X right)
        for k, (name, z, y, lengths) in enumerate(FINGERS):
            p, off = knuckles, (0.0, y, z)
            for level in range(3):
                p = add(Bone('%s%s%d' % (prefix, name, level + 1), p, off,
                             curl=(axis, CURL[level], 0.35 * k + (0.0 if side > 0 else 1.6))))
                off = (0.0, -lengths[level], 0.0)
            bones[p].ends.append(off)
        d = (0.0, -math.sqrt(0.5), math.sqrt(0.5))  # down and forward, as the BVH's thumb End Site
        taxis = (0.0, -side * math.sqrt(0.5), -side * math.sqrt(0.5))
        p, off = thumb, (-0.08 * side, -0.12, 0.22)
        for level in range(3):
            p = add(Bone('%sThumb%d' % (prefix, level + 1), p, off,
                         curl=(taxis, THUMB_CURL[level], 1.4 + (0.0 if side > 0 else 1.6))))
            off = tuple(THUMB[level] * c for c in d)
        bones[p].ends.append(off)

    def visit(i, parent):
        j = bvh[i]
        me = add(Bone(j.name, parent, j.offset, bvh=i))
        for c in j.children:
            visit(c, me)
        low = j.name.lower()
        if fingers and low in ('lfingers', 'rfingers', 'lthumb', 'rthumb'):
            return
        bones[me].ends = list(j.ends)

    visit(0, None)
    if fingers:
        names = {b.name.lower(): i for i, b in enumerate(bones)}
        for side, k, t in ((1, 'LFingers', 'LThumb'), (-1, 'RFingers', 'RThumb')):
            for want in (k, t):
                if want.lower() not in names:
                    raise BvhError('--fingers needs joints named LFingers, LThumb, RFingers and RThumb '
                                   '(the CMU layout); this file has no %s (use --no-fingers)' % want)
            hand(names[k.lower()], names[t.lower()], side)
    return bones


def curl_rotation(curl, t):
    axis, (base, amp), phase = curl
    c = 0.5 - 0.5 * math.cos(2 * math.pi * t / PERIOD - phase)
    return qaxis(axis, math.radians(base + amp * c))


# ---------------------------------------------------------------------------
# Mesh

RADIUS = {  # metres, by the name of the joint whose segment it is (lower case)
    'lhipjoint': 0.085, 'rhipjoint': 0.085, 'lefthip': 0.07, 'righthip': 0.07, 'leftknee': 0.052,
    'rightknee': 0.052, 'leftankle': 0.042, 'rightankle': 0.042, 'lefttoe': 0.032, 'righttoe': 0.032,
    'lowerback': 0.12, 'chest': 0.13, 'chest2': 0.12, 'lowerneck': 0.05, 'neck': 0.045, 'head': 0.09,
    'leftcollar': 0.055, 'rightcollar': 0.055, 'leftshoulder': 0.045, 'rightshoulder': 0.045,
    'leftelbow': 0.036, 'rightelbow': 0.036, 'leftwrist': 0.03, 'rightwrist': 0.03, 'lhand': 0.028,
    'rhand': 0.028, 'lfingers': 0.011, 'rfingers': 0.011, 'lthumb': 0.012, 'rthumb': 0.012,
}


def radius(name):
    low = name.lower()
    if low in RADIUS:
        return RADIUS[low]
    if 'thumb' in low:
        return 0.0105 - 0.0008 * int(low[-1])
    if 'hand' in low:
        return 0.0095 - 0.0008 * int(low[-1])
    return 0.04


def seg_dist(p, a, b):
    ab = [b[i] - a[i] for i in range(3)]
    ap = [p[i] - a[i] for i in range(3)]
    L = sum(x * x for x in ab)
    t = 0.0 if L == 0 else max(0.0, min(1.0, sum(ab[i] * ap[i] for i in range(3)) / L))
    return math.sqrt(sum((ap[i] - t * ab[i]) ** 2 for i in range(3)))


def build_mesh(bones, origin, scale):
    """Positions, joint indices, weights and triangles of capsules around every bone segment."""
    B = len(bones)
    segs = [[] for _ in range(B)]  # per joint: its segments (start, end), world, metres
    for i, b in enumerate(bones):
        ends = [origin[c] for c in b.children]
        ends += [tuple(origin[i][k] + e[k] * scale for k in range(3)) for e in b.ends]
        for e in ends:
            if math.dist(origin[i], e) > 1e-6:
                segs[i].append((origin[i], e))

    def lineage(i):
        out, p, depth = [i], bones[i].parent, 0
        while p is not None and depth < 3:
            out.append(p)
            p, depth = bones[p].parent, depth + 1
        frontier = [i]
        for _ in range(3):
            frontier = [c for f in frontier for c in bones[f].children]
            out += frontier
        return out

    pos, jnt, wgt, tris = [], [], [], []
    for i in range(B):
        R = radius(bones[i].name)
        n = 12 if R >= 0.03 else 8
        near = lineage(i)
        for a, e in segs[i]:
            L = math.dist(a, e)
            d = tuple((e[k] - a[k]) / L for k in range(3))
            u = (d[1], -d[0], 0.0) if abs(d[2]) < 0.9 else (0.0, d[2], -d[1])
            un = math.sqrt(sum(x * x for x in u))
            u = tuple(x / un for x in u)
            w = (d[1] * u[2] - d[2] * u[1], d[2] * u[0] - d[0] * u[2], d[0] * u[1] - d[1] * u[0])
            rings = max(2, int(math.ceil(L / 0.03)) + 1)
            profile = [(-R * math.sin(a_), R * math.cos(a_)) for a_ in (math.radians(60), math.radians(30))]
            profile += [(L * r / (rings - 1), R) for r in range(rings)]
            profile += [(L + R * math.sin(a_), R * math.cos(a_)) for a_ in (math.radians(30), math.radians(60))]
            first = len(pos)

            def vertex(p):
                cand = []
                for k in near:
                    dist = min((seg_dist(p, s0, s1) for s0, s1 in segs[k]), default=None)
                    if dist is None:
                        dist = math.dist(p, origin[k])
                    cand.append((max(dist, 1e-4) ** -4, k))
                cand.sort(key=lambda c: (-c[0], c[1]))
                cand = cand[:4]
                total = sum(c[0] for c in cand)
                cand = [(c[0] / total, c[1]) for c in cand if c[0] / total >= 0.02]
                total = sum(c[0] for c in cand)
                cand = [(c[0] / total, c[1]) for c in cand] + [(0.0, 0)] * (4 - len(cand))
                pos.append(tuple(p))
                jnt.append(tuple(c[1] for c in cand))
                wgt.append(tuple(c[0] for c in cand))
                return len(pos) - 1

            south = vertex(tuple(a[k] - R * d[k] for k in range(3)))
            for x, r in profile:
                for m in range(n):
                    phi = 2 * math.pi * m / n
                    vertex(tuple(a[k] + x * d[k] + r * (math.cos(phi) * u[k] + math.sin(phi) * w[k])
                                 for k in range(3)))
            north = vertex(tuple(e[k] + R * d[k] for k in range(3)))
            ring0 = first + 1
            for m in range(n):
                tris.append((south, ring0 + (m + 1) % n, ring0 + m))
            for r in range(len(profile) - 1):
                base = ring0 + r * n
                for m in range(n):
                    a0, a1 = base + m, base + (m + 1) % n
                    tris += [(a0, a1, a0 + n), (a0 + n, a1, a1 + n)]
            last = ring0 + (len(profile) - 1) * n
            for m in range(n):
                tris.append((north, last + m, last + (m + 1) % n))
    return pos, jnt, wgt, tris


# ---------------------------------------------------------------------------

def positive_float(text):
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError('%r is not a number' % text)
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError('%r must be a positive number' % text)
    return v


def main():
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split('\n\n')[0],
                                 epilog='Details: the docstring at the top of scripts/make_humanoid.py.')
    ap.add_argument('bvh', metavar='IN.bvh', help='motion capture (e.g. CMU cmu_131_01.bvh)')
    ap.add_argument('-o', '--output', metavar='OUT.glb', help='output .glb (default: IN with .glb, in the current folder)')
    ap.add_argument('--fps', type=positive_float, default=30.0, help='animation keys per second (default 30)')
    ap.add_argument('--fingers', action=argparse.BooleanOptionalAction, default=True,
                    help='add five fingers of three joints to each hand (default on; the finger motion is synthetic)')
    ap.add_argument('--in-place', action='store_true',
                    help="hold the root's horizontal translation at its first frame's (no walk; for comparisons)")
    ap.add_argument('--scale', type=positive_float, default=CMU_SCALE,
                    help='metres per BVH unit (default 0.0254/0.45 = %.5f, the CMU ASF unit)' % CMU_SCALE)
    ap.add_argument('--armature-scale', type=positive_float, metavar='A',
                    help='write every length in metres / A and put the skeleton and the mesh under an '
                         '"Armature" node scaling by A, as tools exporting from centimetre scenes do '
                         '(A = 0.01): the same character in the world, every skinning matrix scaled by A')
    a = ap.parse_args()
    if a.fps > 1000:
        ap.error('--fps %g: at most 1000 keys per second' % a.fps)
    out = a.output or os.path.splitext(os.path.basename(a.bvh))[0] + '.glb'
    try:
        bvh, frame_time, frames = read_bvh(a.bvh)
        bones = skeleton(bvh, a.fingers)
    except BvhError as e:
        print('%s: %s: %s' % (PROG, a.bvh, e), file=sys.stderr)
        return 1
    if len(bones) > 255:
        print('%s: %s: %d joints, more than the 255 this writer indexes' % (PROG, a.bvh, len(bones)), file=sys.stderr)
        return 1
    s = a.scale
    per_m = 1.0 / (a.armature_scale or 1.0)  # written lengths per metre
    B = len(bones)

    # Per BVH frame: every BVH joint's translation (metres) and rotation, signs continuous.
    poses = []
    for f in frames:
        poses.append([local_pose(j, f) for j in bvh])
    for i in range(1, len(poses)):
        for k in range(len(bvh)):
            q0, q1 = poses[i - 1][k][1], poses[i][k][1]
            if sum(x * y for x, y in zip(q0, q1)) < 0:
                poses[i][k] = (poses[i][k][0], tuple(-c for c in q1))

    # Bind pose: the BVH rest pose (rotations identity), the root at its first frame's height.
    root_bind = (bones[0].offset[0] * s, poses[0][0][0][1] * s, bones[0].offset[2] * s)
    origin = []
    for i, b in enumerate(bones):
        if b.parent is None:
            origin.append(root_bind)
        else:
            o = origin[b.parent]
            origin.append(tuple(o[k] + b.offset[k] * s for k in range(3)))

    g = Gltf()
    g.j['asset']['generator'] = 'progskin scripts/make_humanoid.py'
    g.j['asset']['copyright'] = ('Motion: mocap.cs.cmu.edu (created with funding from NSF EIA-0196217), '
                                 'BVH conversion by Bruce Hahne; finger motion synthetic')
    for i, b in enumerate(bones):
        t = list(root_bind) if b.parent is None else [c * s for c in b.offset]
        g.node(name=b.name, translation=[c * per_m for c in t] if a.armature_scale else t)
    for i, b in enumerate(bones):
        if b.children:
            g.j['nodes'][i]['children'] = list(b.children)
    pos, jnt, wgt, tris = build_mesh(bones, origin, s)
    if a.armature_scale:
        pos = [tuple(c * per_m for c in p) for p in pos]
    g.node(name='body', mesh=0, skin=0)
    p_acc = g.accessor(FLOAT, 'VEC3', pos, minmax=True)
    j_acc = g.accessor(UBYTE, 'VEC4', jnt)
    w_acc = g.accessor(FLOAT, 'VEC4', wgt)
    i_acc = g.accessor(UINT, 'SCALAR', [(v,) for tri in tris for v in tri])
    g.j['meshes'].append({'name': 'body', 'primitives': [{'attributes': {'POSITION': p_acc, 'JOINTS_0': j_acc,
                                                                         'WEIGHTS_0': w_acc}, 'indices': i_acc}]})
    ibm = g.accessor(FLOAT, 'MAT4', [translation(-o[0] * per_m, -o[1] * per_m, -o[2] * per_m) for o in origin])
    g.j['skins'].append({'name': 'humanoid', 'joints': list(range(B)), 'inverseBindMatrices': ibm, 'skeleton': 0})

    # The clip: BVH frames resampled at --fps (rotations slerped, translations lerped).
    duration = (len(frames) - 1) * frame_time
    keys = int(math.floor(duration * a.fps + 1e-6)) + 1
    times = [k / a.fps for k in range(keys)]
    samples = []
    for t in times:
        x = min(t / frame_time, len(frames) - 1)
        f0 = min(int(math.floor(x)), len(frames) - 1)
        f1 = min(f0 + 1, len(frames) - 1)
        samples.append((f0, f1, x - f0))
    t_acc = g.accessor(FLOAT, 'SCALAR', [(t,) for t in times], minmax=True)
    samplers, channels = [], []

    def channel(node, path, values):
        samplers.append({'input': t_acc, 'output': g.accessor(FLOAT, 'VEC4' if path == 'rotation' else 'VEC3', values),
                         'interpolation': 'LINEAR'})
        channels.append({'sampler': len(samplers) - 1, 'target': {'node': node, 'path': path}})

    for i, b in enumerate(bones):
        if b.bvh is not None:
            j = bvh[b.bvh]
            if any(kind == 'position' for kind, _ in j.channels):
                vals = []
                for f0, f1, u in samples:
                    t0, t1 = poses[f0][b.bvh][0], poses[f1][b.bvh][0]
                    v = [(t0[k] + u * (t1[k] - t0[k])) * s for k in range(3)]
                    if a.in_place and b.parent is None:
                        v[0], v[2] = poses[0][b.bvh][0][0] * s, poses[0][b.bvh][0][2] * s
                    vals.append(tuple(c * per_m for c in v))
                channel(i, 'translation', vals)
            if any(kind == 'rotation' for kind, _ in j.channels):
                channel(i, 'rotation', [qslerp(poses[f0][b.bvh][1], poses[f1][b.bvh][1], u) for f0, f1, u in samples])
        elif b.curl is not None:
            channel(i, 'rotation', [curl_rotation(b.curl, t) for t in times])
    g.j['animations'].append({'name': 'mocap', 'samplers': samplers, 'channels': channels})
    if a.armature_scale:
        g.node(name='Armature', scale=[a.armature_scale] * 3, children=[0, B])
    try:
        with open(out, 'wb') as f:
            f.write(g.glb())
    except OSError as e:
        print('%s: %s: cannot write: %s' % (PROG, out, e.strerror or e), file=sys.stderr)
        return 1
    print('%s: %d joints (%d from the BVH), %d vertices, %d triangles, clip "mocap" %.2f s, %d keys at %g/s'
          % (out, B, len(bvh), len(pos), len(tris), times[-1], keys, a.fps))
    return 0


if __name__ == '__main__':
    sys.exit(main())
