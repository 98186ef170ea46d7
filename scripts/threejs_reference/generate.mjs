// generate.mjs — world-space skinned vertex positions computed by three.js, as an
// independent reference for progskin's glTF importer and animation sampler.
//
// For each asset: load it with GLTFLoader.parse (textures stubbed out), play the
// chosen clips with an AnimationMixer at a few times, and write every skinned
// vertex (and every mesh rigidly under a bone) in progskin's vertex order: mesh
// nodes by glTF node index, then primitives, then accessor order.
//
// Usage: npm install && node generate.mjs [assets dir] [output dir]
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';

const here = path.dirname(fileURLToPath(import.meta.url));
const assetsDir = path.resolve(process.argv[2] ?? path.join(here, '../../assets'));
const outDir = path.resolve(process.argv[3] ?? path.join(here, '../../tests/data/threejs'));

// clip: progskin --clip spec (select_clips); names: the three.js clips played together.
// dir: the file's folder relative to the repository root (default: the assets dir).
const jobs = [
  { file: 'RiggedSimple.gltf', clip: 'all' },
  { file: 'CesiumMan.glb', clip: 'all' },
  { file: 'Fox.glb', clip: 'Survey' },
  { file: 'skinned_morph.gltf', clip: 'talk', dir: 'tests/data' },
];
const requestedTimes = [0.0, 0.37, 1.1];

// FileLoader (used for data: URIs and external .bin files) reports progress with a
// browser-only event class.
globalThis.ProgressEvent ??= class ProgressEvent extends Event {
  constructor(type, init = {}) {
    super(type);
    Object.assign(this, init);
  }
};

// Never decode images: every texture resolves to null (geometry does not need them).
class NoTextures {
  constructor() { this.name = 'progskin_no_textures'; }
  loadTexture() { return Promise.resolve(null); }
}

function parseGltf(file) {
  const bytes = fs.readFileSync(file);
  const data = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
  const loader = new GLTFLoader();
  loader.register(() => new NoTextures());
  return new Promise((resolve, reject) => loader.parse(data, path.dirname(file) + '/', resolve, reject));
}

// Node index of a mesh object (the node itself, or the group of a multi-primitive mesh).
function nodeIndexOf(parser, object) {
  for (let o = object; o; o = o.parent) {
    const a = parser.associations.get(o);
    if (a && a.nodes !== undefined) return a.nodes;
  }
  return undefined;
}

function hasBoneAncestor(object) {
  for (let o = object.parent; o; o = o.parent) if (o.isBone) return true;
  return false;
}

// Mesh objects in progskin order: (node index, primitive index).
function orderedMeshes(gltf) {
  const parser = gltf.parser;
  const list = [];
  gltf.scene.traverse((o) => {
    if (!o.isMesh) return;
    if (!o.isSkinnedMesh && !hasBoneAncestor(o)) return;
    const a = parser.associations.get(o) ?? {};
    list.push({ mesh: o, node: nodeIndexOf(parser, o), primitive: a.primitives ?? 0 });
  });
  list.sort((x, y) => x.node - y.node || x.primitive - y.primitive);
  return list;
}

// World-space positions of all listed meshes as rendered by three.js. getVertexPosition
// applies the morph targets at the mesh's morphTargetInfluences and then, for a skinned
// mesh, applyBoneTransform (glTF order: morphs, then skinning). In AttachedBindMode
// bindMatrixInverse = inverse(matrixWorld), so matrixWorld * applyBoneTransform(v) is
// sum w * G * IBM * v: the skinned mesh node's own transform cancels, as glTF requires.
function worldPositions(list) {
  const out = [];
  const v = new THREE.Vector3();
  for (const { mesh } of list) {
    const pos = mesh.geometry.attributes.position;
    for (let i = 0; i < pos.count; ++i) {
      mesh.getVertexPosition(i, v);
      v.applyMatrix4(mesh.matrixWorld);
      out.push(v.x, v.y, v.z);
    }
  }
  return out;
}

const round6 = (x) => Number(x.toPrecision(6));

async function run(job) {
  const gltf = await parseGltf(path.join(job.dir ? path.join(here, '../..', job.dir) : assetsDir, job.file));
  const clips = job.clip === 'all' ? gltf.animations : gltf.animations.filter((c) => c.name === job.clip);
  if (clips.length === 0) throw new Error(`${job.file}: no clip ${job.clip}`);
  let start = Infinity, end = -Infinity;
  for (const clip of clips)
    for (const track of clip.tracks) {
      start = Math.min(start, track.times[0]);
      end = Math.max(end, track.times[track.times.length - 1]);
    }

  const mixer = new THREE.AnimationMixer(gltf.scene);
  for (const clip of clips) {
    const action = mixer.clipAction(clip);
    action.setLoop(THREE.LoopOnce, 1);
    action.clampWhenFinished = true;
    action.play();
  }
  const list = orderedMeshes(gltf);
  const frames = [];
  for (const requested of requestedTimes) {
    const t = Math.min(Math.max(requested, start), end);
    mixer.setTime(t);
    gltf.scene.updateMatrixWorld(true);
    frames.push({ time: t, positions: worldPositions(list).map(round6) });
  }
  const result = {
    asset: job.file,
    clip: job.clip,
    generator: `three.js r${THREE.REVISION} GLTFLoader + AnimationMixer + SkinnedMesh.applyBoneTransform`,
    vertex_count: frames[0].positions.length / 3,
    meshes: list.map(({ node, primitive, mesh }) => ({ node, primitive, count: mesh.geometry.attributes.position.count })),
    frames,
  };
  fs.mkdirSync(outDir, { recursive: true });
  const name = path.join(outDir, job.file.replace(/\.(gltf|glb)$/, '.json'));
  fs.writeFileSync(name, JSON.stringify(result) + '\n');
  console.log(`${name}: ${result.vertex_count} vertices, times ${frames.map((f) => f.time).join(', ')}`);
}

for (const job of jobs) await run(job);
