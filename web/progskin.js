// progskin.js — the browser client's page (docs/browser.md). The client
// session is the C++ one compiled to WebAssembly (web/wasm_api.cpp); this
// file only moves bytes between the WebSocket and it (every message whole,
// kind byte included, both ways: no protocol here), and draws what it
// displays with three.js: one SkinnedMesh per character whose bone matrices
// are the streamed palette (12 floats per bone, progressive order, relative
// to the character's root), so the GPU skins.
//
// window.progskin.stats() -> {state, characters, bones_mean, rate_kbps,
// frames_displayed} (scripts rely on these names); the address takes
// ?max_kbps=N, ?server=ws://HOST:PORT/ws, ?snap_to_ticks=1, ?record_every=N
// (keep the palette of every N-th server tick for window.progskin.recorded()).
import * as THREE from './three.module.js';
import createProgskinWasm from './progskin_wasm.js';

const params = new URLSearchParams(location.search);
const maxKbps = Math.max(0, Number(params.get('max_kbps') || 0)) || 0;
const snap = params.get('snap_to_ticks') === '1';
const recordEvery = Math.max(0, Math.floor(Number(params.get('record_every') || 0))) || 0;
const wsUrl = params.get('server') ||
    (location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/ws';
const STATES = ['idle', 'connecting', 'streaming', 'closed', 'failed'];
const now = () => performance.now() / 1000;

const M = await createProgskinWasm();
const w = M._pskw_create(maxKbps, 0, snap ? 1 : 0);
const heapF32 = (ptr, n) => new Float32Array(M.HEAPF32.buffer, ptr, n);

// ----------------------------------------------------------- transport --
let ws = null;
let bytesIn = 0;
function connect() {
    const peer = new URL(wsUrl).host;
    const len = M.lengthBytesUTF8(peer) + 1;
    const p = M._malloc(len);
    M.stringToUTF8(peer, p, len);
    M._pskw_start(w, now(), p);
    M._free(p);
    ws = new WebSocket(wsUrl);
    ws.binaryType = 'arraybuffer';
    ws.onopen = () => { M._pskw_open(w); flush(); };
    ws.onmessage = (ev) => {
        const b = new Uint8Array(ev.data);
        bytesIn += b.length;
        const p = M._pskw_in_buffer(w, b.length);
        if (p) M.HEAPU8.set(b, p);
        M._pskw_receive(w, b.length, now());
    };
    ws.onclose = () => M._pskw_closed(w);
    ws.onerror = () => {};
}
// What the session has to send, message by message, onto the socket.
function flush() {
    if (!ws || ws.readyState !== WebSocket.OPEN) return;
    const n = M._pskw_take_outgoing(w);
    for (let i = 0; i < n; ++i) {
        const p = M._pskw_outgoing(w, i), len = M._pskw_outgoing_size(w, i);
        ws.send(M.HEAPU8.slice(p, p + len));
    }
}

// --------------------------------------------------------------- scene --
const canvas = document.getElementById('view');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio || 1);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x20242b);
const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 10000);
scene.add(new THREE.HemisphereLight(0xffffff, 0x404050, 2.0));
const sun = new THREE.DirectionalLight(0xffffff, 2.0);
sun.position.set(3, 10, 6);
scene.add(sun);
const grid = new THREE.GridHelper(1, 20, 0x606878, 0x3a404a);
scene.add(grid);
function resize() {
    const wdt = canvas.clientWidth || window.innerWidth, h = canvas.clientHeight || window.innerHeight;
    renderer.setSize(wdt, h, false);
    camera.aspect = wdt / h;
    camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

const geometries = new Map();  // asset index -> BufferGeometry (bind pose, progressive bone indices)
function geometryOf(a) {
    if (geometries.has(a)) return geometries.get(a);
    const nv = M._pskw_asset_vertex_count(w, a);
    if (nv <= 0) return null;
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.Float32BufferAttribute(heapF32(M._pskw_asset_positions(w, a), nv * 3).slice(), 3));
    const np = M._pskw_asset_normals(w, a);
    if (np) g.setAttribute('normal', new THREE.Float32BufferAttribute(heapF32(np, nv * 3).slice(), 3));
    const jp = M._pskw_asset_joints4(w, a);
    g.setAttribute('skinIndex', new THREE.Uint16BufferAttribute(new Uint16Array(M.HEAPU16.buffer, jp, nv * 4).slice(), 4));
    g.setAttribute('skinWeight', new THREE.Float32BufferAttribute(heapF32(M._pskw_asset_weights4(w, a), nv * 4).slice(), 4));
    const ni = M._pskw_asset_index_count(w, a);
    if (ni > 0) g.setIndex(new THREE.Uint32BufferAttribute(new Uint32Array(M.HEAPU32.buffer, M._pskw_asset_indices(w, a), ni).slice(), 1));
    if (!np) g.computeVertexNormals();
    // Morph targets: position deltas (relative), weighted each frame by the
    // streamed weights before the GPU skins (glTF's order).
    const nm = M._pskw_asset_morph_count(w, a);
    if (nm > 0) {
        g.morphAttributes.position = [];
        for (let t = 0; t < nm; ++t)
            g.morphAttributes.position.push(new THREE.Float32BufferAttribute(heapF32(M._pskw_asset_morph_deltas(w, a, t), nv * 3).slice(), 3));
        g.morphTargetsRelative = true;
    }
    geometries.set(a, g);
    return g;
}

