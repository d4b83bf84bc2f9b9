// Validate one .glb/.gltf with the Khronos glTF validator and print its JSON report on stdout.
// Usage: node validate.js FILE   (exit 0 when the validator ran, whatever it found; 2 on usage or read errors)
"use strict";
const fs = require("fs");
const path = require("path");
const validator = require("gltf-validator");

const file = process.argv[2];
if (!file) {
  console.error("usage: node validate.js FILE.glb");
  process.exit(2);
}
let bytes;
try {
  bytes = new Uint8Array(fs.readFileSync(file));
} catch (error) {
  console.error(`cannot read ${file}: ${error.message}`);
  process.exit(2);
}
validator
  .validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 0,
    externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri} not allowed`)),
  })
  .then((report) => console.log(JSON.stringify(report, null, 2)))
  .catch((error) => {
    console.error(`validator failed: ${error}`);
    process.exit(2);
  });
