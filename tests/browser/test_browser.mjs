// test_browser.mjs — the browser client end to end (ctest Browser.Loopback;
// docs/browser.md): a real progskin-server --no-tls --web on loopback serving
// the page (build/web), Debian's chromium headless (puppeteer-core from
// web/node_modules; no browser is downloaded) loading it, and a native
// client (progskin_palette_dump, a progskin::net::Client) beside it.
//
// Checks: every character of the scene shown in the page within the
// deadline; they move (each one's palette differs between server ticks); at
// the same server ticks (both display snapped to ticks) the page's palette
// equals the native client's within the quantisation bound (bone_codec.h:
// rotation entries 1.5e-4 per side, translation box extent / 131070 per
// side, the extent taken as twice the largest translation seen) for at least
// 80 % of the (instance, tick) pairs showing the same bones after each
// character's first second (see the comparison below for why not all); a player
// spawned in the page is seen by the native client and by the page itself; a
// screenshot (PNG) of the page whose pixels are not all the background.
// Prints the figures docs/browser.md quotes (frames per second, wasm ms per
// frame, bytes per character against the native client at the same cap).
//
//   node test_browser.mjs --server PATH --dump PATH --web-root DIR --out DIR
//        [--chromium /usr/bin/chromium] [--characters N] [--max-kbps N] [--seconds S] [--crowd N]
//        [--tls 1]   (a TLS server with its self-signed certificate: https:// and wss://,
//                     chromium told to accept it, the native client pinning it)
//        [--asset FILE --morphs 1]  (the server serves FILE, a character with morph
//                     targets; the checks are then: every character shown, its mesh's
//                     morphTargetInfluences equal to the session's streamed weights in every
//                     sample, the weights moving, a screenshot)
// Exit 0 pass, 1 fail, 77 skipped (chromium or the page missing, unless
// PROGSKIN_REQUIRE_BROWSER=1, then 1), 2 bad arguments.
import { spawn } from 'node:child_process';
import { createRequire } from 'node:module';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';

const SKIP = 77;
const args = { chromium: '/usr/bin/chromium', characters: '4', 'max-kbps': '0', seconds: '8', crowd: '', tls: '0', asset: '',
               morphs: '0' };
for (let i = 2; i < process.argv.length; ++i) {
    const a = process.argv[i];
    if (a === '--help') {
        console.log(fs.readFileSync(new URL(import.meta.url)).toString().split('\n').slice(0, 22).join('\n'));
        process.exit(0);
    }
    if (!a.startsWith('--') || i + 1 >= process.argv.length) {
        console.error(`test_browser: bad argument ${a} (--help)`);
        process.exit(2);
    }
    args[a.slice(2)] = process.argv[++i];
}
for (const k of ['server', 'dump', 'web-root', 'out'])
    if (!args[k]) { console.error(`test_browser: --${k} is required`); process.exit(2); }
const expected = Number(args.characters), maxKbps = Number(args['max-kbps']), seconds = Number(args.seconds);
const require_ = process.env.PROGSKIN_REQUIRE_BROWSER === '1';
function skip(why) {
    console.error(`test_browser: ${require_ ? 'FAIL' : 'SKIPPED'}: ${why}`);
    process.exit(require_ ? 1 : SKIP);
}
if (!fs.existsSync(args.chromium)) skip(`${args.chromium} missing (apt-get install chromium; scripts/setup.sh)`);
if (!fs.existsSync(path.join(args['web-root'], 'index.html')) || !fs.existsSync(path.join(args['web-root'], 'progskin_wasm.wasm')))
    skip(`the page is not built in ${args['web-root']} (scripts/build_web.sh)`);
let puppeteer;
try {
    puppeteer = createRequire(new URL('../../web/package.json', import.meta.url))('puppeteer-core');
} catch (e) {
    skip(`puppeteer-core missing (cd web && npm ci): ${e.message}`);
}

let failures = 0;
function check(ok, what) {
    console.log(`${ok ? 'ok  ' : 'FAIL'} ${what}`);
    if (!ok) ++failures;
}
fs.mkdirSync(args.out, { recursive: true });
const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'progskin-browser-'));
const children = [];
function cleanup() {
    for (const c of children) if (c.exitCode === null) c.kill('SIGTERM');
    fs.rmSync(tmp, { recursive: true, force: true });
}
process.on('exit', cleanup);