const shownByInstance = new Map();  // instance -> {mesh, skeleton, bones}
const identity = new THREE.Matrix4();
function meshFor(inst, a, nb) {
    let s = shownByInstance.get(inst);
    if (s) return s;
    const g = geometryOf(a);
    if (!g || nb <= 0) return null;
    const bones = [];
    for (let b = 0; b < nb; ++b) bones.push(new THREE.Bone());
    const skeleton = new THREE.Skeleton(bones, bones.map(() => new THREE.Matrix4()));
    skeleton.computeBoneTexture();
    // The bone matrices are the streamed palette, written every frame below.
    skeleton.update = function () { if (this.boneTexture) this.boneTexture.needsUpdate = true; };
    const hue = ((inst < 0 ? 0.5 - inst : inst) * 0.137) % 1;
    const mat = new THREE.MeshStandardMaterial({ color: new THREE.Color().setHSL(hue, 0.55, 0.6), roughness: 0.7,
                                                 side: THREE.DoubleSide });
    const mesh = new THREE.SkinnedMesh(g, mat);
    // Detached: the bind matrix stays the identity (three.js's attached mode
    // would undo the mesh's own placement, the character's root).
    mesh.bindMode = THREE.DetachedBindMode;
    mesh.bind(skeleton, identity);
    mesh.frustumCulled = false;
    scene.add(mesh);
    s = { mesh, skeleton, nb, asset: a, seen: 0 };
    shownByInstance.set(inst, s);
    return s;
}

// ---------------------------------------------------------- frame loop --
let framesDisplayed = 0, wasmSeconds = 0, wasmFrames = 0, lastFrameAt = 0;
let shownCount = 0, bonesMean = 0, frameSerial = 0, ownShown = 0;
const recorded = [];  // {instance, tick, bones, fresh (bones shown from a record of the tick), palette, gap_ms (since the frame before)} of every record_every-th tick
const MAX_RECORDED = 4000;
let lastStats = null, lastStatsAt = 0;

