// Validates the glTF files named on the command line with the Khronos glTF-Validator
// (validateBytes) and prints one JSON array: [{file, issues: [{code, severity, pointer,
// message}]}]. Run through scripts/validate-gltf, which installs the validator.
'use strict';
const fs = require('fs');
const path = require('path');
const zlib = require('zlib');
const validator = require('gltf-validator');

async function validate(file) {
    let bytes = fs.readFileSync(file);
    if (file.endsWith('.gz')) {
        bytes = zlib.gunzipSync(bytes);
    }
    const report = await validator.validateBytes(new Uint8Array(bytes), {
        uri: path.basename(file.replace(/\.gz$/, '')),
        maxIssues: 0,
        // Buffers and images named by relative URIs, read beside the file.
        externalResourceFunction: (uri) =>
            new Promise((resolve, reject) => {
                const resource = path.resolve(path.dirname(file), decodeURIComponent(uri));
                fs.readFile(resource, (err, data) => (err ? reject(err.toString()) : resolve(new Uint8Array(data))));
            }),
    });
    const issues = report.issues.messages.map((m) => ({
        code: m.code,
        severity: m.severity,
        pointer: m.pointer || '',
        message: m.message,
    }));
    return { file, issues };
}

async function main() {
    const reports = [];
    for (const file of process.argv.slice(2)) {
        reports.push(await validate(file));
    }
    process.stdout.write(JSON.stringify(reports) + '\n');
}

main().catch((e) => {
    process.stderr.write(`validate-gltf: ${e}\n`);
    process.exit(1);
});
