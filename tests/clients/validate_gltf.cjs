// Validate a .gltf file with the Khronos glTF-Validator (npm package gltf-validator) and print its report as JSON.
// Usage: node validate_gltf.cjs FILE.gltf   (run from the project root, where npm installed node_modules/)
const fs = require("fs");
const path = require("path");
const validator = require(path.join(process.cwd(), "node_modules", "gltf-validator"));

const file = process.argv[2];
const bytes = new Uint8Array(fs.readFileSync(file));
validator
  .validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 100,
    externalResourceFunction: () => Promise.reject(new Error("the file must be self-contained")),
  })
  .then((report) => process.stdout.write(JSON.stringify(report)))
  .catch((error) => {
    process.stderr.write(String(error) + "\n");
    process.exit(2);
  });