function frame() {
    requestAnimationFrame(frame);
    const t0 = performance.now();
    M._pskw_update(w, now());
    flush();
    ++frameSerial;
    const n = M._pskw_character_count(w);
    let shown = 0, bonesSum = 0;
    const box = new THREE.Box3();
    let maxDiag = 0;
    // Places one character: its mesh (made on first sight), the palette as bone matrices, the root.
    const place = (key, a, nb, palPtr, rootPtr, morphPtr = 0, nMorph = 0) => {
        const s = meshFor(key, a, nb);
        if (!s || s.nb !== nb) return null;
        s.seen = frameSerial;
        const pal = heapF32(palPtr, nb * 12);
        const bm = s.skeleton.boneMatrices;
        for (let b = 0; b < nb; ++b) {  // Mat34 rows -> column-major 4x4
            const o = b * 16, p = b * 12;
            bm[o] = pal[p]; bm[o + 1] = pal[p + 4]; bm[o + 2] = pal[p + 8]; bm[o + 3] = 0;
            bm[o + 4] = pal[p + 1]; bm[o + 5] = pal[p + 5]; bm[o + 6] = pal[p + 9]; bm[o + 7] = 0;
            bm[o + 8] = pal[p + 2]; bm[o + 9] = pal[p + 6]; bm[o + 10] = pal[p + 10]; bm[o + 11] = 0;
            bm[o + 12] = pal[p + 3]; bm[o + 13] = pal[p + 7]; bm[o + 14] = pal[p + 11]; bm[o + 15] = 1;
        }
        s.skeleton.boneTexture.needsUpdate = true;
        const inf = s.mesh.morphTargetInfluences;
        if (inf) {
            const wts = morphPtr && nMorph > 0 ? heapF32(morphPtr, nMorph) : null;
            for (let k = 0; k < inf.length; ++k) inf[k] = wts && k < nMorph ? wts[k] : 0;
        }
        const r = heapF32(rootPtr, 8);
        s.mesh.position.set(r[0], r[1], r[2]);
        s.mesh.quaternion.set(r[3], r[4], r[5], r[6]);
        s.mesh.visible = true;
        box.expandByPoint(s.mesh.position);
        maxDiag = Math.max(maxDiag, M._pskw_asset_diagonal(w, a));
        return pal;
    };
    for (let i = 0; i < n; ++i) {
        const inst = M._pskw_character_instance(w, i);
        const a = M._pskw_character_asset(w, i);
        const nb = M._pskw_character_palette_size(w, i);
        if (a < 0 || !M._pskw_character_shown(w, i)) continue;
        const pal = place(inst, a, nb, M._pskw_character_palette(w, i), M._pskw_character_root(w, i),
                          M._pskw_character_morph_weights(w, i), M._pskw_character_morph_count(w, i));
        if (!pal) continue;
        const bones = M._pskw_character_bones(w, i);
        ++shown;
        bonesSum += bones;
        if (recordEvery > 0) {
            const tick = M._pskw_character_tick(w, i);
            if (Math.abs(tick - Math.round(tick)) < 1e-6 && Math.round(tick) % recordEvery === 0 &&
                recorded.length < MAX_RECORDED &&
                !recorded.some((x) => x.instance === inst && x.tick === Math.round(tick)))
                recorded.push({ instance: inst, tick: Math.round(tick), bones, fresh: M._pskw_character_fresh_bones(w, i),
                                palette: Array.from(pal),
                                gap_ms: t0 - lastFrameAt });
        }
    }
    // The page's own characters, from the pose it publishes (keys below 0).
    ownShown = 0;
    for (let k = 0; k < M._pskw_published_count(w); ++k) {
        const nb = M._pskw_own_palette_size(w, k);
        if (nb > 0 && place(-1 - k, M._pskw_own_asset(w, k), nb, M._pskw_own_palette(w, k), M._pskw_own_root(w, k))) ++ownShown;
    }
    for (const [inst, s] of shownByInstance) {  // gone or not shown this frame
        if (s.seen !== frameSerial) {
            s.mesh.visible = false;
            if (s.seen < frameSerial - 600) {
                scene.remove(s.mesh);
                s.skeleton.dispose();
                s.mesh.material.dispose();
                shownByInstance.delete(inst);
            }
        }
    }
    lastFrameAt = t0;
    wasmSeconds += (performance.now() - t0) / 1000;
    ++wasmFrames;
    shownCount = shown;
    bonesMean = shown ? bonesSum / shown : 0;
    if (shown) frameCamera(box, maxDiag);
    renderer.render(scene, camera);
    ++framesDisplayed;
    if (performance.now() - lastStatsAt > 250) overlay();
}

