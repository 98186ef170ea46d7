// validate.mjs — the Khronos glTF validator (npm gltf-validator) on each file
// given; prints one JSON object per line: {"file", "errors", "warnings",
// "infos", "hints", "codes": {CODE: count, ...}, "messages": [first 20 errors/warnings]}.
// Exit 0 when every file was read (whatever it contains), 1 otherwise.
//
// usage: npm ci && node validate.mjs FILE...
import fs from 'node:fs';
import path from 'node:path';
import validator from 'gltf-validator';

let failed = false;
for (const file of process.argv.slice(2)) {
  try {
    const bytes = new Uint8Array(fs.readFileSync(file));
    const dir = path.dirname(file);
    const report = await validator.validateBytes(bytes, {
      uri: path.basename(file),
      maxIssues: 0,
      externalResourceFunction: (uri) =>
        new Promise((resolve, reject) => {
          fs.readFile(path.join(dir, decodeURIComponent(uri)), (err, data) => (err ? reject(err.toString()) : resolve(new Uint8Array(data))));
        }),
    });
    const codes = {};
    for (const m of report.issues.messages) codes[m.code] = (codes[m.code] ?? 0) + 1;
    const messages = report.issues.messages.filter((m) => m.severity <= 1).slice(0, 20)
      .map((m) => `${m.severity === 0 ? 'error' : 'warning'} ${m.code} ${m.pointer ?? ''}: ${m.message}`);
    console.log(JSON.stringify({
      file, errors: report.issues.numErrors, warnings: report.issues.numWarnings,
      infos: report.issues.numInfos, hints: report.issues.numHints, codes, messages,
    }));
  } catch (e) {
    console.log(JSON.stringify({ file, read_error: String(e) }));
    failed = true;
  }
}
process.exit(failed ? 1 : 0);