// ------------------------------------------------------------- server --
function startServer() {
    const extra = [...(args.crowd ? ['--crowd', args.crowd] : []), ...(args.asset ? ['--asset', args.asset] : [])];
    const tls = args.tls === '1' ? ['--tls-dir', path.join(tmp, 'tls')] : ['--no-tls'];
    const p = spawn(args.server, [...tls, '--port', '0', '--bind', '127.0.0.1', '--web', '0', '--web-root', args['web-root'],
                                  '--cache', path.join(tmp, 'server-cache'), '--duration', '300', ...extra],
                    { stdio: ['ignore', 'pipe', 'pipe'] });
    children.push(p);
    let err = '';
    p.stderr.on('data', (d) => { err += d; });
    return new Promise((resolve, reject) => {
        let out = '';
        const info = {};
        const timer = setTimeout(() => reject(new Error('server did not start in 120 s:\n' + out + err)), 120000);
        p.stdout.on('data', (d) => {
            out += d;
            let m = out.match(/listening on TCP (\d+), UDP \d+, (\d+) instances/);
            if (m) { info.tcp = Number(m[1]); info.instances = Number(m[2]); }
            m = out.match(/WebSocket endpoint wss?:\/\/[^:]+:(\d+)\/ws/);
            if (m) info.web = Number(m[1]);
            m = out.match(/TLS certificate sha256 ([0-9A-Fa-f:]+)/);
            if (m) info.pin = m[1];
            if (info.tcp && info.web && out.includes('tick thread')) { clearTimeout(timer); resolve(info); }
        });
        p.on('exit', (code) => reject(new Error(`server exited (${code}):\n${out}${err}`)));
    });
}

function runDump(port, secs, every, kbps) {
    const p = spawn(args.dump, ['127.0.0.1', String(port), String(secs), String(every), String(kbps)],
                    { stdio: ['ignore', 'pipe', 'pipe'],
                      env: { ...process.env, PROGSKIN_CACHE: path.join(tmp, 'native-cache'), PROGSKIN_PIN: server.pin || '' } });
    children.push(p);
    let out = '', err = '';
    p.stdout.on('data', (d) => { out += d; });
    p.stderr.on('data', (d) => { err += d; });
    return new Promise((resolve) => p.on('exit', (code) => {
        const lines = out.split('\n').filter((l) => l.trim()).map((l) => JSON.parse(l));
        resolve({ code, err, records: lines.filter((l) => !l.summary), summary: (lines.find((l) => l.summary) || {}).summary });
    }));
}

// Largest difference between two palettes, rotation entries and translations apart.
function paletteDiff(a, b) {
    let rot = 0, tr = 0;
    for (let i = 0; i < Math.min(a.length, b.length); ++i) {
        const d = Math.abs(a[i] - b[i]);
        if (i % 4 === 3) tr = Math.max(tr, d); else rot = Math.max(rot, d);
    }
    return { rot, tr, sameSize: a.length === b.length };
}

// Fraction of the screenshot's pixels that differ from the background colour.
async function drawnFraction(page) {
    return page.evaluate(() => {
        const src = document.getElementById('view');
        const c = document.createElement('canvas');
        c.width = src.width; c.height = src.height;
        const g = c.getContext('2d');
        g.drawImage(src, 0, 0);
        const d = g.getImageData(0, 0, c.width, c.height).data;
        let differ = 0;
        for (let i = 0; i < d.length; i += 4)
            if (Math.abs(d[i] - 0x20) + Math.abs(d[i + 1] - 0x24) + Math.abs(d[i + 2] - 0x2b) > 30) ++differ;
        return differ / (d.length / 4);
    });
}

const server = await startServer().catch((e) => { console.error(`test_browser: ${e.message}`); process.exit(1); });
console.log(`server: TCP ${server.tcp}, web ${server.web}, ${server.instances} instances`);
const base = `${args.tls === '1' ? 'https' : 'http'}://127.0.0.1:${server.web}/`;
if (args.tls === '1') process.env.NODE_TLS_REJECT_UNAUTHORIZED = '0';  // the server's self-signed certificate