// Keeps every character in view (the scene's placements differ in scale).
let camTarget = null;
function frameCamera(box, diag) {
    const c = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length() + 1.5 * diag;
    if (!camTarget || performance.now() - (frameCamera.at || 0) > 1000) {
        camTarget = { c, size };
        frameCamera.at = performance.now();
        grid.scale.setScalar(size * 1.5);
        grid.position.set(c.x, box.min.y, c.z);
    }
    const d = camTarget.size / (2 * Math.tan(THREE.MathUtils.degToRad(camera.fov) / 2)) * 1.1;
    camera.position.set(camTarget.c.x, camTarget.c.y + 0.45 * d + 0.3 * diag, camTarget.c.z + d);
    camera.lookAt(camTarget.c.x, camTarget.c.y + 0.15 * d, camTarget.c.z);  // the characters below the panel
    camera.near = d / 100;
    camera.far = d * 100;
    camera.updateProjectionMatrix();
}

function wasmStats() {
    const p = M._pskw_stats(w, now());
    return Array.from(new Float64Array(M.HEAPF64.buffer, p, 12));
}

const overlayEl = document.getElementById('overlay');
const stateEl = document.getElementById('state');
function overlay() {
    lastStatsAt = performance.now();
    const st = wasmStats();
    lastStats = st;
    const state = STATES[M._pskw_state(w)] || 'unknown';
    stateEl.textContent = state + (state === 'failed' ? ': ' + M.UTF8ToString(M._pskw_error(w)) : '');
    const lines = [`rate       ${st[7].toFixed(0)} kbit/s (cap ${st[11] > 0 ? st[11].toFixed(0) : 'max'})`,
                   `characters ${shownCount}` + (ownShown ? ` + ${ownShown} of mine` : '')];
    const n = M._pskw_character_count(w);
    for (let i = 0; i < n; ++i)
        lines.push(`  #${M._pskw_character_instance(w, i)}  ${M._pskw_character_bones(w, i)}/${M._pskw_character_palette_size(w, i)} bones` +
                   (M._pskw_character_root(w, i) && heapF32(M._pskw_character_root(w, i), 8)[7] ? '  (player)' : ''));
    lines.push(`latency    rtt ${st[4].toFixed(1)} ms + display delay ${st[6].toFixed(0)} ms`);
    lines.push(`wasm       ${(wasmFrames ? 1000 * wasmSeconds / wasmFrames : 0).toFixed(3)} ms/frame`);
    overlayEl.textContent = lines.join('\n');
    updateSpawnUi();
}

// ------------------------------------------------------------ controls --
const kbps = document.getElementById('kbps'), kbpsText = document.getElementById('kbps_text');
kbps.value = String(maxKbps);
function showCap(v) { kbpsText.textContent = v > 0 ? `${v} kbit/s` : 'server maximum'; }
showCap(maxKbps);
kbps.addEventListener('input', () => {
    const v = Number(kbps.value);
    M._pskw_set_max_kbps(w, v);
    showCap(v);
});
const spawnBtn = document.getElementById('spawn'), spawnSel = document.getElementById('spawn_asset');
let spawned = 0;
function updateSpawnUi() {
    const na = M._pskw_asset_count(w);
    if (spawnSel.options.length !== na) {
        spawnSel.innerHTML = '';
        for (let a = 0; a < na; ++a) {
            const o = document.createElement('option');
            o.value = String(a);
            o.textContent = M.UTF8ToString(M._pskw_asset_name(w, a));
            spawnSel.appendChild(o);
        }
    }
    const ready = M._pskw_state(w) === 2 && na > 0;
    spawnBtn.disabled = !ready;
    spawnSel.disabled = !ready;
}
// Spawns a character of asset `a` (its clips all together) walking a circle
// beside the scene, and publishes it every frame. Returns the handle or -1.
function spawn(a = Number(spawnSel.value || 0), clip = -1) {
    const diag = M._pskw_asset_diagonal(w, a);
    const h = M._pskw_spawn_clip(w, a, clip, (3 + 2 * spawned) * diag, 2 * diag, 0.5, now());
    if (h >= 0) ++spawned;
    return h;
}
spawnBtn.addEventListener('click', () => spawn());

