// Validate glTF files with the Khronos glTF Validator (npm package gltf-validator);
// prints one JSON report summary per file: {"file", "errors", "warnings", "messages"}.
// Usage: NODE_PATH=<dir>/node_modules node gltf_validate.js FILE...
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

async function check(file) {
  const bytes = new Uint8Array(fs.readFileSync(file));
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 100,
    externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri} not expected`)),
  });
  const issues = report.issues;
  return {
    file,
    errors: issues.numErrors,
    warnings: issues.numWarnings,
    messages: issues.messages.map((m) => ({ code: m.code, severity: m.severity, pointer: m.pointer, message: m.message })),
    info: report.info,
  };
}

(async () => {
  for (const file of process.argv.slice(2)) {
    console.log(JSON.stringify(await check(file)));
  }
})().catch((e) => {
  console.error(e);
  process.exit(1);
});