// A static file: the wasm with its content type; and a refused path.
{
    const r = await fetch(base + 'progskin_wasm.wasm');
    check(r.status === 200 && r.headers.get('content-type') === 'application/wasm', `GET /progskin_wasm.wasm: ${r.status} ${r.headers.get('content-type')}`);
    const bad = await fetch(base + 'a/../index.html').catch(() => null);  // fetch normalises "..": also check raw below
    check(!bad || bad.status === 200 || bad.status === 400, 'normalised path served or refused');
}

const browser = await puppeteer.launch({
    executablePath: args.chromium,
    headless: true,
    args: ['--no-sandbox', '--disable-dev-shm-usage', '--use-angle=swiftshader', '--enable-unsafe-swiftshader',
           '--ignore-gpu-blocklist', '--window-size=800,500', ...(args.tls === '1' ? ['--ignore-certificate-errors'] : [])],
});
let exitCode = 1;
try {
    const page = await browser.newPage();
    await page.setViewport({ width: 800, height: 500 });
    const logs = [];
    page.on('console', (m) => logs.push(`console.${m.type()}: ${m.text()}`));
    page.on('pageerror', (e) => logs.push(`pageerror: ${e.message}`));
    const every = 5;
    const t0 = Date.now();
    await page.goto(`${base}?snap_to_ticks=1&record_every=${every}${maxKbps > 0 ? `&max_kbps=${maxKbps}` : ''}`,
                    { waitUntil: 'load' });
    // The native client beside it, for as long as the page is measured.
    const dump = runDump(server.tcp, seconds + 4, every, maxKbps);
    let all = false;
    try {
        await page.waitForFunction((n) => window.progskin && window.progskin.stats().characters >= n, { timeout: 30000, polling: 50 },
                                   expected);
        all = true;
    } catch (e) {
        const st = await page.evaluate(() => window.progskin ? [window.progskin.stats(), window.progskin.error()] : null).catch(() => null);
        console.log(`page: ${JSON.stringify(st)}\n${logs.join('\n')}`);
    }
    const shownAfter = (Date.now() - t0) / 1000;
    console.log('characters: ' + JSON.stringify(await page.evaluate(() => window.progskin.characters())));
    check(all, `all ${expected} characters shown in the page ${shownAfter.toFixed(2)} s after loading it (deadline 30 s)`);
    if (!all) throw new Error('the page shows nothing to compare');
    if (args.morphs === '1') {
        // Morph targets: the page's meshes apply the session's weights.
        let samples = 0, mismatched = 0, lo = Infinity, hi = -Infinity, targets = 0;
        for (let k = 0; k < 40; ++k) {
            await new Promise((r) => setTimeout(r, 50));
            for (const c of await page.evaluate(() => window.progskin.characters())) {
                if (!c.shown || c.morphs.length === 0) continue;
                ++samples;
                targets = Math.max(targets, c.morphs.length);
                if (c.influences.length !== c.morphs.length ||
                    c.morphs.some((x, i) => Math.abs(x - c.influences[i]) > 1e-6)) ++mismatched;
                for (const x of c.morphs) { lo = Math.min(lo, x); hi = Math.max(hi, x); }
            }
        }
        console.log(`morphs: ${samples} samples of up to ${targets} weights, ${mismatched} not applied as streamed, weights from ${lo.toFixed(3)} to ${hi.toFixed(3)}`);
        check(samples > 0 && targets > 0, `characters with morph weights shown (${samples} samples, ${targets} targets)`);
        check(mismatched === 0, `the page's morphTargetInfluences equal the streamed weights (${mismatched} of ${samples} samples differ)`);
        check(hi - lo > 0.05, `the weights move (${lo.toFixed(3)} .. ${hi.toFixed(3)})`);
        const shot = path.join(args.out, 'browser_morphs.png');
        fs.mkdirSync(args.out, { recursive: true });
        const drawn = await drawnFraction(page);
        await page.screenshot({ path: shot });
        check(drawn > 0.001, `screenshot ${shot}: ${(100 * drawn).toFixed(2)} % of the pixels drawn`);
        throw Object.assign(new Error('morph checks done'), { done: true });
    }

    // Frames displayed per second over a few seconds, and the per-frame wasm cost.
    const f0 = await page.evaluate(() => window.progskin.details());
    await new Promise((r) => setTimeout(r, 3000));
    const f1 = await page.evaluate(() => window.progskin.details());
    const fps = (f1.frames_displayed - f0.frames_displayed) / 3;
    console.log(`measure: ${fps.toFixed(1)} frames displayed per second, wasm decode + palette ${f1.wasm_ms_per_frame.toFixed(3)} ms per frame, ` +
                `${(await page.evaluate(() => window.progskin.stats().bones_mean)).toFixed(1)} bones per character`);
    check(fps > 5, `the page keeps drawing (${fps.toFixed(1)} frames/s)`);

    const shot = path.join(args.out, 'browser.png');
    await page.screenshot({ path: shot });
    const drawn = await drawnFraction(page);
    check(drawn > 0.01, `screenshot ${shot}: ${(100 * drawn).toFixed(1)} % of the pixels drawn (not background)`);

    // The native client's palettes at the same ticks.
    const native = await dump;
    check(native.code === 0, `native client ran (${native.code}) ${native.err.trim()}`);
    const mine = await page.evaluate(() => window.progskin.recorded());
    fs.writeFileSync(path.join(args.out, 'palettes.json'), JSON.stringify({ page: mine, native: native.records }));
    const byKey = new Map(mine.map((r) => [`${r.instance}/${r.tick}`, r]));
    let pairs = 0, worstRot = 0, worstTr = 0, worstTrBound = 0, over = 0, sizeMismatch = 0;
    const maxT = new Map();
    for (const r of [...mine, ...native.records])
        for (let i = 3; i < r.palette.length; i += 4) maxT.set(r.instance, Math.max(maxT.get(r.instance) || 0, Math.abs(r.palette[i])));
    // Left out: each character's first second (30 ticks) on either side, while
    // bones still blend in over display frames (ClientConfig::blend_frames:
    // frames of each client's own display loop, not server ticks).
    const firstOf = (recs, i) => Math.min(...recs.filter((r) => r.instance === i).map((r) => r.tick));
    const warm = (i, t) => t >= Math.max(firstOf(mine, i), firstOf(native.records, i)) + 30;
    let otherLod = 0, afterStall = 0, stale = 0;
    for (const n of native.records) {
        const b = byKey.get(`${n.instance}/${n.tick}`);
        if (!b || !warm(n.instance, n.tick)) continue;
        if (b.bones !== n.bones) {  // the two sessions' streams differ (each has its own rate controller)
            ++otherLod;
            continue;
        }
        if (b.gap_ms > 100) {  // a page frame after a stall displays a tick whose frame it has not read yet
            ++afterStall;
            continue;
        }
        if (b.fresh !== b.bones || n.fresh !== n.bones) {  // a bone without its record of this tick on either side:
            ++stale;                                       // interpolated across a longer gap or held (not comparable)
            continue;
        }
        ++pairs;
        const d = paletteDiff(b.palette, n.palette);
        if (!d.sameSize) ++sizeMismatch;
        const trBound = 2 * (2 * maxT.get(n.instance)) / 131070;  // two sides, each box extent / 131070
        worstRot = Math.max(worstRot, d.rot);
        worstTr = Math.max(worstTr, d.tr / Math.max(trBound, 1e-12));
        worstTrBound = Math.max(worstTrBound, trBound);
        if (d.rot > 2 * 1.5e-4 * 2 || d.tr > trBound) {  // rotation entries: 2 sides x 2 x angle bound
            if (++over <= 8)
                console.log(`  over: instance ${n.instance} tick ${n.tick}: bones page ${b.bones} native ${n.bones}, ` +
                            `page frame ${b.gap_ms.toFixed(0)} ms after the one before, ` +
                            `rotation ${d.rot.toExponential(2)}, translation ${(d.tr / trBound).toFixed(1)} x bound`);
        }
    }
    console.log(`compare: ${pairs} (instance, tick) pairs at the same server tick; largest rotation-entry difference ` +
                `${worstRot.toExponential(2)} (bound 6.0e-4), largest translation difference ${worstTr.toFixed(3)} x its bound; ` +
                `${over} over the bound, ${sizeMismatch} of another size; ${otherLod} pairs left out (another LOD), ` +
                `${afterStall} (a page frame more than 100 ms after the one before), ${stale} (a bone without its record of the tick)`);
    const pd = await page.evaluate(() => window.progskin.details());
    const ns0 = native.summary || {};
    console.log(`loss: page ${(100 * pd.loss).toFixed(2)} % (${pd.datagrams} datagrams, ${pd.dropped} dropped in the page), ` +
                `native ${(100 * (ns0.loss || 0)).toFixed(2)} % (${ns0.datagrams} datagrams)`);
    check(pairs >= 10, `at least 10 palettes compared at the same server tick (${pairs})`);
    // Each client displays what it received: the two sessions have their own
    // rate controllers (the page's Acks come in bursts over TCP, so the
    // server may send it fewer records for a while: another LOD, left out
    // above, or the same LOD with some bones older: left out when either
    // side shows a bone without its record of the tick), and a page frame
    // after a stall (a screenshot, a busy machine) displays a tick before
    // its frame was read. The same code fed the same records gives the same
    // palette (5e-10 measured), so 80 % of the pairs left must agree (the
    // rest: a bone still blending on one side).
    if (maxKbps > 0)  // under a cap each session's scheduler sends its own choice of records: not comparable
        console.log('compare: not checked under a cap (each session gets its own records)');
    else
        check(sizeMismatch === 0 && over <= 0.2 * pairs,
              `the page displays what the native client displays at the same server tick (${pairs - over} of ${pairs} within the quantisation bound)`);

    // Moving: each instance's palette differs between two recorded ticks.
    const insts = [...new Set(mine.map((r) => r.instance))];
    let moving = 0;
    for (const i of insts) {
        const rs = mine.filter((r) => r.instance === i).sort((a, b) => a.tick - b.tick);
        let most = 0;  // the largest change between two successive recorded ticks
        for (let k = 1; k < rs.length; ++k) most = Math.max(most, paletteDiff(rs[k - 1].palette, rs[k].palette).rot);
        if (most > 1e-3) ++moving;
    }
    check(insts.length >= expected && moving === insts.length, `${moving} of ${insts.length} characters move (palette changes between ticks)`);

    // Bytes per character: the page against the native client at the same cap.
    const d = await page.evaluate(() => window.progskin.details());
    const pageBpc = d.wire_bytes / Math.max(d.seconds, 1e-9) / expected;
    const ns = native.summary || {};
    const nativeBpc = ns.wire_bytes / Math.max(ns.seconds, 1e-9) / Math.max(ns.characters, 1);
    console.log(`measure: bytes per character per second: page ${pageBpc.toFixed(0)}, native ${nativeBpc.toFixed(0)} ` +
                `(${(100 * (pageBpc / nativeBpc - 1)).toFixed(1)} %), cap ${maxKbps > 0 ? maxKbps + ' kbit/s' : 'none'}`);

    // A player in the page: spawned and published, seen by the native client and the page.
    const handle = await page.evaluate(() => window.progskin.spawn(0, -1));
    check(handle >= 0, `spawn from the page (handle ${handle})`);
    let inst = -1;
    for (let i = 0; i < 100 && inst < 0; ++i) {
        await new Promise((r) => setTimeout(r, 50));
        inst = await page.evaluate((h) => window.progskin.instance_of(h), handle);
    }
    check(inst >= 0, `the server gave the page's character instance ${inst}`);
    const seen = await runDump(server.tcp, 3, 1, 0);
    const nativeSaw = seen.records.some((r) => r.instance === inst);
    check(nativeSaw, `a native client sees the page's character (instance ${inst})`);
    const pageSaw = await page.evaluate((i) => window.progskin.own().some((c) => c.instance === i && c.shown), inst);
    check(pageSaw, 'the page draws its own published character');
    await page.screenshot({ path: path.join(args.out, 'browser_with_player.png') });
    if (failures) console.log(logs.join('\n'));
    exitCode = failures ? 1 : 0;
} catch (e) {
    if (e && e.done) {  // a mode that ends early (--morphs 1)
        exitCode = failures ? 1 : 0;
    } else {
        console.error(`test_browser: ${e.stack || e}`);
        exitCode = 1;
    }
} finally {
    await browser.close();
}
console.log(failures || exitCode ? `test_browser: FAILED (${failures} checks)` : 'test_browser: passed');
process.exit(exitCode);