// -------------------------------------------------------------- the API --
window.progskin = {
    stats: () => ({
        state: STATES[M._pskw_state(w)] || 'unknown',
        characters: shownCount,
        bones_mean: bonesMean,
        rate_kbps: lastStats ? lastStats[7] : 0,
        frames_displayed: framesDisplayed,
    }),
    error: () => M.UTF8ToString(M._pskw_error(w)),
    // Everything the session measures (pskw_stats), by name.
    details: () => {
        const s = wasmStats();
        return { seconds: s[0], datagrams: s[1], wire_bytes: s[2], loss: s[3], rtt_ms: s[4], estimate_kbps: s[5],
                 delay_ms: s[6], rate_kbps: s[7], asset_bytes: s[8], malformed: s[9], dropped: s[10], cap_kbps: s[11],
                 websocket_bytes: bytesIn, wasm_ms_per_frame: wasmFrames ? 1000 * wasmSeconds / wasmFrames : 0,
                 frames_displayed: framesDisplayed };
    },
    set_max_kbps: (v) => { M._pskw_set_max_kbps(w, v); kbps.value = String(v); showCap(v); },
    spawn,
    instance_of: (h) => M._pskw_instance_of(w, h),
    // The page's own characters drawn (from the poses it publishes).
    own: () => {
        const out = [];
        for (let k = 0; k < M._pskw_published_count(w); ++k)
            out.push({ instance: M._pskw_own_instance(w, k), asset: M._pskw_own_asset(w, k),
                       shown: M._pskw_own_palette_size(w, k) > 0 });
        return out;
    },
    recorded: () => recorded,
    characters: () => {
        const out = [];
        const n = M._pskw_character_count(w);
        for (let i = 0; i < n; ++i)
            out.push({ instance: M._pskw_character_instance(w, i), asset: M._pskw_character_asset(w, i),
                       shown: !!M._pskw_character_shown(w, i), bones: M._pskw_character_bones(w, i),
                       tick: M._pskw_character_tick(w, i),
                       root: Array.from(heapF32(M._pskw_character_root(w, i), 3)),
                       player: !!heapF32(M._pskw_character_root(w, i), 8)[7],
                       // the session's morph weights and what the page's mesh applies
                       morphs: M._pskw_character_morph_count(w, i) > 0
                           ? Array.from(heapF32(M._pskw_character_morph_weights(w, i), M._pskw_character_morph_count(w, i))) : [],
                       influences: shownByInstance.has(M._pskw_character_instance(w, i)) &&
                                   shownByInstance.get(M._pskw_character_instance(w, i)).mesh.morphTargetInfluences
                           ? Array.from(shownByInstance.get(M._pskw_character_instance(w, i)).mesh.morphTargetInfluences) : [] });
        return out;
    },
};
// Leaving the page: the session's Goodbye, so the server frees it at once.
window.addEventListener('pagehide', () => {
    const reason = 'page closed', len = M.lengthBytesUTF8(reason) + 1, p = M._malloc(len);
    M.stringToUTF8(reason, p, len);
    M._pskw_close(w, p);
    M._free(p);
    flush();
});
connect();
requestAnimationFrame(frame);
